"""Detection recall and precision before tracking (eval-tracks), on hand-made frames with known answers."""

from __future__ import annotations

import dataclasses
import json

import pytest

from core.packets import NETWORK, Detection, Measurement
from pipeline.eval_metrics import detection_scores, evaluate, size_group
from pipeline.eval_reports import format_report, json_default
from pipeline.eval_sequences import (DetectionBox, FrameRecord, OutputBox, SequenceRun, TruthBox, detection_record,
                                     eval_class)


def _truth(object_id, cls, x, h=60.0, visibility=1.0):
    return TruthBox(object_id, cls, (x, 50.0, 20.0, h), visibility, 1.75)


def _det(cls, x, h=60.0):
    return DetectionBox((x, 50.0, 20.0, h), 1.75, cls)


# One frame of a clear day (camera 5 m):
#   1 person   found by a person detection                   (found, class right)
#   2 person   found by a "vehicle" detection                (found, class wrong)
#   3 cyclist  a cyclist detection 15 px aside (IoU 0.14)    (missed; the detection is wrong)
#   4 vehicle  170 px high, found by a vehicle detection     (found, class right)
#   5 person   30 px high, no detection                      (missed)
#   6 person   10 % visible (don't care), a detection on it  (neither counted)
#   and an "other" detection on nothing                      (wrong)
CLEAR_DAY = FrameRecord(
    truth=[_truth(1, "person", 0.0), _truth(2, "person", 100.0), _truth(3, "cyclist", 200.0),
           _truth(4, "vehicle", 300.0, h=170.0), _truth(5, "person", 400.0, h=30.0),
           _truth(6, "person", 500.0, visibility=0.1)],
    tracks=[],
    detections=[_det("person", 0.0), _det("vehicle", 100.0), _det("cyclist", 215.0),
                _det("vehicle", 300.0, h=170.0), _det("person", 500.0), _det("other", 600.0)],
)
# Two frames of a rainy night (camera 5 m): the person found in one of them; one false detection.
RAINY_NIGHT = [
    FrameRecord([_truth(1, "person", 0.0)], [], [_det("person", 2.0)]),
    FrameRecord([_truth(1, "person", 10.0)], [], [_det("person", 300.0)]),
]


def _runs():
    return [SequenceRun("dry", 5.0, "clear", "day", 10.0, [CLEAR_DAY]),
            SequenceRun("wet", 5.0, "rain", "night", 10.0, RAINY_NIGHT)]


@pytest.fixture(scope="module")
def table():
    return detection_scores(_runs(), min_visibility=0.3, min_box_px=0.0)


# group: (truths, found, found_class, detections, correct, correct_class)
EXPECTED = {
    "all":              (7, 4, 3, 7, 4, 3),
    "class person":     (5, 3, 2, 3, 2, 2),
    "class cyclist":    (1, 0, 0, 1, 0, 0),
    "class vehicle":    (1, 1, 1, 2, 2, 1),
    "class other":      (0, 0, 0, 1, 0, 0),
    "box < 40 px":      (1, 0, 0, 0, 0, 0),
    "box 40-80 px":     (5, 3, 2, 6, 3, 2),
    "box >= 160 px":    (1, 1, 1, 1, 1, 1),
    "weather clear":    (5, 3, 2, 5, 3, 2),
    "day":              (5, 3, 2, 5, 3, 2),
    "weather rain":     (2, 1, 1, 2, 1, 1),
    "night":            (2, 1, 1, 2, 1, 1),
    "camera at 5.0 m":  (7, 4, 3, 7, 4, 3),
}


@pytest.mark.parametrize("group", sorted(EXPECTED))
def test_counts_per_group(table, group):
    row = table[group]
    counts = (row["truths"], row["found"], row["found_class"], row["detections"], row["correct"],
              row["correct_class"])
    assert counts == EXPECTED[group]


@pytest.mark.parametrize("group, recall, precision, class_recall, class_precision", [
    ("all",           4 / 7, 4 / 7, 3 / 7, 3 / 7),
    ("class person",  3 / 5, 2 / 3, 2 / 5, 2 / 3),
    ("class cyclist", 0.0,   0.0,   0.0,   0.0),
    ("class vehicle", 1.0,   1.0,   1.0,   0.5),     # the vehicle detection on person 2: right box, wrong class
    ("class other",   None,  0.0,   None,  0.0),     # no truth to recall
    ("box < 40 px",   0.0,   None,  0.0,   None),    # no detection to be precise about
    ("box 40-80 px",  3 / 5, 1 / 2, 2 / 5, 1 / 3),
    ("weather rain",  0.5,   0.5,   0.5,   0.5),
])
def test_recall_and_precision_per_group(table, group, recall, precision, class_recall, class_precision):
    row = table[group]
    for key, expected in (("recall", recall), ("precision", precision), ("class_recall", class_recall),
                          ("class_precision", class_precision)):
        assert row[key] == (None if expected is None else pytest.approx(expected)), key


def test_groups_without_boxes_are_left_out_and_rows_come_in_order(table):
    assert "box 80-160 px" not in table
    assert list(table)[:9] == ["all", "class person", "class cyclist", "class vehicle", "class other",
                               "box < 40 px", "box 40-80 px", "box >= 160 px", "camera at 5.0 m"]


def test_small_boxes_are_dont_care_for_detections_too():
    """With boxes under 40 px don't-care (``--min-box-px 40``) person 5 is no longer required."""
    table = detection_scores(_runs()[:1], min_visibility=0.3, min_box_px=40.0)
    assert table["all"]["truths"] == 4 and "box < 40 px" not in table


def test_matching_is_one_to_one():
    """Two detections on one object: one is correct, the other a false positive."""
    frame = FrameRecord([_truth(1, "person", 0.0)], [], [_det("person", 0.0), _det("person", 1.0)])
    row = detection_scores([SequenceRun("s", 5.0, "clear", "day", 10.0, [frame])], 0.3)["all"]
    assert (row["recall"], row["precision"], row["class_precision"]) == (1.0, 0.5, 0.5)


@pytest.mark.parametrize("height_px, group", [
    (39.9, "box < 40 px"), (40.0, "box 40-80 px"), (79.9, "box 40-80 px"), (80.0, "box 80-160 px"),
    (159.9, "box 80-160 px"), (160.0, "box >= 160 px"),
])
def test_size_bands(height_px, group):
    assert size_group((0.0, 0.0, 10.0, height_px)) == group


@pytest.mark.parametrize("name, cls", [
    ("pedestrian", "person"), ("cyclist", "cyclist"), ("car", "vehicle"), ("van", "vehicle"),
    ("truck", "vehicle"), ("bus", "vehicle"),                     # the generator's classes
    ("person", "person"), ("vehicle", "vehicle"), ("other", "other"),   # object extraction's
    ("tree", "other"),
])
def test_generator_and_pipeline_classes_meet_in_three_names(name, cls):
    assert eval_class(name) == cls


def test_a_pipeline_detection_is_recorded_with_its_box_and_class():
    detection = Detection(box=(1, 2, 3, 4), cls="cyclist")
    detection.add_height(NETWORK, Measurement(1.7, 0.1, "network"))
    record = detection_record(detection)
    assert record == DetectionBox((1.0, 2.0, 3.0, 4.0), 1.7, "cyclist")


def test_the_report_prints_and_writes_the_detection_table():
    report = evaluate(_runs(), use_trackeval=False, min_box_px=0.0)
    assert report["detection"]["class vehicle"]["class_precision"] == pytest.approx(0.5)
    text = format_report(report)
    assert "detection before tracking" in text
    assert text.index("tracking by group") < text.index("detection before tracking") < text.index("height error")
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if "detection before tracking" in line)
    rows = {line[:42].strip(): line[42:].split() for line in lines[start + 1:start + 14]}
    assert lines[start].split()[-6:] == ["recall", "precision", "class-recall", "class-precision", "boxes",
                                         "detections"]
    assert rows["class vehicle"] == ["1.000", "1.000", "1.000", "0.500", "1", "2"]
    assert rows["class other"] == ["-", "0.000", "-", "0.000", "0", "1"]
    assert rows["weather rain"] == ["0.500", "0.500", "0.500", "0.500", "2", "2"]
    assert json.loads(json.dumps(report, default=json_default))["detection"]["box < 40 px"]["precision"] is None


def test_standing_and_moving_people_get_their_own_recall():
    """Issue 21 asks for standing people by name: a background model primed with them cannot see them."""
    standing = dataclasses.replace(_truth(1, "person", 0.0), speed_mps=0.0)
    standing_missed = dataclasses.replace(_truth(2, "person", 100.0), speed_mps=0.2)
    walker = dataclasses.replace(_truth(3, "person", 200.0), speed_mps=1.3)
    unknown = _truth(4, "person", 300.0)   # no ground position: in neither group
    frame = FrameRecord([standing, standing_missed, walker, unknown], [],
                        [_det("person", 0.0), _det("person", 200.0), _det("person", 300.0)])
    table = detection_scores([SequenceRun("s", 5.0, "clear", "day", 10.0, [frame])], 0.3)
    assert (table["standing (< 0.3 m/s)"]["truths"], table["standing (< 0.3 m/s)"]["found"]) == (2, 1)
    assert (table["moving"]["truths"], table["moving"]["found"]) == (1, 1)
    assert table["standing (< 0.3 m/s)"]["precision"] is None    # a detection has no speed
    assert list(table).index("box 40-80 px") < list(table).index("standing (< 0.3 m/s)") < list(table).index("moving")


def test_ground_speed_from_the_frames_before_and_after():
    from types import SimpleNamespace

    from pipeline.eval_sequences import ground_speeds

    class Sequence:
        meta = SimpleNamespace(fps=10.0)

        def __len__(self):
            return 3

        def objects(self, i):
            walker = SimpleNamespace(id=1, ground_xy_m=(0.1 * i, 0.0))          # 1 m/s
            still = SimpleNamespace(id=2, ground_xy_m=(5.0, 5.0))
            unplaced = SimpleNamespace(id=3, ground_xy_m=(float("nan"), float("nan")))
            return [walker, still, unplaced]

    for index in range(3):   # both neighbours in the middle, one at either end
        speeds = ground_speeds(Sequence(), index)
        assert speeds[1] == pytest.approx(1.0) and speeds[2] == 0.0 and 3 not in speeds


# truth: two required walkers side by side, one small (don't-care) walker far off
WALKERS = [_truth(1, "person", 0.0), _truth(2, "person", 22.0),
           TruthBox(3, "person", (300.0, 10.0, 5.0, 15.0), 1.0, 1.75)]


@pytest.mark.parametrize("box, kind", [
    ((500.0, 300.0, 20.0, 60.0), "on nothing"),
    ((298.0, 8.0, 9.0, 20.0), "on don't-care objects only"),      # IoU 0.42 with the 5 x 15 px truth
    ((-2.0, 45.0, 46.0, 70.0), "holds several objects"),
    ((-15.0, 30.0, 40.0, 100.0), "off a required object"),         # covers walker 1, IoU 0.3
    ((0.0, 50.0, 20.0, 18.0), "on part of an object"),             # walker 1's head and shoulders
])
def test_what_lies_under_a_wrong_detection(box, kind):
    from pipeline.eval_metrics import wrong_detection_kind

    assert wrong_detection_kind(box, WALKERS, min_visibility=0.3, min_box_px=20.0) == kind


def test_wrong_detections_are_counted_per_group_and_correct_ones_left_out():
    from pipeline.eval_metrics import wrong_detection_breakdown

    frame = FrameRecord(WALKERS, [], [_det("person", 0.0), DetectionBox((500.0, 300.0, 20.0, 60.0), 1.7, "person"),
                                      DetectionBox((-2.0, 45.0, 46.0, 70.0), 1.7, "vehicle")])
    table = wrong_detection_breakdown([SequenceRun("s", 5.0, "rain", "night", 10.0, [frame])], 0.3, 20.0)
    assert table["all"]["on nothing"] == 1 and table["all"]["holds several objects"] == 1
    assert sum(table["all"].values()) == 2                 # the matched walker is not wrong
    assert table["class vehicle"]["holds several objects"] == 1 and table["night"]["on nothing"] == 1


def test_wrong_track_boxes_are_the_scored_tracks_that_match_nothing_required():
    from pipeline.eval_metrics import wrong_detection_breakdown

    on_walker = OutputBox(1, _det("person", 0.0).box, 1.7, 0.05, "person", "network", True)
    on_nothing = OutputBox(2, (500.0, 300.0, 20.0, 60.0), 1.7, 0.05, "person", "network", True)
    coasting = OutputBox(3, (700.0, 300.0, 20.0, 60.0), 1.7, 0.05, "person", "network", False)
    frame = FrameRecord(WALKERS, [on_walker, on_nothing, coasting], [DetectionBox((900.0, 300.0, 20.0, 60.0), 1.7)])
    table = wrong_detection_breakdown([SequenceRun("s", 5.0, "rain", "night", 10.0, [frame])], 0.3, 20.0, tracks=True)
    # The detection is not looked at; the coasting track is not scored (not seen this frame).
    assert table["all"]["on nothing"] == 1 and sum(table["all"].values()) == 1
