"""Height maps from images with the exported ONNX model (ONNX Runtime only: no torch needed).

``HeightPredictor`` follows the run-time contract (``stages/heightnet_model.py``): resize
any frame to the model's input with INTER_AREA, normalise, run, resize both outputs back
bilinearly, and turn ``camera_height_fraction`` outputs into metres with the camera height.
A ground-contact (v2) model's offsets become metres with the camera as the run takes it
(``stages/contact_heights.py``: a calibration file's or ``[camera]``'s pose, else the camera
height and the network's camera heads); the inputs of one command are taken to be one camera's,
as its ``--camera-height`` and ``--calibration`` are, so the heads are averaged over them.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from core.config import CameraConfig
from core.errors import ConfigError, ModelError, SourceError
from core.packets import CameraInfo, HeightCamera
from heightnet.normalisation import normalise
from stages.heightnet_model import model_file

IMAGE_SUFFIXES = {".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp"}
VIDEO_SUFFIXES = {".mp4", ".avi", ".mkv", ".mov", ".webm", ".m4v"}


@dataclass
class HeightPrediction:
    height_m: np.ndarray
    """float32 H x W, height above ground in metres (frame resolution)."""
    ground_probability: np.ndarray
    """float32 H x W in [0, 1]."""
    camera: HeightCamera | None = None
    """The camera a v2 model's heights were decoded with (None: a v1 model)."""


def model_path_from_config(configured: str) -> Path:
    path = model_file(configured)
    if not path.is_file():
        raise ModelError(f"height model not found: {path}")
    return path


class HeightPredictor:
    """Height maps of RGB images from an exported model.

    The ONNX Runtime session, its metadata and its input and output signature are
    ``stages.heightnet_model.HeightNetModel``'s (one wrapper for the run-time stages and for
    these commands); this class adds the RGB-image interface and the metres.
    """

    def __init__(self, model_path: str | Path, threads: int = 2, input_width: int = 0):
        from stages.contact_heights import ContactHeights
        from stages.heightnet_model import HeightNetModel

        model = HeightNetModel(model_path, threads, input_width=input_width)
        self.model = model
        self.contact = ContactHeights(spread_scale=model.info.camera_spread_scale) if model.info.contact else None
        """v2 models: the decoder, with the camera heads' running mean over this predictor's inputs."""
        self.height_camera: HeightCamera | None = None
        """The camera of the last v2 prediction (what ``heightpipe predict`` reports)."""
        self.session = model.session
        self.input_name = model.input_name
        self.width, self.height = model.info.input_width, model.info.input_height
        self.mean, self.std = list(model.info.mean), list(model.info.std)
        self.units = model.info.output_units
        self.metadata = dict(self.session.get_modelmeta().custom_metadata_map)

    @property
    def needs_camera_height(self) -> bool:
        return self.units == "camera_height_fraction"

    def predict(self, rgb: np.ndarray, camera_height_m: float = 0.0,
                camera: CameraInfo | None = None) -> HeightPrediction:
        """``rgb``: uint8 H x W x 3 in RGB order; ``camera``: this image's camera
        (``stages.calibration.camera_for_run``), else ``camera_height_m`` is all that is known.
        v1 models use only the camera height."""
        if camera is None:
            h, w = rgb.shape[:2]
            camera = CameraInfo(w, h, height_m=camera_height_m if camera_height_m > 0 else None,
                                source="camera-height" if camera_height_m > 0 else "none")
        if self.contact is not None:
            return self._predict_contact(rgb, camera)
        camera_height_m = camera.height_m if camera.source != "none" and camera.height_m else 0.0
        if self.needs_camera_height and camera_height_m <= 0:
            raise ConfigError("this height model predicts height relative to the camera height: "
                              "give --camera-height (or camera.height_m)")
        h, w = rgb.shape[:2]
        small = cv2.resize(rgb, (self.width, self.height), interpolation=cv2.INTER_AREA)
        image = normalise(small, self.mean, self.std)[None]
        height, ground_logit = self.session.run(["height", "ground_logit"], {self.input_name: image})
        height = cv2.resize(height[0, 0], (w, h), interpolation=cv2.INTER_LINEAR)
        ground_logit = cv2.resize(ground_logit[0, 0], (w, h), interpolation=cv2.INTER_LINEAR)
        if self.needs_camera_height:
            height = height * camera_height_m
        ground = 1.0 / (1.0 + np.exp(-np.clip(ground_logit, -30, 30)))
        return HeightPrediction(height.astype(np.float32), ground.astype(np.float32))

    def _predict_contact(self, rgb: np.ndarray, camera: CameraInfo) -> HeightPrediction:
        h, w = rgb.shape[:2]
        output = self.model.run(np.ascontiguousarray(rgb[:, :, ::-1]))  # run() takes BGR, as frames are
        height, self.height_camera = self.contact.decode(output, camera, (w, h))
        return HeightPrediction(height, output.ground_probability, self.height_camera)


def height_to_png16(height_m: np.ndarray) -> np.ndarray:
    """uint16 millimetres, 0 = ground (and undefined), saturating at 65.535 m."""
    mm = np.nan_to_num(height_m, nan=0.0) * 1000.0
    return np.clip(np.round(mm), 0, 65535).astype(np.uint16)


def colourise(rgb: np.ndarray, height_m: np.ndarray, max_height_m: float = 3.0) -> np.ndarray:
    """BGR visualisation: the frame beside its height map (turbo colour map, 0 to max_height_m)."""
    scaled = np.clip(np.nan_to_num(height_m) / max_height_m, 0, 1)
    colour = cv2.applyColorMap((scaled * 255).astype(np.uint8), cv2.COLORMAP_TURBO)
    colour[scaled < 0.02] = (colour[scaled < 0.02] * 0.35).astype(np.uint8)
    return np.concatenate([cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), colour], axis=1)


def iter_inputs(source: Path, every: int = 1) -> Iterator[tuple[str, np.ndarray]]:
    """(stem, RGB frame) for an image, every image of a folder, or every Nth frame of a video."""
    if not source.exists():
        raise SourceError(f"input not found: {source}")
    if source.is_dir():
        files = sorted(p for p in source.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not files:
            raise SourceError(f"no images in {source}")
        for path in files:
            yield path.stem, _read_image(path)
    elif source.suffix.lower() in VIDEO_SUFFIXES:
        capture = cv2.VideoCapture(str(source))
        if not capture.isOpened():
            raise SourceError(f"cannot open video {source}")
        index = 0
        try:
            while True:
                ok, frame = capture.read()
                if not ok:
                    break
                if index % every == 0:
                    yield f"{source.stem}_{index:06d}", cv2.cvtColor(frame, cv2.COLOR_BGR2RGB)
                index += 1
        finally:
            capture.release()
        if index == 0:
            raise SourceError(f"no frames could be read from {source}")
    else:
        yield source.stem, _read_image(source)


def _read_image(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise SourceError(f"cannot read image {path}")
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def predict_to_folder(source: Path, out_dir: Path, predictor: HeightPredictor,
                      camera_height_m: float = 0.0, every: int = 1,
                      camera_config: CameraConfig | None = None) -> list[Path]:
    """Writes <stem>.png (uint16 mm) and <stem>_color.jpg for each input; returns the PNG paths.

    ``camera_config`` (``[camera]`` with the command's flags applied) gives each input's camera
    as ``heightpipe run`` builds it; without it, ``camera_height_m`` is all that is known.
    """
    from stages.calibration import camera_for_run

    config = camera_config or CameraConfig(height_m=camera_height_m)
    cameras: dict[tuple[int, int], CameraInfo] = {}  # images of a folder may differ in size
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for stem, rgb in iter_inputs(source, every):
        size = (rgb.shape[1], rgb.shape[0])
        if size not in cameras:
            cameras[size] = camera_for_run(config, *size)
        prediction = predictor.predict(rgb, camera=cameras[size])
        png = out_dir / f"{stem}.png"
        cv2.imwrite(str(png), height_to_png16(prediction.height_m))
        cv2.imwrite(str(out_dir / f"{stem}_color.jpg"), colourise(rgb, prediction.height_m))
        written.append(png)
    return written
