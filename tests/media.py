"""Test media made on the fly: small videos and a tiny ONNX height model (no torch needed)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

REPO_ROOT = Path(__file__).resolve().parent.parent
SHARED_REAL = REPO_ROOT.parent / "shared" / "real"


def make_tiny_height_model(path: Path, width: int = 64, height: int = 48,
                           units: str = "camera_height_fraction", input_shape=None) -> Path:
    """A two-head ONNX model with heightpipe metadata: height from brightness, ground from darkness.

    Not a trained network: it lets pipeline tests run without torch or the shipped model.
    Bright pixels come out 'high', so a white box on a dark floor is an object.
    """
    import onnx
    from onnx import TensorProto, helper

    shape = input_shape or [1, 3, height, width]
    w_height = np.full((1, 3, 1, 1), 0.15, np.float32)   # ~0.45 x camera height for white
    w_ground = np.full((1, 3, 1, 1), -2.0, np.float32)
    b_ground = np.array([1.0], np.float32)
    nodes = [
        helper.make_node("Conv", ["image", "w_height"], ["height_raw"]),
        helper.make_node("Relu", ["height_raw"], ["height"]),
        helper.make_node("Conv", ["image", "w_ground", "b_ground"], ["ground_logit"]),
    ]
    graph = helper.make_graph(
        nodes, "tiny_heightnet",
        [helper.make_tensor_value_info("image", TensorProto.FLOAT, shape)],
        [helper.make_tensor_value_info("height", TensorProto.FLOAT, [1, 1, height, width]),
         helper.make_tensor_value_info("ground_logit", TensorProto.FLOAT, [1, 1, height, width])],
        initializer=[helper.make_tensor("w_height", TensorProto.FLOAT, w_height.shape, w_height.ravel()),
                     helper.make_tensor("w_ground", TensorProto.FLOAT, w_ground.shape, w_ground.ravel()),
                     helper.make_tensor("b_ground", TensorProto.FLOAT, [1], b_ground)])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    meta = {"heightpipe.format_version": "1", "heightpipe.input_width": str(width),
            "heightpipe.input_height": str(height), "heightpipe.mean": json.dumps([0.5, 0.5, 0.5]),
            "heightpipe.std": json.dumps([0.5, 0.5, 0.5]), "heightpipe.color_order": "RGB",
            "heightpipe.output_units": units, "heightpipe.architecture": "tiny-test"}
    helper.set_model_props(model, meta)
    onnx.save(model, str(path))
    return path


def write_moving_box_video(path: Path, frames: int = 30, size=(160, 120), fps: float = 10.0) -> Path:
    """A dark floor with a white box walking across: an easy 'object' for the tiny model."""
    width, height = size
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, size)
    assert writer.isOpened()
    rng = np.random.default_rng(0)
    floor = (rng.random((height, width, 3)) * 40).astype(np.uint8)
    for i in range(frames):
        image = floor.copy()
        x = 10 + i * (width - 40) // max(1, frames - 1)
        cv2.rectangle(image, (x, height // 3), (x + 16, height // 3 + 40), (255, 255, 255), -1)
        writer.write(image)
    writer.release()
    return path
