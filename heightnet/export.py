"""Checkpoint -> ONNX file that meets the run-time contract (``stages/heightnet_model.py``), checked against PyTorch."""

from __future__ import annotations

import datetime
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from heightnet.checkpoint import load_checkpoint, model_from_checkpoint
from heightnet.model import ExportedHeightNet, HeightNet
from heightnet.normalisation import MEAN, STD
from core.errors import ModelError

OPSET = 17


@dataclass
class ExportReport:
    path: Path
    size_bytes: int
    max_abs_diff_height: float
    max_abs_diff_ground: float
    metadata: dict[str, str]


def input_metadata(input_width: int, input_height: int) -> dict[str, str]:
    """The input contract every exported height network states: size, normalisation, colours."""
    return {
        "heightpipe.input_width": str(input_width),
        "heightpipe.input_height": str(input_height),
        "heightpipe.mean": json.dumps(list(MEAN)),
        "heightpipe.std": json.dumps(list(STD)),
        "heightpipe.color_order": "RGB",
    }


def contract_metadata(net: HeightNet, input_width: int, input_height: int, data_hash: str,
                      trained_steps: int) -> dict[str, str]:
    return {
        "heightpipe.format_version": "1",
        **input_metadata(input_width, input_height),
        "heightpipe.output_units": net.encoding.output_units,
        "heightpipe.architecture": net.arch.name,
        "heightpipe.backbone": net.arch.backbone,
        "heightpipe.training_data_hash": data_hash,
        "heightpipe.trained_steps": str(trained_steps),
        "heightpipe.created": datetime.date.today().isoformat(),
    }


def export_model(net: HeightNet, path: Path, input_width: int, input_height: int,
                 data_hash: str = "", trained_steps: int = 0, tolerance: float = 1e-3,
                 seed: int = 0) -> ExportReport:
    """Trace ``net`` to ONNX with the contract's names and metadata, then compare ORT to PyTorch."""
    if input_width % 16 or input_height % 16:
        raise ModelError(f"input size {input_width}x{input_height} must be a multiple of 16")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    wrapper = ExportedHeightNet(net).eval()
    generator = torch.Generator().manual_seed(seed)
    example = torch.randn(1, 3, input_height, input_width, generator=generator)
    tmp = path.with_suffix(".tmp.onnx")
    torch.onnx.export(wrapper, (example,), str(tmp), input_names=["image"],
                      output_names=["height", "ground_logit"], opset_version=OPSET,
                      do_constant_folding=True, dynamo=False)
    metadata = contract_metadata(net, input_width, input_height, data_hash, trained_steps)
    save_with_metadata(tmp, path, metadata)

    diff_height, diff_ground = compare_with_onnxruntime(wrapper, path, example)
    if max(diff_height, diff_ground) > tolerance:
        raise ModelError(f"ONNX Runtime output differs from PyTorch by {max(diff_height, diff_ground):.2e} "
                         f"(> {tolerance:g}) in {path}")
    return ExportReport(path, path.stat().st_size, diff_height, diff_ground, metadata)


def save_with_metadata(traced: Path, out: Path, metadata: dict[str, str]) -> None:
    """Save the ONNX file ``traced`` (torch's export, then removed) as ``out`` with ``metadata`` as
    its only metadata (what the run time reads), checked by ONNX's checker."""
    import onnx

    model = onnx.load(str(traced))
    del model.metadata_props[:]
    for key, value in metadata.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.checker.check_model(model)
    onnx.save(model, str(out))
    traced.unlink()


def compare_with_onnxruntime(wrapper: torch.nn.Module, path: Path,
                             example: torch.Tensor) -> tuple[float, float]:
    """Largest difference of each output, absolute where |value| <= 1 and relative above."""
    import onnxruntime as ort

    with torch.no_grad():
        height, ground = (t.numpy() for t in wrapper(example))
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    ort_height, ort_ground = session.run(["height", "ground_logit"], {"image": example.numpy()})
    return _max_difference(ort_height, height), _max_difference(ort_ground, ground)


def _max_difference(actual: np.ndarray, expected: np.ndarray) -> float:
    # Absolute below 1, relative above: an untrained net can output exp(20) or overflow to inf.
    with np.errstate(invalid="ignore", over="ignore"):
        diff = np.abs(actual - expected) / np.maximum(1.0, np.abs(expected))
    diff = np.where(actual == expected, 0.0, diff)
    return float(np.nan_to_num(diff, nan=np.inf).max())


def export_checkpoint(checkpoint_path: Path, out: Path) -> ExportReport:
    checkpoint = load_checkpoint(checkpoint_path)
    net = model_from_checkpoint(checkpoint).eval()
    return export_model(net, out, checkpoint["input_width"], checkpoint["input_height"],
                        checkpoint.get("data_hash", ""),
                        int(checkpoint.get("init_steps", 0)) + int(checkpoint["step"]))
