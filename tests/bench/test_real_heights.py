"""The Oxford bench's tracking scores on hand-made labels and tracks."""

import numpy as np
import pytest

from bench.real_heights import (LABELS, UNCOVERED_KINDS, LabelledPerson, identity_scores, load_labels,
                                 uncovered_breakdown)


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


def box_track(tid: str, x: float, y: float, w: float, h: float) -> dict:
    return {"track_id": tid, "x": str(x), "y": str(y), "w": str(w), "h": str(h)}


def test_uncovered_people_are_told_apart_by_what_lies_over_them():
    # Body boxes 40 x 120 from y = 100: people at x = 100 and 130 walk together, one at 400 alone,
    # one at 700 alone, one at 1000 with nothing near.
    labels = {0: [person(0, 100.0), person(1, 130.0), person(2, 400.0), person(3, 700.0), person(4, 1000.0)]}
    tracks = {0: [box_track("group", 98.0, 100.0, 74.0, 120.0),      # over persons 0 and 1
                  box_track("chest", 400.0, 100.0, 40.0, 50.0),      # ends 70 px above person 2's feet
                  box_track("whole", 701.0, 101.0, 39.0, 118.0)]}    # person 3, covered
    counts = uncovered_breakdown(labels, tracks)
    assert set(counts) == set(UNCOVERED_KINDS) and sum(counts.values()) == 5
    assert counts["covered"] == 2            # person 3, and one of the pair by the group's box (IoU >= 0.5)
    assert counts["under a box holding several"] == 1
    assert counts["box short of the feet"] == 1
    assert counts["no track box near"] == 1


def test_a_box_below_the_crown_or_beside_the_person_is_named_by_that_edge():
    labels = {0: [person(0, 100.0), person(1, 400.0)]}
    tracks = {0: [box_track("low", 100.0, 170.0, 40.0, 50.0),         # starts 70 px below the crown
                  box_track("wide", 400.0, 100.0, 110.0, 120.0)]}     # 70 px past the right side
    counts = uncovered_breakdown(labels, tracks)
    assert counts["box short of the crown"] == 1 and counts["box off to a side"] == 1


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


def test_each_track_is_scored_against_the_person_it_covers_most():
    from bench.real_heights import track_height_errors

    tall = LabelledPerson(1, np.array([400.0, 100.0, 40.0, 120.0]), np.array([420.0, 100.0]),
                          np.array([420.0, 220.0]), True, 1.95)
    labels = {f: [person(0, 100.0), tall] for f in range(10)}
    # Track 7 covers person 0 for 6 frames and the tall person for 2; track 8 only the tall person;
    # track 9 is a person track far from everyone, track 5 not a person track.
    tracks = {f: [track("7", 101.0 if f < 6 else 401.0)] if f < 8 else [track("8", 399.0), track("5", 99.0)]
              for f in range(10)}
    tracks[0].append(track("9", 900.0))
    errors, head_px, foot_px = track_height_errors(labels, tracks, {7: 1.70, 8: 1.90, 9: 1.80})
    assert sorted(np.round(errors, 3)) == [0.05, 0.1]   # 7 against person 0 (1.80), 8 against 1.95
    assert len(head_px) == len(foot_px) == 10           # the boxes of tracks 7 and 8
