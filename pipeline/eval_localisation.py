"""How much of the tracking score the boxes' fit loses: the MOT metrics again with boxes put right.

HOTA is the mean of detection and association accuracy over IoU thresholds from 0.05 to 0.95. A
track on the right object whose box is a pixel or two off still counts at the low thresholds and
not at the high ones; for a walker 14 px wide, one pixel on each side is already an IoU of 0.87.
So a low HOTA may be objects missed, or objects found and boxed loosely, and the two call for
different work (a better detector against a better box). ``eval-tracks`` shows DetA and AssA at
five thresholds; this says which part of the box the loss is in.

Each reported box that is about a required object (matched one-to-one to the truth at IoU >= the
misses' "box off" threshold, ``CONSTANTS.miss_near_iou``) is given that object's true horizontal
extent (left and right edges), its true vertical extent (top and bottom), or both, and the runs
are scored again. Nothing else changes: the same boxes exist, with the same track ids, so what a
row gains over the reported score is what better boxes of that kind, and only they, could give.
Boxes on nothing, and boxes that best fit an object too hidden or too small to be required, stay
as they are.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from pipeline.eval_metrics import CONSTANTS, cared_for, matched_at_iou, mot_data, mot_metrics
from pipeline.eval_sequences import FrameRecord, SequenceRun

PUT_RIGHT = {
    "horizontal extent": (0, 2),
    "vertical extent": (1, 3),
    "whole box": (0, 1, 2, 3),
}
"""What each row gives the boxes from the truth: indices into a box (x, y, w, h)."""


def localisation_headroom(runs: list[SequenceRun], min_visibility: float, min_box_px: float = 0.0,
                          use_trackeval: bool | None = None) -> dict[str, dict[str, float]]:
    """HOTA, DetA, AssA and IDF1 of the runs with each of ``PUT_RIGHT``'s parts of the boxes
    taken from the objects they are about (the reported scores are ``evaluate``'s "mot")."""
    rows = {}
    for name, parts in PUT_RIGHT.items():
        fixed = [_with_boxes_put_right(run, parts, min_visibility, min_box_px) for run in runs]
        mot = mot_metrics([mot_data(run, min_visibility, min_box_px) for run in fixed], use_trackeval)
        rows[name] = {key: mot[key] for key in ("HOTA", "DetA", "AssA", "IDF1")}
    return rows


def _with_boxes_put_right(run: SequenceRun, parts: tuple[int, ...], min_visibility: float,
                          min_box_px: float) -> SequenceRun:
    """A copy of ``run`` whose scored boxes take ``parts`` from the required object each is about."""
    return replace(run, frames=[_frame_put_right(frame, parts, min_visibility, min_box_px) for frame in run.frames])


def _frame_put_right(frame: FrameRecord, parts: tuple[int, ...], min_visibility: float,
                     min_box_px: float) -> FrameRecord:
    """The frame with only its scored boxes (``seen_tracks``: the copy is for the MOT metrics,
    which score no others), those about a required object put right."""
    scored = frame.seen_tracks
    # Matched over all the truth, so that a box on a don't-care object is not pulled onto a
    # required one beside it.
    pairs = matched_at_iou([t.box for t in frame.truth], [o.box for o in scored], CONSTANTS.miss_near_iou)
    for row, col in pairs:
        truth = frame.truth[row]
        if not cared_for(truth, min_visibility, min_box_px):
            continue
        box = np.array(scored[col].box, dtype=float)
        box[list(parts)] = np.asarray(truth.box, dtype=float)[list(parts)]
        scored[col] = replace(scored[col], box=tuple(float(v) for v in box))
    return replace(frame, tracks=scored)
