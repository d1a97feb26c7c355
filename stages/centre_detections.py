"""Objects from the height network's detection head: centre-heatmap peaks become boxes.

The head (heightnet/contact_model.py) predicts, at 1/``stride`` of its input, one centre
heatmap per class and at every cell a box (offset of the centre from the cell centre, width and
height, in input pixels). As in CenterNet (Zhou et al. 2019), a cell is an object where its
probability is the largest of its 3x3 neighbourhood and above a threshold; that local maximum
is the whole non-maximum suppression here (the objects stage drops boxes lying mostly inside a
stronger one: ``stages.network_objects``).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from core.packets import NetworkDetections


@dataclass(frozen=True)
class CentreDetections:
    """Boxes in input pixels (N x 4: x0, y0, x1, y1), their class indices and scores."""

    boxes: np.ndarray
    classes: np.ndarray
    scores: np.ndarray

    def __len__(self) -> int:
        return len(self.scores)


def centre_detections(centre_logit: np.ndarray, box: np.ndarray, stride: int,
                      threshold: float | np.ndarray = 0.3, max_objects: int = 100) -> CentreDetections:
    """Peaks of ``centre_logit`` (C x h x w) with their boxes (``box`` 4 x h x w); ``threshold``
    is one score or one per class."""
    prob = 1.0 / (1.0 + np.exp(-centre_logit.astype(np.float32)))
    peaks = prob == _neighbourhood_max(prob)
    limits = np.broadcast_to(np.asarray(threshold, np.float32), (prob.shape[0],))[:, None, None]
    cls, ys, xs = np.nonzero(peaks & (prob >= limits))
    scores = prob[cls, ys, xs]
    keep = np.argsort(-scores, kind="stable")[:max_objects]
    cls, ys, xs, scores = cls[keep], ys[keep], xs[keep], scores[keep]
    dx, dy, w, h = (box[k, ys, xs] for k in range(4))
    cx = (xs + 0.5) * stride + dx
    cy = (ys + 0.5) * stride + dy
    boxes = np.stack([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2], 1).astype(np.float32)
    return CentreDetections(boxes.reshape(-1, 4), cls.astype(np.int64), scores.astype(np.float32))


def _neighbourhood_max(prob: np.ndarray) -> np.ndarray:
    """Each cell's largest probability over its 3x3 neighbourhood in its own class (cells past
    the border count as nothing). OpenCV's dilation, a class at a time: a twentieth of SciPy's
    maximum filter's time on a 1/2-resolution heatmap (0.03 against 0.56 ms at 3 x 90 x 160)."""
    kernel = np.ones((3, 3), np.uint8)
    return np.stack([cv2.dilate(channel, kernel) for channel in prob.reshape(-1, *prob.shape[-2:])]).reshape(prob.shape)


def at_least_tall(detections: CentreDetections, min_height: float) -> CentreDetections:
    """The detections whose boxes are at least ``min_height`` tall (input pixels)."""
    tall = detections.boxes[:, 3] - detections.boxes[:, 1] >= min_height
    return CentreDetections(detections.boxes[tall], detections.classes[tall], detections.scores[tall])


def merged(a: CentreDetections, b: CentreDetections) -> CentreDetections:
    """Two heads' detections as one, strongest first (what the objects stage's fragment rule
    expects: a box is checked against the stronger ones kept before it)."""
    scores = np.concatenate([a.scores, b.scores])
    order = np.argsort(-scores, kind="stable")
    return CentreDetections(np.concatenate([a.boxes, b.boxes]).reshape(-1, 4)[order],
                            np.concatenate([a.classes, b.classes])[order], scores[order])


def with_big_objects(found: CentreDetections, big_centre_logit: np.ndarray, big_box: np.ndarray, stride: int,
                     threshold: float | np.ndarray, min_height: float, max_objects: int = 100) -> CentreDetections:
    """``found`` (the detection head's peaks) joined by a big-object head's (its outputs at
    ``stride``), strongest first, less its boxes under ``min_height`` input pixels: below the
    objects it was taught its coarse boxes only compete with the finer ones."""
    big = centre_detections(big_centre_logit, big_box, stride, threshold, max_objects)
    return merged(found, at_least_tall(big, min_height))


def in_frame(detections: CentreDetections, class_names: tuple[str, ...] | list[str],
             input_size: tuple[int, int], frame_size: tuple[int, int], big_objects: bool = False) -> NetworkDetections:
    """The detections in source-frame pixels, with class names (``big_objects``: they include a
    big-object head's, ``NetworkDetections.big_objects``).

    The frame was squashed to the input (``HeightNetModel.preprocess``: each axis resized on its
    own, edge to edge), so each axis scales back by its own factor (``input_size`` and
    ``frame_size`` are width, height). Boxes are not clipped: one running off the frame says so.
    """
    scale = np.array([frame_size[0] / input_size[0], frame_size[1] / input_size[1]] * 2, np.float32)
    boxes = (np.asarray(detections.boxes, np.float32).reshape(-1, 4) * scale).astype(np.float32)
    return NetworkDetections(boxes, tuple(str(class_names[int(c)]) for c in detections.classes),
                             np.asarray(detections.scores, np.float32), big_objects)


def box_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Intersection over union of every box in ``a`` (N x 4) with every box in ``b`` (M x 4)."""
    x0 = np.maximum(a[:, None, 0], b[None, :, 0])
    y0 = np.maximum(a[:, None, 1], b[None, :, 1])
    x1 = np.minimum(a[:, None, 2], b[None, :, 2])
    y1 = np.minimum(a[:, None, 3], b[None, :, 3])
    inter = np.clip(x1 - x0, 0, None) * np.clip(y1 - y0, 0, None)
    area_a = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
    area_b = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    return inter / np.maximum(area_a[:, None] + area_b[None, :] - inter, 1e-9)
