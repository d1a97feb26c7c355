"""TrackCsvSink: one row per confirmed track per frame, on disk as soon as the frame is written."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from core.errors import HeightpipeError
from core.packets import CameraInfo, Frame, FramePacket, Track
from stages.csv_sink import TrackCsvSink

HEADER = ("frame,time_s,track_id,class,x,y,w,h,score,height_m,height_std_m,height_source,frame_damaged,network_reused,"
          "box_source")


def make_packet(index: int, tracks: list[Track], damage: str = "", network_reused: bool = False) -> FramePacket:
    return FramePacket(frame=Frame(index, index / 25, np.zeros((48, 64, 3), np.uint8), damage=damage),
                       camera=CameraInfo(64, 48), tracks=tracks, network_reused=network_reused)


def test_boxes_of_a_scaled_down_frame_are_written_in_source_pixels(tmp_path):
    path = tmp_path / "run.tracks.csv"
    sink = TrackCsvSink(path)
    packet = make_packet(0, [Track(7, (10.25, 20.0, 5.0, 12.5), "person", 1.7, 0.04, confirmed=True)])
    packet.frame.source_scale = (2.0, 2.0)  # a 128x96 source processed at 64x48
    sink.write(packet)
    sink.close()
    row = next(csv.DictReader(path.open()))
    assert [row[key] for key in "xywh"] == ["20.5", "40.0", "10.0", "25.0"]


def test_rows_are_confirmed_tracks_and_reach_disk_every_frame(tmp_path):
    path = tmp_path / "run.tracks.csv"
    sink = TrackCsvSink(path)
    sink.write(make_packet(0, [Track(7, (10.25, 20.0, 5.0, 12.5), "person", 1.7234, 0.0412,
                                     score=0.9, confirmed=False)]))
    sink.write(make_packet(3, [Track(7, (11.0, 20.5, 5.0, 12.5), "person", 1.7234, 0.0412,
                                     score=0.9, confirmed=True),
                               Track(9, (40.0, 30.0, 8.0, 8.0), "vehicle", 1.41, 0.2, confirmed=True,
                                     height_source="fused")], damage="decoder flags it corrupt"))
    # Before close(): what a crash would leave behind.
    lines = path.read_text().splitlines()
    assert lines[0] == HEADER
    assert lines[1:] == ["3,0.1200,7,person,11.0,20.5,5.0,12.5,0.900,1.723,0.041,network,1,0,detected",
                         "3,0.1200,9,vehicle,40.0,30.0,8.0,8.0,1.000,1.410,0.200,fused,1,0,detected"]
    sink.write(make_packet(4, [Track(9, (40.0, 30.0, 8.0, 8.0), "vehicle", 1.41, 0.2, confirmed=True)]))
    sink.write(make_packet(5, [Track(9, (40.0, 30.0, 8.0, 8.0), "vehicle", 1.41, 0.2, confirmed=True)],
                           network_reused=True))
    sink.close()
    rows = list(csv.DictReader(path.open()))
    assert len(rows) == 4 and float(rows[1]["height_m"]) == pytest.approx(1.41)
    assert [row["frame_damaged"] for row in rows] == ["1", "1", "0", "0"]
    assert [row["network_reused"] for row in rows] == ["0", "0", "0", "1"]


@pytest.mark.parametrize("updated, filled, expected", [
    (True, False, "detected"), (False, True, "interpolated"), (False, False, "predicted")])
def test_each_row_says_where_its_box_comes_from(tmp_path, updated, filled, expected):
    path = tmp_path / "run.tracks.csv"
    sink = TrackCsvSink(path)
    sink.write(make_packet(0, [Track(7, (10.0, 20.0, 5.0, 12.5), "person", 1.7, 0.04, confirmed=True,
                                     updated=updated, filled=filled)]))
    sink.close()
    assert next(csv.DictReader(path.open()))["box_source"] == expected


def test_unwritable_path_is_a_clear_error(tmp_path):
    with pytest.raises(HeightpipeError, match="cannot write"):
        TrackCsvSink(tmp_path / "missing-folder" / "run.tracks.csv")
