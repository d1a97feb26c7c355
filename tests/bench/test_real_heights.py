"""The Oxford bench's tracking scores on hand-made labels and tracks."""

import numpy as np
import pytest

from bench.real_heights import LABELS, LabelledPerson, identity_scores, load_labels


def person(pid: int, x: float) -> LabelledPerson:
    return LabelledPerson(pid, np.array([x, 100.0, 40.0, 120.0]), np.array([x + 20, 100.0]),
                          np.array([x + 20, 220.0]), True, 1.8)


def track(tid: str, x: float) -> dict:
    return {"track_id": tid, "x": str(x), "y": "102", "w": "38", "h": "116"}


def test_a_switch_halfway_costs_identity_recall_not_coverage():
    labels = {f: [person(0, 100.0), person(1, 400.0)] for f in range(10)}
    # Person 0 is followed by track "a" for 5 frames, then by "b"; person 1 by "c" in 8 of 10 frames.
    tracks = {f: [track("a" if f < 5 else "b", 101.0)] + ([track("c", 399.0)] if f < 8 else [])
              for f in range(10)}
    scores = identity_scores(labels, tracks)
    assert scores.person_frames == 20 and scores.people == 2
    assert scores.covered == 18 / 20
    assert scores.id_recall == (5 + 8) / 20           # one id per person: "a" (or "b") and "c"
    assert scores.id_switches == 1
    assert scores.mostly_tracked == 2                 # 10/10 and 8/10 frames covered


def test_a_box_off_the_person_does_not_count():
    labels = {0: [person(0, 100.0)]}
    far = identity_scores(labels, {0: [track("a", 150.0)]})   # IoU ~0.1 with the body box
    assert far.covered == 0.0 and far.id_recall == 0.0 and far.mostly_tracked == 0
    none = identity_scores(labels, {})
    assert none.covered == 0.0 and none.id_switches == 0


@pytest.mark.skipif(not LABELS.is_file(), reason="needs ../shared/real/oxford_towncentre")
@pytest.mark.parametrize("undistort", [False, True])
def test_labelled_boxes_end_at_the_frame_edge(undistort):
    """A walker half out of view is scored against the half a track can box."""
    people = [p for frame in load_labels(undistort).values() for p in frame]
    boxes = np.array([p.box for p in people])
    assert (boxes[:, :2] >= 0).all() and (boxes[:, 0] + boxes[:, 2] <= 1920).all()
    assert (boxes[:, 1] + boxes[:, 3] <= 1080).all() and (boxes[:, 2:] > 0).all()
    # Some feet are labelled below the frame's bottom: their boxes end at it.
    assert any(p.foot[1] > 1080 and p.box[1] + p.box[3] == 1080 for p in people)
