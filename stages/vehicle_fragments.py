"""Joining the pieces of one vehicle that object extraction cut apart, along its track's prediction.

Object extraction splits a blob where the height map shows separate peaks (people side by side,
a walker beside a car). On a large vehicle the network's map is not one plateau: the shipped
model reads a 3 m bus's side at 0.5-1.5 m, with patches up to 2 m and its front at 3.5-4 m,
and the facade behind bleeds into its roof line. Those lumps are "peaks", and the bus came out
of extraction as two to four pieces side by side, each taken by a track of its own that fired
a height rule (generator occlusion scene, seq 0: one 3.0 m bus, three firings).

The tracker knows more than one frame's height map: it had the vehicle whole a frame ago, and
predicts where it is now. Detections that lie inside one vehicle track's predicted box, side by
side, and that together fit that box better than any one of them does, are the vehicle's
fragments: they are joined into one detection for it (the counterpart of ``merged_blobs``, which
cuts a blob holding two tracks' predictions). Two vehicles stay two: a piece another track's
prediction explains better is not taken, and a second vehicle's piece reaching outside the
prediction makes the union fit it worse, not better.

The joined detection keeps the network's height of its highest piece (the blob's top, as the
unsplit blob would have been measured) and no geometry channel: the outline, foot and top the
geometry read were a piece's, not the vehicle's.

A box of the network's detection head (``cls_source`` "network") is never joined: the network
drew one box per object.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from core.packets import NETWORK, Detection
from stages.association import intersection_matrix, iou_matrix


@dataclass(frozen=True)
class VehicleFragmentConstants:
    """The fragment join's fixed numbers: shares of boxes, the same for every camera (the rule
    is in docs/design.md, Configuration)."""

    # Tracks of these classes are rigid objects whose pieces are one object; a walker's prediction
    # can hold two people walking together.
    fragment_classes: tuple[str, ...] = ("vehicle",)
    # A detection is a fragment of a prediction when at least this share of its box lies inside
    # the prediction grown by ``margin`` of its size on every side (the prediction is a few pixels
    # off; the pieces are the measurement).
    min_share_inside: float = 0.8
    margin: float = 0.1
    # Fragments side by side share at least this share of the shorter one's rows (as
    # ``merged_blobs``): a vehicle's pieces stand on one road, not one above the other.
    min_shared_rows: float = 0.5
    # A fragment joins only if the union's IoU with the prediction gains at least this much: the
    # pieces together explain the vehicle better than the piece alone.
    min_iou_gain: float = 0.05


CONSTANTS = VehicleFragmentConstants()


def join_fragments(detections: list[Detection], predictions: list[tuple[float, float, float, float]],
                   classes: list[str]) -> list[Detection]:
    """Detections with every vehicle's fragments joined into one.

    ``predictions``: the predicted boxes of the tracks that may claim fragments (x, y, w, h);
    ``classes``: those tracks' classes. Detections no vehicle prediction gathers are returned as
    they are, in their order; a joined detection takes its first fragment's place.
    """
    if not predictions or len(detections) < 2:
        return detections
    boxes = np.asarray(predictions, dtype=float).reshape(-1, 4)
    detection_boxes = np.asarray([d.box for d in detections], dtype=float).reshape(-1, 4)
    iou = iou_matrix(boxes, detection_boxes)
    # Each detection may be a fragment of the one prediction it overlaps most, only.
    owner = np.argmax(iou, axis=0)
    inside = _share_inside(detection_boxes, boxes)
    joined: dict[int, list[int]] = {}
    for track in range(len(boxes)):
        if classes[track] not in CONSTANTS.fragment_classes:
            continue
        candidates = [i for i, detection in enumerate(detections)
                      if owner[i] == track and iou[track, i] > 0 and inside[i, track] >= CONSTANTS.min_share_inside
                      and detection.mask is not None and detection.blob is not None
                      and detection.cls_source != "network"]
        group = _gather(boxes[track], [detection_boxes[i] for i in candidates],
                        [detections[i].blob for i in candidates])
        if len(group) >= 2:
            joined[track] = [candidates[i] for i in group]
    if not joined:
        return detections
    taken = {i: group for group in joined.values() for i in group}
    result = []
    for i, detection in enumerate(detections):
        if i not in taken:
            result.append(detection)
        elif i == taken[i][0]:
            result.append(_join([detections[j] for j in taken[i]]))
    return result


def _share_inside(detection_boxes: np.ndarray, boxes: np.ndarray, margin: float = CONSTANTS.margin) -> np.ndarray:
    """Share of each detection's box inside each box grown by ``margin`` of its size on every side
    (detections x boxes)."""
    grown = boxes.astype(float)
    grown[:, :2] -= margin * boxes[:, 2:]
    grown[:, 2:] *= 1.0 + 2.0 * margin
    areas = detection_boxes[:, 2] * detection_boxes[:, 3]
    return intersection_matrix(detection_boxes, grown) / np.maximum(areas, 1e-9)[:, None]


def _gather(prediction: np.ndarray, candidates: list[np.ndarray], blobs: list[int]) -> list[int]:
    """The candidates whose union fits the prediction best, greedily from the best single one:
    each added piece was cut from the same blob, stands beside those taken and raises the union's
    IoU by ``min_iou_gain``. Separate blobs are separate objects: the foreground parted them."""
    if len(candidates) < 2:
        return []
    single = iou_matrix([prediction], candidates)[0]
    group = [int(np.argmax(single))]
    union, best = candidates[group[0]], float(single.max())
    candidates = [box if blob == blobs[group[0]] else None for box, blob in zip(candidates, blobs)]
    while True:
        gains = []
        for i, box in enumerate(candidates):
            if i in group or box is None or not _beside(box, union):
                continue
            grown = _union(union, box)
            gains.append((float(iou_matrix([prediction], [grown])[0, 0]) - best, i, grown))
        if not gains:
            break
        gain, i, grown = max(gains, key=lambda g: g[0])
        if gain < CONSTANTS.min_iou_gain:
            break
        group.append(i)
        union, best = grown, best + gain
    # Pieces lying within the pieces already taken (the height peaks' pieces overlap in their
    # boxes) add nothing to the fit, and are the same vehicle's pixels.
    rest = [i for i, box in enumerate(candidates) if i not in group and box is not None]
    within = _share_inside(np.asarray([candidates[i] for i in rest]).reshape(-1, 4), union[None], margin=0.0)
    group += [i for i, share in zip(rest, within[:, 0]) if share >= CONSTANTS.min_share_inside]
    return sorted(group) if len(group) >= 2 else []


def _beside(a: np.ndarray, b: np.ndarray) -> bool:
    """Boxes sharing at least ``CONSTANTS.min_shared_rows`` of the shorter one's rows."""
    shared = min(a[1] + a[3], b[1] + b[3]) - max(a[1], b[1])
    return shared >= CONSTANTS.min_shared_rows * min(a[3], b[3])


def _union(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    x0, y0 = min(a[0], b[0]), min(a[1], b[1])
    x1, y1 = max(a[0] + a[2], b[0] + b[2]), max(a[1] + a[3], b[1] + b[3])
    return np.array([x0, y0, x1 - x0, y1 - y0])


def _join(fragments: list[Detection]) -> Detection:
    """One detection of the fragments' pixels: the union box and mask, the highest network height."""
    x0 = int(min(f.box[0] for f in fragments))
    y0 = int(min(f.box[1] for f in fragments))
    x1 = int(max(f.box[0] + f.box[2] for f in fragments))
    y1 = int(max(f.box[1] + f.box[3] for f in fragments))
    mask = np.zeros((y1 - y0, x1 - x0), dtype=bool)
    for fragment in fragments:
        left, top = int(fragment.box[0]) - x0, int(fragment.box[1]) - y0
        height, width = fragment.mask.shape
        mask[top:top + height, left:left + width] |= fragment.mask
    measured = [f.heights[NETWORK] for f in fragments if NETWORK in f.heights and f.heights[NETWORK].usable]
    heights = {NETWORK: max(measured, key=lambda m: m.value_m)} if measured else {}
    centre = (x0 + x1) / 2.0
    return replace(
        fragments[0],
        box=(float(x0), float(y0), float(x1 - x0), float(y1 - y0)),
        heights=heights, cls="vehicle", cls_source="tracking",
        foot_xy=(centre, float(y1)), top_xy=(centre, float(y0)),
        touches_border=any(f.touches_border for f in fragments),
        foot_cut=any(f.foot_cut for f in fragments), top_cut=any(f.top_cut for f in fragments),
        min_height_m=None, ground_xy_m=None, mask=mask, outline=None,
        vehicle_axis_xy=None, vehicle_length_assumed=False,
    )
