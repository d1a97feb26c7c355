"""Sharper edges for the detection head's boxes: a second, close look at each person's box.

The head (heightnet/contact_model.py) reads every box from the one cell at its centre, through
features shared with the heights. Its people's edges are about 2 input pixels off each (a walker
is 14 x 30 pixels at the median), on its own training pictures as on held-out ones, and most of
that is a steady offset per walker that tracking cannot average away (docs/results.md,
2026-12-07 forty-third and 2026-12-08 forty-fourth sessions). The tops and feet are where the camera
geometry reads a person's height, so those pixels are centimetres: a 1.7 m walker 30 pixels tall
is 5.7 cm a pixel.

The refiner is a small convolutional network trained on the head's own boxes over the
generator's training pictures (heightnet/box_refiner.py). It reads a fixed-size crop of the
network's input around each box, resampled so that every box fills it alike (the box grown by
``margin`` of its width at each side and of its height above and below), with the box's size in
input pixels, and says how far each edge lies from the truth, in shares of the box's width
(left, right) and height (top, bottom). On held-out sequences it took the head's people's edges
from 1.71 to 1.21 pixels off (mean of the four; trk_test40 HOTA 0.548 -> 0.598, people's tracked
heights 10.1 -> 6.6 cm).

It runs on each frame's person boxes after the network, on the image the network read (a crop
of the frame itself would hold detail the refiner never saw in training). Its ONNX file carries
its crop size, its margin, the classes it refines and the SHA-256 of the detection model it was
trained on: with ``height.box_refiner = "auto"`` it refines that model's boxes only, since another
head's errors are not the ones it learnt.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import cv2
import numpy as np

from core.errors import ConfigError, ModelError
from stages.onnx_session import cpu_session

SHIPPED_REFINER = Path(__file__).resolve().parent / "models" / "box_refiner.onnx"
"""The refiner trained on the shipped HeightNet v2's boxes (``height.box_refiner = "auto"``)."""
CROPS_INPUT = "crops"
SIZES_INPUT = "log_size"
EDGES_OUTPUT = "edges"
SIZE_UNIT_PX = 16.0
"""The box size input is log(size / SIZE_UNIT_PX), as the head's own box sizes are."""
MIN_REFINED_PX = 1.0
"""A refined box narrower or shorter than this (input pixels) is left as the head drew it."""


def crop_window(boxes: np.ndarray, margin: tuple[float, float]) -> np.ndarray:
    """N x 4 (x0, y0, x1, y1): each box grown by ``margin[0]`` of its width at the left and at
    the right, and by ``margin[1]`` of its height above and below."""
    boxes = np.asarray(boxes, np.float32).reshape(-1, 4)
    w = np.maximum(boxes[:, 2] - boxes[:, 0], MIN_REFINED_PX)
    h = np.maximum(boxes[:, 3] - boxes[:, 1], MIN_REFINED_PX)
    grow = np.stack([-margin[0] * w, -margin[1] * h, margin[0] * w, margin[1] * h], 1)
    return boxes + grow


def box_crops(image: np.ndarray, boxes: np.ndarray, crop_size: tuple[int, int],
              margin: tuple[float, float]) -> np.ndarray:
    """N x height x width x 3 (``crop_size`` is width, height): each box's ``crop_window`` of
    ``image`` resampled to ``crop_size`` (bilinear; the image's border repeated past its edge).
    Boxes are in pixel edges (0 is the first pixel's left edge) and OpenCV maps pixel centres, so
    the map goes through the centres: a crop of a mirrored image is then the crop mirrored."""
    width, height = crop_size
    crops = np.empty((len(boxes), height, width, 3), np.uint8)
    for i, (x0, y0, x1, y1) in enumerate(crop_window(boxes, margin)):
        sx, sy = width / (x1 - x0), height / (y1 - y0)
        warp = np.array([[sx, 0.0, sx * (0.5 - x0) - 0.5], [0.0, sy, sy * (0.5 - y0) - 0.5]], np.float32)
        crops[i] = cv2.warpAffine(image, warp, (width, height), flags=cv2.INTER_LINEAR,
                                  borderMode=cv2.BORDER_REPLICATE)
    return crops


def refiner_inputs(crops: np.ndarray, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The refiner's two inputs: crops as N x 3 x H x W float32 (the image's channels as read,
    0-255 mapped to -0.5..0.5) and each box's log(width, height / ``SIZE_UNIT_PX``)."""
    pixels = crops.transpose(0, 3, 1, 2).astype(np.float32) / 255.0 - 0.5
    boxes = np.asarray(boxes, np.float32).reshape(-1, 4)
    sizes = np.maximum(boxes[:, 2:] - boxes[:, :2], MIN_REFINED_PX)
    return pixels, np.log(sizes / SIZE_UNIT_PX).astype(np.float32)


def moved_edges(boxes: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """``boxes`` (N x 4: x0, y0, x1, y1) with each edge moved by ``edges`` (N x 4: left, top,
    right, bottom in shares of the box's width and height); a box that would become thinner or
    shorter than ``MIN_REFINED_PX`` stays as it was."""
    boxes = np.asarray(boxes, np.float32).reshape(-1, 4)
    w, h = boxes[:, 2] - boxes[:, 0], boxes[:, 3] - boxes[:, 1]
    moved = boxes + np.asarray(edges, np.float32).reshape(-1, 4) * np.stack([w, h, w, h], 1)
    ok = ((moved[:, 2] - moved[:, 0]) >= MIN_REFINED_PX) & ((moved[:, 3] - moved[:, 1]) >= MIN_REFINED_PX)
    return np.where(ok[:, None], moved, boxes).astype(np.float32)


def file_digest(path: str | Path) -> str:
    """SHA-256 of a file's bytes (hex): which detection model a refiner was trained on."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


class BoxRefiner:
    """One exported refiner in an ONNX Runtime session (one thread: it runs beside the network
    on the network's thread, a few crops a frame)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        if not self.path.is_file():
            raise ModelError(f"box refiner not found: {self.path}")
        self.session = cpu_session(self.path, threads=1)
        meta = self.session.get_modelmeta().custom_metadata_map
        try:
            self.crop_size = tuple(int(v) for v in json.loads(meta["heightpipe.crop_size"]))
            self.margin = tuple(float(v) for v in json.loads(meta["heightpipe.margin"]))
            self.classes = tuple(str(c) for c in json.loads(meta["heightpipe.refined_classes"]))
            self.trained_on = str(meta["heightpipe.detection_model_sha256"])
        except (KeyError, ValueError, TypeError):
            raise ModelError(f"{self.path} is not a box refiner (heightnet/box_refiner.py writes one): "
                             "its metadata lacks the crop size, margin, classes or detection model") from None
        names = {i.name for i in self.session.get_inputs()}
        if names != {CROPS_INPUT, SIZES_INPUT}:
            raise ModelError(f"{self.path}: expected inputs {CROPS_INPUT!r} and {SIZES_INPUT!r}, found {sorted(names)}")

    def refine(self, image: np.ndarray, boxes: np.ndarray, classes) -> np.ndarray:
        """``boxes`` (N x 4, x0, y0, x1, y1 in ``image``'s pixels: the network's input) with the
        edges of those whose class (``classes``, one name a box) it refines moved."""
        boxes = np.asarray(boxes, np.float32).reshape(-1, 4)
        chosen = np.flatnonzero([name in self.classes for name in classes])
        if chosen.size == 0:
            return boxes
        crops = box_crops(image, boxes[chosen], self.crop_size, self.margin)
        pixels, sizes = refiner_inputs(crops, boxes[chosen])
        edges = self.session.run([EDGES_OUTPUT], {CROPS_INPUT: pixels, SIZES_INPUT: sizes})[0]
        refined = boxes.copy()
        refined[chosen] = moved_edges(boxes[chosen], edges)
        return refined


def refiner_for(setting: str, model_path: str | Path) -> BoxRefiner | None:
    """The refiner ``height.box_refiner`` names for the detection model at ``model_path``: "auto"
    = the shipped one where it was trained on this very model (else none), "off" = none, else
    the file named (on any model)."""
    if setting == "off":
        return None
    if setting == "auto":
        if not SHIPPED_REFINER.is_file():
            return None
        refiner = BoxRefiner(SHIPPED_REFINER)
        return refiner if refiner.trained_on == file_digest(model_path) else None
    if not setting:
        raise ConfigError('height.box_refiner must be "auto", "off" or a refiner\'s ONNX file, got ""')
    return BoxRefiner(setting)
