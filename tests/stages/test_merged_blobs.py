"""Splitting a merged blob along the tracks' predicted boxes."""

from __future__ import annotations

import numpy as np

from core.config import TrackingConfig
from core.packets import NETWORK, Detection, Measurement
from stages.association import iou_matrix
from stages.merged_blobs import split_by_predictions
from stages.tracking import ObjectTracker


def _merged(boxes: list[tuple[int, int, int, int]], height_m: float = 1.9) -> Detection:
    """One detection whose mask is the union of these person boxes (as one blob)."""
    x0 = min(b[0] for b in boxes)
    y0 = min(b[1] for b in boxes)
    x1 = max(b[0] + b[2] for b in boxes)
    y1 = max(b[1] + b[3] for b in boxes)
    mask = np.zeros((y1 - y0, x1 - x0), dtype=bool)
    for x, y, w, h in boxes:
        mask[y - y0:y - y0 + h, x - x0:x - x0 + w] = True
    return Detection(box=(float(x0), float(y0), float(x1 - x0), float(y1 - y0)),
                     heights={NETWORK: Measurement(height_m, 0.15, "test")}, cls="vehicle", mask=mask)


def test_a_blob_holding_two_predictions_is_cut_into_one_piece_each():
    left, right = (100, 50, 30, 80), (122, 56, 30, 80)            # overlapping walkers
    merged = _merged([left, right])
    pieces = split_by_predictions([merged], [(98, 51, 30, 80), (124, 55, 30, 80)], ["person", "person"])
    assert len(pieces) == 2
    iou = iou_matrix([p.box for p in pieces], [left, right])
    assert iou[0, 0] > 0.6 and iou[1, 1] > 0.6
    # The blob's top may be the other person's: a piece carries no height of its own.
    assert all(p.heights == {} and p.min_height_m is None for p in pieces)
    assert [(p.cls, p.cls_source) for p in pieces] == [("person", "tracking")] * 2
    assert all(p.mask.shape == (int(p.box[3]), int(p.box[2])) and p.mask.any() for p in pieces)


def test_no_cut_for_one_prediction_a_box_that_explains_the_blob_or_an_unclaimed_rest():
    merged = _merged([(100, 50, 30, 80), (122, 56, 30, 80)])
    # One prediction inside: nothing to share out.
    assert split_by_predictions([merged], [(98, 51, 30, 80)], ["person"]) == [merged]
    # A prediction as big as the blob (the track that has the blob) and one inside it.
    whole = merged.box
    assert split_by_predictions([merged], [whole, (98, 51, 30, 80)], ["person"] * 2) == [merged]
    # Half of the blob lies outside both predictions: something untracked is in it.
    wide = _merged([(100, 50, 30, 80), (122, 56, 30, 80), (170, 50, 60, 80)])
    assert split_by_predictions([wide], [(98, 51, 30, 80), (124, 55, 30, 80)], ["person"] * 2) == [wide]
    # Two tracks one above the other are fragments of one object (head and legs), not two.
    tall = _merged([(100, 0, 40, 120)])
    assert split_by_predictions([tall], [(100, 0, 40, 60), (100, 58, 40, 62)], ["person"] * 2) == [tall]
    # A piece much shorter than its prediction is a fragment, not the object.
    pair = _merged([(100, 50, 30, 80), (130, 90, 30, 40)])
    assert split_by_predictions([pair], [(100, 50, 30, 80), (130, 50, 30, 80)], ["person"] * 2) == [pair]


def test_walkers_who_pass_close_keep_their_own_boxes_ids_and_heights():
    tracker = ObjectTracker(TrackingConfig())
    heights = {"a": 1.60, "b": 1.90}
    ids: dict[str, set[int]] = {"a": set(), "b": set()}
    merged_frames_ok = 0
    for frame in range(50):
        # a walks right, b (nearer the camera, lower in the image) walks left: one blob while
        # their boxes touch (frames 21-29).
        a = (40 + 3 * frame, 100, 24, 70)
        b = (190 - 3 * frame, 130, 24, 70)
        overlapping = abs(a[0] - b[0]) < 26
        if overlapping:
            detections = [_merged([a, b], height_m=1.90)]
        else:
            detections = [Detection(box=tuple(map(float, box)), cls="person",
                                    heights={NETWORK: Measurement(heights[name], 0.1, "test")})
                          for name, box in (("a", a), ("b", b))]
        tracks = [t for t in tracker.update(detections) if t.confirmed]
        if frame < 5:
            continue
        iou = iou_matrix([t.box for t in tracks], [a, b])
        for column, name in enumerate(("a", "b")):
            ids[name].add(tracks[int(np.argmax(iou[:, column]))].track_id)
        if overlapping:
            merged_frames_ok += int(iou[:, 0].max() >= 0.5 and iou[:, 1].max() >= 0.5)
    assert len(ids["a"]) == 1 and len(ids["b"]) == 1 and ids["a"] != ids["b"]
    assert merged_frames_ok >= 6          # without the split: 0 (one track takes the blob)
    final = {t.track_id: t.height_m for t in tracks}
    assert abs(final[ids["a"].pop()] - heights["a"]) < 0.03
    assert abs(final[ids["b"].pop()] - heights["b"]) < 0.03


def test_two_vehicle_tracks_in_one_blob_are_one_vehicle_not_cut():
    tracker = ObjectTracker(TrackingConfig())
    front, back = (100, 50, 40, 40), (138, 46, 40, 44)          # a van's cab and box, seen apart
    for frame in range(6):
        tracker.update([Detection(box=tuple(map(float, b)), heights={NETWORK: Measurement(2.6, 0.1, "test")},
                                  cls="vehicle") for b in (front, back)])
    whole = _merged([front, back], height_m=2.6)
    tracks = [t for t in tracker.update([whole]) if t.updated]
    assert len(tracks) == 1 and iou_matrix([tracks[0].box], [whole.box])[0, 0] > 0.8
