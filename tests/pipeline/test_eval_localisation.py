"""The scores with the boxes put right (``eval-tracks --localisation``) on hand-made sequences."""

from __future__ import annotations

import pytest

from pipeline.eval_localisation import localisation_headroom
from pipeline.eval_metrics import mot_data, mot_metrics
from pipeline.eval_reports import format_localisation
from pipeline.eval_sequences import FrameRecord, OutputBox, SequenceRun, TruthBox


def _truth(object_id, x, visibility=1.0, y=50.0):
    return TruthBox(object_id, "person", (x, y, 20.0, 60.0), visibility, 1.75)


def _out(track_id, box, updated=True):
    return OutputBox(track_id, box, 1.75, 0.02, "person", "network", updated)


def _run(frames):
    return SequenceRun("seq", 5.0, "clear", "day", 10.0, frames)


def _reported(runs):
    return mot_metrics([mot_data(run, 0.3) for run in runs], use_trackeval=False)


def _headroom(runs):
    return localisation_headroom(runs, 0.3, use_trackeval=False)


def test_boxes_off_to_the_side_are_scored_as_found_once_their_horizontal_extent_is_right():
    # Every walker found, each box 6 px too wide on the right: IoU 20 / 26 = 0.77.
    frames = [FrameRecord([_truth(1, 10 + 3 * i)], [_out(7, (10 + 3 * i, 50.0, 26.0, 60.0))], [])
              for i in range(20)]
    reported, rows = _reported([_run(frames)]), _headroom([_run(frames)])
    assert reported["HOTA"] < 0.9
    assert rows["horizontal extent"]["HOTA"] == pytest.approx(1.0)
    assert rows["whole box"]["HOTA"] == pytest.approx(1.0)
    assert rows["vertical extent"]["HOTA"] == pytest.approx(reported["HOTA"])


def test_boxes_too_short_gain_from_their_vertical_extent_only():
    frames = [FrameRecord([_truth(1, 10 + 3 * i)], [_out(7, (10 + 3 * i, 58.0, 20.0, 52.0))], [])
              for i in range(20)]
    reported, rows = _reported([_run(frames)]), _headroom([_run(frames)])
    assert rows["vertical extent"]["HOTA"] == pytest.approx(1.0)
    assert rows["horizontal extent"]["HOTA"] == pytest.approx(reported["HOTA"])


def test_exact_boxes_gain_nothing_and_a_box_on_nothing_stays_a_false_positive():
    frames = [FrameRecord([_truth(1, 10 + 3 * i)],
                          [_out(7, (10 + 3 * i, 50.0, 20.0, 60.0)), _out(8, (200.0, 100.0, 20.0, 60.0))], [])
              for i in range(20)]
    reported, rows = _reported([_run(frames)]), _headroom([_run(frames)])
    assert reported["HOTA"] < 0.9    # the box on nothing costs detection accuracy
    for row in rows.values():
        assert row["HOTA"] == pytest.approx(reported["HOTA"])
        assert row["IDF1"] == pytest.approx(reported["IDF1"])


def test_a_box_on_a_hidden_object_is_not_pulled_onto_the_required_one_beside_it():
    # The box lies on the hidden walker (don't-care, dropped from the scores) and reaches the
    # required walker beside it at IoU 0.25: it is about the hidden one, so it stays.
    box = (40.0, 50.0, 20.0, 60.0)
    frames = [FrameRecord([_truth(1, 28.0), _truth(2, 40.0, visibility=0.1)], [_out(7, box)], [])
              for _ in range(10)]
    reported, rows = _reported([_run(frames)]), _headroom([_run(frames)])
    assert reported["HOTA"] == pytest.approx(0.0)
    assert rows["whole box"]["HOTA"] == pytest.approx(0.0)


def test_predicted_boxes_are_left_as_they_are():
    # Coasting boxes are not scored (the tracker's guess), so they are not put right either.
    frames = [FrameRecord([_truth(1, 10.0)], [_out(7, (16.0, 50.0, 20.0, 60.0), updated=i % 2 == 0)], [])
              for i in range(10)]
    rows = _headroom([_run(frames)])
    assert rows["whole box"]["DetA"] == pytest.approx(0.5)    # half the frames' boxes scored, all right


def test_the_table_shows_each_row_beside_the_reported_scores():
    frames = [FrameRecord([_truth(1, 10 + 3 * i)], [_out(7, (10 + 3 * i, 50.0, 26.0, 60.0))], [])
              for i in range(20)]
    text = format_localisation(_headroom([_run(frames)]), _reported([_run(frames)]))
    lines = text.splitlines()
    assert lines[2].split()[:3] == ["boxes", "as", "reported"]
    horizontal = next(line for line in lines if line.strip().startswith("horizontal extent right"))
    assert "1.000 (+" in horizontal
    assert all(line == line.rstrip() for line in lines)
