"""PREFIX.objects.csv: one row per confirmed track, rewritten whole as the run goes."""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest

from core.packets import CameraInfo, Frame, FramePacket, Track
from stages.height_rules import RuleEvent
from stages.objects_table import OBJECTS_COLUMNS, ObjectsSink, ObjectTable, read_objects_csv


def packet(index: int, tracks: list[Track], events=()) -> FramePacket:
    return FramePacket(frame=Frame(index, index / 10, np.zeros((4, 4, 3), np.uint8)),
                       camera=CameraInfo(64, 48), tracks=tracks, events=list(events))


def test_rows_fold_frames_and_round_trip_through_the_csv(tmp_path):
    table = ObjectTable()
    path = tmp_path / "run.objects.csv"
    sink = ObjectsSink(path, table, rewrite_every_s=0.25)
    frames = [
        [Track(7, (0, 0, 5, 5), "person", 1.60, 0.30, confirmed=False)],
        [Track(7, (0, 0, 5, 5), "person", 1.70, 0.10, confirmed=True, ground_xy_m=(1.0, 10.0)),
         Track(9, (9, 9, 5, 5), "vehicle", math.nan, math.inf, confirmed=True)],
        [Track(7, (0, 0, 5, 5), "person", 1.72, 0.05, confirmed=True, updated=False, ground_xy_m=(9.0, 9.0))],
        [Track(7, (0, 0, 5, 5), "person", 1.74, 0.04, confirmed=True, ground_xy_m=(2.0, 12.0),
               height_source="geometry")],
    ]
    event = RuleEvent("tall", 7, "person", 3, 0.3, 1.74, 0.04, "geometry", (0, 0, 5, 5), None)
    for index, tracks in enumerate(frames):
        p = packet(index, tracks, [event] if index == 3 else [])
        table.add(p)
        sink.write(p)
    # Rewritten at 0.3 s (0.25 s after the first frame), before close: a crash keeps this much.
    assert [row["track_id"] for row in csv.DictReader(path.open())] == ["7", "9"]
    sink.close()
    with path.open() as f:
        assert next(csv.reader(f)) == list(OBJECTS_COLUMNS)
    person, vehicle = read_objects_csv(path)
    assert (person.track_id, person.cls, person.height_m, person.height_std_m, person.height_source) == \
        (7, "person", 1.74, 0.04, "geometry")
    assert (person.first_time_s, person.last_time_s) == (0.1, 0.3)
    assert (person.frames_seen, person.frames_measured) == (3, 2), "the coasting frame is seen, not measured"
    assert (person.ground_x_m, person.ground_y_m) == pytest.approx((1.5, 11.0)), \
        "mean ground position of measured frames"
    assert person.rules_fired == ["tall"]
    assert math.isnan(vehicle.height_m) and math.isnan(vehicle.ground_x_m) and vehicle.rules_fired == []
    assert "\n9,vehicle,,,network," in path.read_text(), "unknown values are empty cells"
