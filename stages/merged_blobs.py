"""Splitting a blob that holds several tracked objects, along the tracks' predicted boxes.

When two walkers cross or walk past each other, background subtraction sees one blob: the
object extractor's own splits (foreground gaps, height peaks, heads) need the people to stand
apart. The tracker knows more: it had each of them a frame ago and predicts where they are
now. A detection that contains the predicted boxes of two or more tracks is cut into one piece
per track, each piece the detection's own pixels nearest that track's prediction (as blob
trackers split merged blobs on prediction). On half of the held-out trk_test40 sequences, 435
of 2926 person boxes lay in a blob shared with another person although they had been detected
on their own within the last 15 frames.

A piece's height is not measured (no channel: the blob's top, foot and outline may belong to the
other object), so the pieces move the tracks' boxes only, and their heights hold as through an
occlusion.

A box of the network's detection head (``cls_source`` "network") is never cut: the network drew
one box per object, and a vehicle's box holding people in front of it is not a merged blob.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from core.packets import NETWORK, Detection
from stages.association import intersection_matrix


@dataclass(frozen=True)
class MergedBlobConstants:
    """The merged-blob cut's fixed numbers: shares of the predicted boxes, the same for
    every camera (the rule is in docs/design.md, Configuration)."""

    # A predicted box is inside a detection when this share of it overlaps the detection, and the
    # detection is then at least this many times the box's area (else the box explains the blob).
    min_share_inside: float = 0.6
    min_area_ratio: float = 1.4
    # A prediction is grown by this share of its size on every side when it claims pixels: the
    # prediction is a few pixels off, the silhouette is the measurement.
    claim_margin: float = 0.15
    # No split when more than this share of the blob lies outside every prediction (something not
    # yet tracked is in it), nor when a piece has fewer pixels than this share of what its prediction
    # would hold, or stands less tall than this share of it (Oxford: a 72 px piece given to a track
    # at the frame's top edge shrank its box, and the track went on to a 0.68 m height).
    max_unclaimed_share: float = 0.35
    min_piece_share: float = 0.25
    min_piece_height_share: float = 0.7
    # Predictions standing one on top of the other (sharing less than this share of the shorter one's
    # rows) are two fragments of one object, not two objects (Oxford: a walker at the frame's top
    # edge had a track on its head and one on its legs).
    min_shared_rows: float = 0.2
    # Tracks of these classes only, side by side in one blob, are the fragments of one vehicle (generator
    # dev set: a van coming closer kept two tracks for 30 frames); a walker beside a car is two objects.
    fragment_classes: tuple[str, ...] = ("vehicle",)


CONSTANTS = MergedBlobConstants()


def split_by_predictions(detections: list[Detection], predictions: list[tuple[float, float, float, float]],
                         classes: list[str]) -> list[Detection]:
    """Detections with every blob holding two or more predicted boxes cut into one piece each.

    ``predictions``: the predicted boxes of the tracks that may claim pixels (x, y, w, h);
    ``classes``: those tracks' classes, given to their pieces.
    """
    if len(predictions) < 2:
        return detections
    boxes = np.asarray(predictions, dtype=float).reshape(-1, 4)
    result = []
    for detection in detections:
        inside = np.flatnonzero(_predictions_inside(detection.box, boxes))
        pieces = None
        if (len(inside) >= 2 and detection.mask is not None and detection.cls_source != NETWORK
                and _side_by_side(boxes[inside])
                and any(classes[i] not in CONSTANTS.fragment_classes for i in inside)):
            pieces = _cut(detection, boxes[inside], [classes[i] for i in inside])
        result.extend(pieces or [detection])
    return result


def _predictions_inside(box, boxes: np.ndarray) -> np.ndarray:
    """Bool per predicted box: mostly inside this detection's box, and well smaller than it."""
    overlap = intersection_matrix([box], boxes)[0]
    areas = boxes[:, 2] * boxes[:, 3]
    return ((overlap >= CONSTANTS.min_share_inside * areas) & (areas > 0)
            & (box[2] * box[3] >= CONSTANTS.min_area_ratio * areas))


def _side_by_side(boxes: np.ndarray) -> bool:
    """Every two boxes share at least ``CONSTANTS.min_shared_rows`` of the shorter one's rows."""
    top, bottom = boxes[:, 1], boxes[:, 1] + boxes[:, 3]
    shared = np.minimum(bottom[:, None], bottom[None]) - np.maximum(top[:, None], top[None])
    shorter = np.minimum(boxes[:, 3][:, None], boxes[:, 3][None])
    return bool((shared >= CONSTANTS.min_shared_rows * shorter).all())


def _cut(detection: Detection, boxes: np.ndarray, classes: list[str]) -> list[Detection] | None:
    """One piece per box: the mask pixels inside the grown box, nearest its centre; None = no split."""
    mask = detection.mask
    rows, cols = np.nonzero(mask)
    if rows.size == 0:
        return None
    x = cols + detection.box[0] + 0.5
    y = rows + detection.box[1] + 0.5
    centre_x = boxes[:, 0] + boxes[:, 2] / 2.0
    centre_y = boxes[:, 1] + boxes[:, 3] / 2.0
    # Distance to each box centre in half box sizes: the grown box reaches 1 + 2 x margin.
    dx = np.abs(x[:, None] - centre_x[None]) / (boxes[None, :, 2] / 2.0)
    dy = np.abs(y[:, None] - centre_y[None]) / (boxes[None, :, 3] / 2.0)
    reach = 1.0 + 2.0 * CONSTANTS.claim_margin
    claims = (dx <= reach) & (dy <= reach)
    claimed = claims.any(axis=1)
    if 1.0 - claimed.mean() > CONSTANTS.max_unclaimed_share:
        return None
    owner = np.argmin(np.where(claims, np.hypot(dx, dy), np.inf), axis=1)
    pieces = []
    for index, (box, cls) in enumerate(zip(boxes, classes)):
        mine = claimed & (owner == index)
        if mine.sum() < CONSTANTS.min_piece_share * box[2] * box[3] * mask.mean():
            return None
        r0, r1, c0, c1 = rows[mine].min(), rows[mine].max() + 1, cols[mine].min(), cols[mine].max() + 1
        if r1 - r0 < CONSTANTS.min_piece_height_share * box[3]:
            return None
        piece = np.zeros((r1 - r0, c1 - c0), dtype=bool)
        piece[rows[mine] - r0, cols[mine] - c0] = True
        left, top = detection.box[0] + c0, detection.box[1] + r0
        pieces.append(replace(
            detection,
            box=(float(left), float(top), float(c1 - c0), float(r1 - r0)),
            heights={}, cls=cls, cls_source="tracking",
            foot_xy=(left + (c1 - c0) / 2.0, float(top + r1 - r0)), top_xy=(left + (c1 - c0) / 2.0, float(top)),
            min_height_m=None, ground_xy_m=None, mask=piece, outline=None,
            vehicle_axis_xy=None, vehicle_length_assumed=False,
        ))
    return pieces
