"""Held-out scores of a HeightNet v2 network, as the issue states them.

On each held-out frame (whole frame, the run-time input) heights are decoded twice: with the
true camera, and with only the true camera *height* — pitch, roll and focal length from the
camera heads, averaged over the sequence's frames as a fixed camera would be.

* object-top error: per mover with at least ``min_pixels`` input pixels, the 98th percentile of
  the decoded heights on its (true) pixels against its highest true height; median |error| per
  class group (people, cyclists, cars/vans, trucks/buses);
* mover-pixel RMSE (true height > 0.1 m on a mover) per camera-height row, with and without
  trucks and buses;
* the camera heads' median pitch error (degrees), focal-length error and horizon error (per cent;
  the horizon's height above the image centre, f tan(pitch): what heights from a camera height
  depend on most);
* with a detection head: per class, the share of true boxes (at least ``MIN_BOX_PX`` tall at the
  input size) found at IoU >= 0.5 and score >= ``DETECTION_SCORE`` (recall), and the share of
  detections that match a true box (precision).
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass, field
from typing import Sequence

import cv2
import numpy as np
import torch

from stages.camera_heads import camera_from_heads
from stages.ground_contact import PinholeCamera, heights_from_offsets
from stages.centre_detections import CentreDetections, box_iou, centre_detections, with_big_objects
from stages.heightnet_model import CONSTANTS as MODEL_CONSTANTS
from heightnet.contact_data import CLASS_GROUPS, ContactSequence, camera_channels, camera_targets
from heightnet.contact_model import BIG_STRIDE, DETECTION_CLASSES
from heightnet.detection_targets import window_boxes
from heightnet.normalisation import normalise
from synth.dataset import CLASS_NAMES

GROUPS = ("person", "cyclist", "car/van", "truck/bus")
# Decoded heights are clipped as the run-time stage clips them: nothing stands below the ground,
# and a contact point predicted at the horizon must not decode to kilometres.
MAX_HEIGHT_M = 50.0
BIG = "truck/bus"
DETECTION_SCORE = 0.3
MATCH_IOU = 0.5


@dataclass
class Scores:
    top_error_cm: dict[str, float] = field(default_factory=dict)        # true camera
    top_error_heads_cm: dict[str, float] = field(default_factory=dict)  # camera height only
    objects: dict[str, int] = field(default_factory=dict)
    rmse_cm: dict[str, float] = field(default_factory=dict)             # per row, no trucks/buses
    rmse_all_cm: dict[str, float] = field(default_factory=dict)         # per row, every mover
    rmse_heads_cm: dict[str, float] = field(default_factory=dict)
    pitch_error_deg: float = float("nan")
    focal_error_pct: float = float("nan")
    roll_error_deg: float = float("nan")
    horizon_error_pct: float = float("nan")
    detection_recall: dict[str, float] = field(default_factory=dict)    # per detection class
    detection_precision: float = float("nan")


def predict(net: torch.nn.Module, rgb: np.ndarray, width: int, height: int,
            camera: PinholeCamera | None = None,
            previous_rgb: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, CentreDetections | None]:
    """Offsets H x W x 2 (input pixels), camera-head outputs (6) and, with a detection head,
    the detected boxes (input pixels) for one whole frame. ``previous_rgb``: the frame before,
    for a detection head that reads motion (None: no change, as on a run's first frame)."""
    def network_input(image: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(normalise(cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)))[None]

    arch = getattr(net, "arch", None)
    channels, motion = None, {}
    if arch is not None and arch.camera_channels:
        channels = torch.from_numpy(camera_channels(camera, width, height))[None]
    if arch is not None and arch.detection_motion and previous_rgb is not None:
        motion["previous"] = network_input(previous_rgb)
    with torch.no_grad():
        offsets, _, cam, *detection = net(network_input(rgb), channels, **motion)
    found = None
    if detection:
        centre, box = (t[0].numpy() for t in detection[:2])
        found = centre_detections(centre, box, arch.detection_stride, DETECTION_SCORE)
        if len(detection) == 4:   # the big-object head's peaks join the small head's, as at run time
            big_centre, big_box = (t[0].numpy() for t in detection[2:])
            found = with_big_objects(found, big_centre, big_box, BIG_STRIDE, DETECTION_SCORE,
                                     MODEL_CONSTANTS.big_min_height_px)
    return offsets[0].permute(1, 2, 0).numpy(), cam[0].numpy(), found


def evaluate(net: torch.nn.Module, sequences: Sequence[ContactSequence], width: int, height: int,
             min_pixels: int = 20, frames: int = 2, whole_boxes: bool = False) -> Scores:
    """Held-out scores of ``net`` (``whole_boxes``: detections are scored against boxes of the
    whole objects, as ``train_v2.whole_boxes`` trains them)."""
    was_training = net.training
    net.eval()
    tops: dict[str, list[float]] = defaultdict(list)
    tops_heads: dict[str, list[float]] = defaultdict(list)
    sq: dict[str, list[np.ndarray]] = defaultdict(list)
    sq_all: dict[str, list[np.ndarray]] = defaultdict(list)
    sq_heads: dict[str, list[np.ndarray]] = defaultdict(list)
    pitch_err, focal_err, roll_err, horizon_err = [], [], [], []
    found_true: dict[int, list[bool]] = defaultdict(list)
    detections_matched: list[bool] = []
    reads_motion = getattr(getattr(net, "arch", None), "detection_motion", False)
    for seq in sequences:
        _, src_h, src_w, _ = seq.rgb.shape
        true_camera = seq.camera.window(0, 0, src_w, src_h, width, height)
        row = f"{seq.camera.height_m * 100:.0f}"
        used = range(min(frames, len(seq)))
        outputs = [predict(net, np.asarray(seq.rgb[t]), width, height, true_camera,
                           np.asarray(seq.rgb[_other_frame(t, len(seq))]) if reads_motion else None)
                   for t in used]
        mean_camera = np.mean([cam for _, cam, _ in outputs], axis=0)
        head_camera = camera_from_heads(mean_camera, width, height, (src_w, src_h), seq.camera.height_m)
        truth_cam = camera_targets(true_camera, height)
        pitch_err.append(abs(math.degrees(mean_camera[0] - truth_cam[0])))
        roll_err.append(abs(math.degrees(mean_camera[1] - truth_cam[1])))
        focal_err.append(abs(math.exp(mean_camera[2] - truth_cam[2]) - 1) * 100)
        horizon_err.append(abs(_horizon(mean_camera) / _horizon(truth_cam) - 1) * 100)
        for t, (offsets, _, found) in zip(used, outputs):
            if found is not None:
                truths = window_boxes(np.asarray(seq.instance[t]), np.asarray(seq.semantic[t]),
                                      width / src_w, height / src_h, False, width,
                                      seq.whole_boxes(t) if whole_boxes else None)
                _match_detections(found, truths, found_true, detections_matched)
            truth, instance, semantic = frame_labels(seq, t, width, height)
            pred = np.clip(heights_from_offsets(true_camera, offsets), 0, MAX_HEIGHT_M)
            pred_heads = np.clip(heights_from_offsets(head_camera, offsets), 0, MAX_HEIGHT_M)
            mover = (instance > 0) & np.isfinite(truth) & (truth > 0.1)
            big = np.zeros_like(mover)
            for group, pixels in labelled_objects(truth, instance, semantic):
                if group == BIG:
                    big |= pixels
                if pixels.sum() < min_pixels:
                    continue
                tops[group].append(top_error(pred, truth, pixels))
                tops_heads[group].append(top_error(pred_heads, truth, pixels))
            sq_all[row].append((pred - truth)[mover] ** 2)
            sq[row].append((pred - truth)[mover & ~big] ** 2)
            sq_heads[row].append((pred_heads - truth)[mover & ~big] ** 2)
    net.train(was_training)
    scores = Scores()
    for group in GROUPS:
        if tops[group]:
            scores.top_error_cm[group] = float(np.median(tops[group]) * 100)
            scores.top_error_heads_cm[group] = float(np.median(tops_heads[group]) * 100)
            scores.objects[group] = len(tops[group])
    for source, dest in ((sq, scores.rmse_cm), (sq_all, scores.rmse_all_cm), (sq_heads, scores.rmse_heads_cm)):
        for row in sorted(source, key=float):
            values = np.concatenate(source[row])
            dest[row] = float(np.sqrt(values.mean()) * 100) if len(values) else float("nan")
        values = np.concatenate([np.concatenate(v) for v in source.values()]) if source else np.zeros(0)
        dest["all"] = float(np.sqrt(values.mean()) * 100) if len(values) else float("nan")
    scores.pitch_error_deg = float(np.median(pitch_err))
    scores.roll_error_deg = float(np.median(roll_err))
    scores.focal_error_pct = float(np.median(focal_err))
    scores.horizon_error_pct = float(np.median(horizon_err))
    for index, name in enumerate(DETECTION_CLASSES):
        if found_true[index]:
            scores.detection_recall[name] = float(np.mean(found_true[index]))
    if detections_matched:
        scores.detection_precision = float(np.mean(detections_matched))
    return scores


def _other_frame(t: int, frames: int) -> int:
    """The frame a motion-reading head compares frame ``t`` with: the one before, and for the
    first frame the one after, as training pairs them (``contact_train.pair_previous``)."""
    return t - 1 if t > 0 else min(1, frames - 1)


def frame_labels(seq: ContactSequence, t: int, width: int, height: int
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frame ``t``'s true heights, instance ids and classes at the input size (nearest)."""
    def nearest(array: np.ndarray) -> np.ndarray:
        return cv2.resize(array, (width, height), interpolation=cv2.INTER_NEAREST_EXACT)

    return (nearest(np.asarray(seq.height_m[t], np.float32)), nearest(np.asarray(seq.instance[t])),
            nearest(np.asarray(seq.semantic[t])))


def labelled_objects(truth: np.ndarray, instance: np.ndarray, semantic: np.ndarray):
    """(class group, pixels) of every mover whose class is scored (``CLASS_GROUPS``)."""
    for obj in np.unique(instance[instance > 0]):
        pixels = (instance == obj) & np.isfinite(truth)
        cls = CLASS_NAMES[np.bincount(semantic[pixels]).argmax()] if pixels.any() else ""
        group = CLASS_GROUPS.get(cls)
        if group is not None:
            yield group, pixels


def top_error(pred: np.ndarray, truth: np.ndarray, pixels: np.ndarray) -> float:
    """|98th percentile of the decoded heights on the object's pixels - its highest true height| (m)."""
    return abs(float(np.percentile(pred[pixels], 98)) - float(truth[pixels].max()))


def _horizon(camera: np.ndarray) -> float:
    """The horizon's height above the image centre in image heights: f tan(pitch)."""
    return math.exp(camera[2]) * math.tan(camera[0])


def _match_detections(found: CentreDetections, truths: list, found_true: dict[int, list[bool]],
                      detections_matched: list[bool]) -> None:
    """Greedy one-to-one matching per class in score order (IoU >= MATCH_IOU)."""
    for index in range(len(DETECTION_CLASSES)):
        true_boxes = np.array([[b.x0, b.y0, b.x1, b.y1] for b in truths if b.cls == index], np.float32).reshape(-1, 4)
        mine = found.classes == index
        boxes = found.boxes[mine]
        taken = np.zeros(len(true_boxes), bool)
        if len(boxes) and len(true_boxes):
            iou = box_iou(boxes, true_boxes)
            for row in iou:   # detections come in score order
                row = np.where(taken, 0.0, row)
                best = int(row.argmax())
                hit = row[best] >= MATCH_IOU
                taken[best] |= hit
                detections_matched.append(bool(hit))
        else:
            detections_matched.extend([False] * len(boxes))
        found_true[index].extend(taken.tolist())


def scores_row(scores: Scores) -> dict[str, float]:
    """A flat dict for CSV logs and tables."""
    row: dict[str, float] = {}
    for group in GROUPS:
        key = group.replace("/", "_")
        row[f"top_{key}_cm"] = scores.top_error_cm.get(group, float("nan"))
        row[f"top_heads_{key}_cm"] = scores.top_error_heads_cm.get(group, float("nan"))
    row["rmse_cm"] = scores.rmse_cm.get("all", float("nan"))
    row["rmse_all_cm"] = scores.rmse_all_cm.get("all", float("nan"))
    row["rmse_heads_cm"] = scores.rmse_heads_cm.get("all", float("nan"))
    row["rmse_worst_row_cm"] = max((v for k, v in scores.rmse_cm.items() if k != "all"), default=float("nan"))
    row["pitch_error_deg"] = scores.pitch_error_deg
    row["roll_error_deg"] = scores.roll_error_deg
    row["focal_error_pct"] = scores.focal_error_pct
    row["horizon_error_pct"] = scores.horizon_error_pct
    for name in DETECTION_CLASSES:
        row[f"det_recall_{name}"] = scores.detection_recall.get(name, float("nan"))
    row["det_precision"] = scores.detection_precision
    return row
