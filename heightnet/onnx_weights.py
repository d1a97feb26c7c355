"""An exported HeightNet's weights read back from its ONNX file, to fine-tune a shipped model.

The ONNX file is what ships; a training checkpoint need not survive. Every weight is in the
file, under the module names of ``ExportedHeightNet`` (``net.`` + the state-dict key), except
where export changed them:

* each encoder convolution absorbed the BatchNorm after it (the node keeps the convolution's
  module path in its name): the convolution gets the folded weight, the BatchNorm becomes an
  identity with the folded bias (weight 1, running mean 0, variance 1 - eps). That is exact in
  eval mode only, so a network rebuilt this way trains with its BatchNorms frozen
  (:func:`freeze_batchnorm`);
* GroupNorm is exported as an instance norm, then a Mul by its weight and an Add of its bias;
* equal weights (a freshly initialised bias) are stored once, other names point to it.

Loading checks the rebuilt network against ONNX Runtime on a random image.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from heightnet.model import ExportedHeightNet, HeightNet
from core.errors import ModelError

PREFIX = "net."
TOLERANCE = 1e-3


def module_path(node_name: str) -> str:
    """``/net/encoder/to_4/to_4.0/body/body.3/Conv`` -> ``encoder.to_4.0.body.3``.

    Each scope in an exported node's name repeats its parent's local name as a prefix.
    """
    scopes = node_name.strip("/").split("/")[1:-1]
    parts, previous = [], None
    for scope in scopes:
        parts.append(scope[len(previous) + 1:] if previous and scope.startswith(previous + ".") else scope)
        previous = scope
    return ".".join(parts)


def load_onnx_weights(net: HeightNet, path: Path) -> None:
    """Loads the weights of the ONNX file at ``path`` into ``net`` (same architecture)."""
    import onnx
    from onnx import numpy_helper

    path = Path(path)
    if not path.is_file():
        raise ModelError(f"model not found: {path}")
    try:
        graph = onnx.load(str(path)).graph
    except Exception as exc:  # protobuf raises several types for a damaged file
        raise ModelError(f"cannot read ONNX model {path}: {exc}") from None
    arrays = {i.name: numpy_helper.to_array(i) for i in graph.initializer}
    for node in graph.node:       # export shares equal weights between names through Identity nodes
        if node.op_type == "Identity" and node.input[0] in arrays:
            arrays[node.output[0]] = arrays[node.input[0]]
    modules = dict(net.named_modules())
    expected = net.state_dict()
    state = {key: torch.from_numpy(arrays[PREFIX + key].copy())
             for key in expected if PREFIX + key in arrays}
    for node in graph.node:
        name = module_path(node.name)
        module = modules.get(name)
        if node.op_type == "Conv" and isinstance(module, torch.nn.Conv2d) and name + ".weight" not in state:
            _unfold_batchnorm(state, modules, name, arrays[node.input[1]],
                              arrays[node.input[2]] if len(node.input) > 2 else None)
        elif node.op_type in ("Mul", "Add") and isinstance(module, torch.nn.GroupNorm):
            consts = [arrays[i] for i in node.input if i in arrays]
            if len(consts) == 1:
                state[name + (".weight" if node.op_type == "Mul" else ".bias")] = torch.from_numpy(
                    consts[0].reshape(-1).copy())
    missing = [key for key in expected if key not in state]
    if missing or any(state[k].shape != expected[k].shape for k in expected):
        raise ModelError(f"{path} does not fit a {net.arch.name} HeightNet "
                         f"({len(missing)} weights missing, e.g. {missing[:3]})")
    net.load_state_dict(state)
    _check_against_onnx(net, path)


def load_onnx_weights_shared(net: HeightNet, path: Path) -> list[str]:
    """Loads into ``net`` what it shares with the exported model at ``path``, of an architecture
    with more decoder levels (``light`` into ``light_half``); returns the weights left as built.

    Every weight of the same name and shape is copied. The finest head ``net`` has predicts the
    height residual (channel 0, copied) and, now that it is the last level, the ground logit
    (channel 1): that channel keeps its fresh initialisation and is learnt by fine-tuning.
    """
    from heightnet.model import architecture_from_name

    source = HeightNet(architecture_from_name(exported_architecture(path)), net.encoding)
    load_onnx_weights(source, path)
    theirs = source.state_dict()
    state = net.state_dict()
    fresh = []
    for key, value in state.items():
        if key in theirs and theirs[key].shape == value.shape:
            state[key] = theirs[key].clone()
        elif key in theirs and value.shape[0] > theirs[key].shape[0] == 1:  # finest head: + ground
            state[key][:1] = theirs[key]
            fresh.append(f"{key}[1:]")
        else:
            fresh.append(key)
    net.load_state_dict(state)
    return fresh


def _unfold_batchnorm(state: dict, modules: dict, conv_path: str, weight: np.ndarray,
                      bias: np.ndarray | None) -> None:
    state[conv_path + ".weight"] = torch.from_numpy(weight.copy())
    parent, index = conv_path.rsplit(".", 1)
    norm = modules.get(f"{parent}.{int(index) + 1}")
    if not isinstance(norm, torch.nn.BatchNorm2d) or bias is None:
        raise ModelError(f"ONNX convolution {conv_path} is not followed by a folded BatchNorm")
    channels = weight.shape[0]
    key = f"{parent}.{int(index) + 1}"
    state[key + ".weight"] = torch.ones(channels)
    state[key + ".bias"] = torch.from_numpy(bias.copy())
    state[key + ".running_mean"] = torch.zeros(channels)
    state[key + ".running_var"] = torch.full((channels,), 1.0 - norm.eps)
    state[key + ".num_batches_tracked"] = torch.tensor(0)


def _check_against_onnx(net: HeightNet, path: Path) -> None:
    import onnxruntime as ort

    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    shape = [d if isinstance(d, int) and d > 0 else s
             for d, s in zip(session.get_inputs()[0].shape, (1, 3, 192, 320))]
    image = np.random.default_rng(0).random(shape, dtype=np.float32)
    expected = session.run(None, {session.get_inputs()[0].name: image})
    was_training = net.training
    with torch.no_grad():
        got = ExportedHeightNet(net).eval()(torch.from_numpy(image))
    net.train(was_training)
    worst = max(float(np.abs(a - b.numpy()).max()) for a, b in zip(expected, got))
    if worst > TOLERANCE:
        raise ModelError(f"weights read from {path} do not reproduce it (max difference {worst:.3g})")


def exported_metadata(path: Path) -> dict[str, str]:
    """An exported model's metadata (the heightpipe contract's keys), without its weights."""
    import onnx

    if not Path(path).is_file():
        raise ModelError(f"model not found: {path}")
    try:
        props = onnx.load(str(path), load_external_data=False).metadata_props
    except Exception as exc:  # protobuf raises several types for a damaged file
        raise ModelError(f"cannot read ONNX model {path}: {exc}") from None
    return {p.key: p.value for p in props}


def exported_architecture(path: Path) -> str:
    """The architecture an exported model was built as (its metadata; "" if it does not say)."""
    return exported_metadata(path).get("heightpipe.architecture", "")


def trained_steps(path: Path) -> int:
    """The optimiser steps behind an exported model (its metadata; 0 if it does not say)."""
    value = exported_metadata(path).get("heightpipe.trained_steps", "0")
    return int(value) if value.isdigit() else 0


def freeze_batchnorm(net: torch.nn.Module) -> None:
    """BatchNorms in eval mode (running statistics, not the batch's), whatever ``net.train()`` says."""
    for module in net.modules():
        if isinstance(module, torch.nn.modules.batchnorm._BatchNorm):
            module.eval()
