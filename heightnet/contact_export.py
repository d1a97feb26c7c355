"""HeightNet v2 state -> ONNX file, checked against PyTorch.

The graph's input size is free (the metadata names the one it was trained at); it ends at what
the network knows: ``offsets`` (1 x 2 x H x W, input pixels to each
pixel's ground-contact point), ``ground_logit`` (1 x 1 x H x W) and ``camera`` (1 x 6: pitch,
roll, log vertical focal length in image heights, then their log-variances) and, with a
detection head, ``centre_logit`` (1 x 3 x H/4 x W/4) and ``box`` (1 x 4 x H/4 x W/4; H/2 x W/2 with
the fine path), with a big-object head ``big_centre_logit`` and ``big_box`` at H/16 x W/16; a head that reads
motion (``detection_motion``) takes the frame before as a second input, ``previous_image``. Metres need the
camera and come from the closed form in ``stages/ground_contact.py`` at run time. The metadata says
so (``heightpipe.output_units = ground_contact_offsets``) beside the usual input contract.
"""

from __future__ import annotations

import datetime
import json
from pathlib import Path

import numpy as np
import torch

from heightnet.contact_model import BIG_STRIDE, CAMERA_OUTPUTS, DETECTION_CLASSES, ContactNet
from heightnet.contact_train import load_network
from heightnet.export import input_metadata, save_with_metadata
from stages.heightnet_model import CONTACT_UNITS, PREVIOUS_INPUT

OPSET = 17
# What the run-time stage reads the offsets as (stages/heightnet_model.py tells v1 from v2 by it).
OUTPUT_UNITS = CONTACT_UNITS


def output_names(net: ContactNet) -> list[str]:
    return (["offsets", "ground_logit", "camera"] + (["centre_logit", "box"] if net.arch.detection else [])
            + (["big_centre_logit", "big_box"] if net.arch.detection and net.arch.detection_big else []))


def contact_metadata(net: ContactNet, width: int, height: int, images_seen: int,
                     camera_spread_scale: list[float] | None = None,
                     camera_error_correlation: list[list[float]] | None = None) -> dict[str, str]:
    """The model's metadata; ``camera_spread_scale`` (measured by ``python -m heightnet.camera_fresh
    --write``): how much wider the camera heads' errors on unseen cameras are than the spread they
    report, per pitch, roll and log focal length (absent: not measured, the run takes 1), and
    ``camera_error_correlation`` (the same tool): how those errors go together (absent: the run
    takes them as independent)."""
    outputs = {
        "offsets": "du, dv in input pixels from each pixel to the image of its ground-contact point",
        "ground_logit": "ground-plane logit",
        "camera": [*CAMERA_OUTPUTS, *(f"log_var_{name}" for name in CAMERA_OUTPUTS)]}
    if net.arch.detection:
        outputs["centre_logit"] = {"classes": list(DETECTION_CLASSES), "stride": net.arch.detection_stride}
        outputs["box"] = "centre dx, dy from the cell centre, box width, height; input pixels"
        if net.arch.detection_big:
            outputs["big_centre_logit"] = {"classes": list(DETECTION_CLASSES), "stride": BIG_STRIDE}
            outputs["big_box"] = "as box, for the big-object head's cells"
    return {
        "heightpipe.format_version": "2",
        **input_metadata(width, height),
        "heightpipe.output_units": OUTPUT_UNITS,
        "heightpipe.outputs": json.dumps(outputs),
        "heightpipe.architecture": json.dumps(net.arch.to_dict()),
        "heightpipe.trained_images": str(images_seen),
        "heightpipe.created": datetime.date.today().isoformat(),
        **({"heightpipe.camera_spread_scale": json.dumps([round(float(v), 3) for v in camera_spread_scale])}
           if camera_spread_scale is not None else {}),
        **({"heightpipe.camera_error_correlation": json.dumps([[round(float(v), 3) for v in row]
                                                                for row in camera_error_correlation])}
           if camera_error_correlation is not None else {}),
    }


def export_contact(state_path: Path, out: Path, tolerance: float = 1e-3) -> dict[str, float]:
    """Export a training state; returns the size and ORT-vs-PyTorch differences per output."""
    import onnxruntime as ort

    state = torch.load(state_path, map_location="cpu", weights_only=False)
    net = load_network(state_path)
    if net.arch.camera_channels:
        raise ValueError("a network with camera-channel inputs needs the camera before it runs; "
                         "export supports RGB-only networks")
    width, height = state["input_size"]
    example = torch.randn(1, 3, height, width, generator=torch.Generator().manual_seed(0))
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".tmp.onnx")
    # A free input size (the metadata keeps the trained one): the run time may choose another
    # (``height.input_width``) and fixes it when it builds its session.
    free = {"image": {2: "height", 3: "width"}}
    free.update({name: {2: f"{name}_height", 3: f"{name}_width"} for name in output_names(net) if name != "camera"})
    inputs = {"image": example}
    if net.arch.detection_motion:
        # The frame before: the run time passes the last frame it ran on (the first frame twice).
        inputs[PREVIOUS_INPUT] = torch.randn(1, 3, height, width, generator=torch.Generator().manual_seed(1))
        free[PREVIOUS_INPUT] = {2: "height", 3: "width"}
    graph = _WithPrevious(net).eval() if net.arch.detection_motion else net
    torch.onnx.export(graph, tuple(inputs.values()), str(tmp), input_names=list(inputs),
                      output_names=output_names(net), opset_version=OPSET,
                      do_constant_folding=True, dynamo=False, dynamic_axes=free)
    save_with_metadata(tmp, out, contact_metadata(net, width, height, int(state["images"]),
                                                  state.get("camera_spread_scale"),
                                                  state.get("camera_error_correlation")))
    with torch.no_grad():
        expected = [t.numpy() for t in graph(*inputs.values())]
    session = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    names = output_names(net)
    got = session.run(names, {name: value.numpy() for name, value in inputs.items()})
    diffs = {name: float(np.abs(a - b).max()) for name, a, b in zip(names, got, expected)}
    if max(diffs.values()) > tolerance:
        raise ValueError(f"ONNX Runtime differs from PyTorch by {max(diffs.values()):.2e} in {out}")
    return {"size_bytes": out.stat().st_size, **diffs}


class _WithPrevious(torch.nn.Module):
    """The network with the previous frame as its second positional input (what ONNX export traces)."""

    def __init__(self, net: ContactNet):
        super().__init__()
        self.net = net

    def forward(self, image: torch.Tensor, previous: torch.Tensor):
        return self.net(image, previous=previous)
