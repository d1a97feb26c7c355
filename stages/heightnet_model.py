"""The ONNX HeightNet model as the run-time stages see it.

One network has two heads (height and ground), and two stages read them, so both hold the
same ``HeightNetModel`` and it caches its result for the frame being processed: the
network runs once per frame. Everything about the model's input and output (size,
normalisation, units) is read from metadata stored in the ONNX file, never hard-coded.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from core.errors import ModelError
from core.packets import CameraInfo, Frame

SHIPPED_MODEL = Path(__file__).resolve().parent / "models" / "heightnet.onnx"
SHIPPED_INT8_MODEL = SHIPPED_MODEL.with_name("heightnet_int8.onnx")
"""The shipped model quantised to INT8 (heightnet/quantize.py): ``height.model = "int8"``."""
OUTPUT_UNITS = ("metres", "camera_height_fraction")


@dataclass
class ModelInfo:
    """What the ONNX metadata says about the model (see heightnet/export.py)."""

    input_width: int
    input_height: int
    mean: tuple[float, float, float]
    std: tuple[float, float, float]
    output_units: str
    architecture: str
    color_order: str = "RGB"


@dataclass
class ModelOutput:
    """Network outputs resized to the frame: raw height (model units) and ground probability."""

    height: np.ndarray
    ground_probability: np.ndarray


def _read_info(path: Path, meta: dict[str, str]) -> ModelInfo:
    try:
        info = ModelInfo(
            input_width=int(meta["heightpipe.input_width"]),
            input_height=int(meta["heightpipe.input_height"]),
            mean=tuple(json.loads(meta["heightpipe.mean"])),
            std=tuple(json.loads(meta["heightpipe.std"])),
            output_units=meta["heightpipe.output_units"],
            architecture=meta.get("heightpipe.architecture", "unknown"),
            color_order=meta.get("heightpipe.color_order", "RGB"),
        )
    except KeyError as exc:
        raise ModelError(f"{path} lacks heightpipe metadata {exc.args[0]!r}: "
                         "export it with `heightpipe export`") from None
    except (ValueError, TypeError) as exc:
        raise ModelError(f"{path} has malformed heightpipe metadata: {exc}") from None
    if info.output_units not in OUTPUT_UNITS:
        raise ModelError(f"{path}: unknown output units {info.output_units!r}")
    return info


class HeightNetModel:
    def __init__(self, model_path: str | Path = "", threads: int = 2):
        import onnxruntime as ort

        path = SHIPPED_INT8_MODEL if str(model_path) == "int8" else Path(model_path) if model_path else SHIPPED_MODEL
        if not path.is_file():
            raise ModelError(f"model file not found: {path}")
        options = ort.SessionOptions()
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
        options.log_severity_level = 3
        try:
            self.session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own untyped errors for bad files
            first_line = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise ModelError(f"{path} is not a loadable ONNX model: {first_line[:200]}") from None
        self.path = path
        self.info = _read_info(path, self.session.get_modelmeta().custom_metadata_map)
        self._check_signature()
        self._mean = np.array(self.info.mean, np.float32) * 255.0
        self._inv_std = 1.0 / (np.array(self.info.std, np.float32) * 255.0)
        self._cached_index: int | None = None
        self._cached: ModelOutput | None = None

    def _check_signature(self) -> None:
        inputs = self.session.get_inputs()
        if len(inputs) != 1:
            raise ModelError(f"{self.path}: expected one input, found {len(inputs)}")
        expected = [1, 3, self.info.input_height, self.info.input_width]
        if list(inputs[0].shape) != expected:
            raise ModelError(f"{self.path}: input shape {inputs[0].shape} does not match "
                             f"the expected {expected} (1 x RGB x height x width from metadata)")
        self.input_name = inputs[0].name
        outputs = {o.name: o.shape for o in self.session.get_outputs()}
        for name in ("height", "ground_logit"):
            if name not in outputs:
                raise ModelError(f"{self.path}: missing output {name!r} (has {sorted(outputs)})")
            if list(outputs[name]) != [1, 1, self.info.input_height, self.info.input_width]:
                raise ModelError(f"{self.path}: output {name!r} has shape {outputs[name]}, expected "
                                 f"[1, 1, {self.info.input_height}, {self.info.input_width}]")

    def preprocess(self, image_bgr: np.ndarray) -> np.ndarray:
        small = cv2.resize(image_bgr, (self.info.input_width, self.info.input_height),
                           interpolation=cv2.INTER_AREA)
        if self.info.color_order == "RGB":
            small = small[:, :, ::-1]
        tensor = (small.astype(np.float32) - self._mean) * self._inv_std
        return np.ascontiguousarray(tensor.transpose(2, 0, 1)[None])

    def infer(self, frame: Frame) -> ModelOutput:
        """Run the network on a frame (once: repeated calls for one frame hit the cache)."""
        if self._cached_index == frame.index and self._cached is not None:
            return self._cached
        height, ground_logit = self.session.run(["height", "ground_logit"],
                                                {self.input_name: self.preprocess(frame.image)})
        h, w = frame.image.shape[:2]
        height_full = cv2.resize(height[0, 0], (w, h), interpolation=cv2.INTER_LINEAR)
        logit_full = cv2.resize(ground_logit[0, 0], (w, h), interpolation=cv2.INTER_LINEAR)
        probability = 1.0 / (1.0 + np.exp(-np.clip(logit_full, -30, 30)))
        self._cached_index = frame.index
        self._cached = ModelOutput(np.maximum(height_full, 0.0), probability.astype(np.float32))
        return self._cached

    def to_metres(self, height: np.ndarray, camera: CameraInfo) -> np.ndarray:
        """Model units to metres: scale-free outputs are multiplied by the camera height."""
        if self.info.output_units == "metres":
            return height
        return height * np.float32(camera.height_m)
