"""RerunSink writes a .rrd that rerun itself reads back: frames, overlays, tracks, blueprint."""

from __future__ import annotations

import shutil
import socket
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from rerun.chunk import RrdReader

from core.config import OutputConfig
from core.errors import ConfigError, HeightpipeError
from core.packets import FramePacket
from stages.height_rules import RuleEvent
from stages.rerun_sink import RerunSink, writes_index
from stages.sink_common import QUALITY_RGB, FrameEncoder

from media import make_sink_packet, rrd_rows

REPO_ROOT = Path(__file__).resolve().parents[2]
W, H = 64, 48


def make_packet(index: int, complete: bool = True) -> FramePacket:
    """An incomplete frame lacks the ground mask, height map and matches."""
    return make_sink_packet(index, with_maps=complete, with_ground=complete)


def test_rrd_reads_back_with_frames_overlays_tracks_and_blueprint(tmp_path):
    path = tmp_path / "run.rrd"
    sink = RerunSink(path, "save", OutputConfig(height_map_scale=2, ground_overlay=True, height_map_every=1),
                     "test-run")
    indices = [0, 2, 4, 6, 8]  # a --stride 2 run: source frame indices
    for index in indices:
        packet = make_packet(index, complete=index != 4)
        packet.camera.source = "camera-height" if index < 6 else "calibration"
        if index == 6:
            packet.tracks[0].updated = False  # track 1 coasts: its plot must show a gap
        if index == 8:
            # Events are in source pixels: a source twice the recorded frame's size.
            packet.events.append(RuleEvent("tall", 1, "person", 8, 0.8, 1.72, 0.04, "geometry",
                                           (40.0, 20.0, 20.0, 40.0), None, source_scale=(2.0, 2.0)))
        sink.write(packet)
    sink.close()
    sink.close()  # idempotent: the runner's finally may follow an explicit close

    verify = subprocess.run([shutil.which("rerun") or "rerun", "rrd", "verify", str(path)],
                            capture_output=True, text=True, timeout=60)
    assert verify.returncode == 0, verify.stderr
    reader = RrdReader(path)
    assert len(reader.recordings()) == 1
    assert len(reader.blueprints()) == 1, "the layout must be embedded in the .rrd"

    rows = rrd_rows(path, extra_columns=("time",))
    images = rows["/camera/image"]
    assert [frame for frame, _ in images] == indices
    assert [row["time"].total_seconds() for _, row in images] == pytest.approx([i / 10 for i in indices])
    jpeg = bytes(images[0][1]["EncodedImage:blob"][0])
    assert cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR).shape == (H, W, 3)

    labels = {frame: row["Boxes2D:labels"] for frame, row in rows["/camera/tracks"]}
    assert labels[0] == ["1.20 m \u00b130 cm"], "small boxes: the height line only"
    assert labels[6] == ["1.72 m \u00b14 cm", "1.20 m \u00b130 cm"]
    assert not any("0.60" in label for frame_labels in labels.values() for label in frame_labels)
    colors = {frame: row["Boxes2D:colors"] for frame, row in rows["/camera/tracks"]}
    settled, settling = (int.from_bytes(bytes(rgb) + b"\xff", "big") for rgb in
                         (QUALITY_RGB["settled"], QUALITY_RGB["settling"]))
    assert colors[6] == [settled, settling], "colour by quality: std 4 cm settled, 30 cm settling"
    height_series = rows["/tracks/1/height"]
    assert [frame for frame, row in height_series if "Scalars:scalars" in row] == [4, 8]
    assert all(row["Scalars:scalars"] == pytest.approx([1.72]) for _, row in height_series
               if "Scalars:scalars" in row)
    assert [frame for frame, row in height_series if "Clear:is_recursive" in row] == [6], \
        "a coasting track's series is cleared (a gap in the plot), not extended flat"
    assert "/tracks/3/height" not in rows, "tentative tracks are not logged"
    assert [frame for frame, _ in rows["/events"]] == [8]
    assert rows["/events"][0][1]["TextLog:text"] == ["tall: #1 person 1.72 m \u00b14 cm (geometry)"]
    marker = rows["/camera/events"][0][1]  # around the box on the recorded image, padded by 6 px
    assert marker["Boxes2D:half_sizes"] == [pytest.approx([11.0, 16.0])]
    assert marker["Boxes2D:centers"] == [pytest.approx([25.0, 20.0])]
    status = [(frame, row["TextDocument:text"][0]) for frame, row in rows["/status"]]
    assert [frame for frame, _ in status] == [0, 6], "the camera state is logged when it changes"
    assert "camera height given" in status[0][1] and "calibrated" in status[1][1]

    # Height map: uint16 mm at half size; the frame without one clears the stale map.
    depth = [(frame, row) for frame, row in rows["/height"] if "DepthImage:buffer" in row]
    assert [frame for frame, _ in depth] == [0, 2, 6, 8]
    image_format = depth[0][1]["DepthImage:format"][0]
    assert (image_format["width"], image_format["height"]) == (W // 2, H // 2)
    millimetres = np.frombuffer(bytes(depth[0][1]["DepthImage:buffer"][0]), np.uint16)
    assert millimetres.max() == 1720 and depth[0][1]["DepthImage:meter"] == [1000.0]
    cleared = [frame for frame, row in rows["/height"] if "Clear:is_recursive" in row]
    assert cleared == [4]
    assert len([1 for _, row in rows["/camera/ground"] if "SegmentationImage:buffer" in row]) == 4
    arrows = [row for _, row in rows["/camera/matches"] if "Arrows2D:vectors" in row]
    assert len(arrows) == 4 and len(arrows[0]["Arrows2D:vectors"]) == 30
    assert "Pinhole:image_from_camera" in rows["/camera"][0][1]


def test_status_shows_the_camera_a_v2_network_decoded_with_and_changes_only_with_it(tmp_path):
    from core.packets import HeightCamera

    path = tmp_path / "v2.rrd"
    sink = RerunSink(path, "save", OutputConfig(), "v2-run")
    for index, pitch in enumerate([18.21, 18.24, 19.0]):
        packet = make_packet(index)
        packet.camera.source = "camera-height"
        packet.height_camera = HeightCamera("heads", 6.0, pitch, 0.3, 512.0, pitch_std_deg=1.1,
                                            roll_std_deg=0.5, focal_std_pct=6.0, frames=index + 1)
        sink.write(packet)
    sink.close()
    status = [(frame, row["TextDocument:text"][0]) for frame, row in rrd_rows(path)["/status"]]
    assert [frame for frame, _ in status] == [0, 2], "a new frame count alone is not a new state"
    assert "camera heads" in status[0][1] and "pitch 18.2° ±1.1°" in status[0][1]
    assert "pitch 19.0°" in status[1][1]


def test_a_camera_read_from_the_scene_is_shown_beside_the_camera_state(tmp_path):
    """Told only the height, the run's view says what it read and shows the picture of it."""
    from core.packets import HeightCamera

    path = tmp_path / "read.rrd"
    read = HeightCamera("heads", 7.84, 20.54, 1.31, 1379.0, pitch_std_deg=1.3, roll_std_deg=0.58,
                        focal_std_pct=7.0, frames=30, edges=55)
    picture = np.full((36, 64, 3), 200, np.uint8)
    sink = RerunSink(path, "save", OutputConfig(), "read", scene_camera=read, scene_picture=picture)
    packet = make_packet(0)
    packet.camera.source = "self"
    sink.write(packet)
    sink.close()
    rows = rrd_rows(path)
    status = rows["/status"][0][1]["TextDocument:text"][0]
    assert status.startswith("**Camera:** self-calibrated") and "Read from 30 early frames" in status
    assert "55 straight lines of the scene: pitch 20.5° ±1.3°" in status
    from rerun.chunk import RrdReader

    static = {chunk.entity_path for chunk in RrdReader(path).stream() if chunk.is_static}
    assert "/scene_camera" in static                     # the picture, for the whole recording


def test_frame_encoder_encodes_once_and_converts_heights_to_mm():
    encoder = FrameEncoder(jpeg_quality=90, height_map_scale=2)
    packet = make_packet(0)
    gradient = np.linspace(0, 255, W, dtype=np.uint8)
    packet.frame.image = np.dstack([np.tile(gradient, (H, 1))] * 3)
    first = encoder.jpeg(packet)
    assert encoder.jpeg(packet) is first, "a second sink must reuse the encoded frame"
    decoded = cv2.imdecode(np.frombuffer(first, np.uint8), cv2.IMREAD_COLOR)
    assert np.abs(decoded.astype(int) - packet.frame.image).mean() < 3
    assert encoder.jpeg(make_packet(1)) != first, "a new frame is encoded anew"

    packet.height_map = np.full((4, 6), 1.7, np.float32)
    packet.height_map[0, 0:2] = np.nan
    packet.height_map[1, 0:2] = -0.5
    packet.height_map[2, 4:6], packet.height_map[3, 4:6] = 80.0, 80.0
    millimetres = encoder.height_mm(packet)
    assert millimetres.dtype == np.uint16 and millimetres.shape == (2, 3)
    assert millimetres[0, 0] == 0, "NaN and below-ground heights become 0"
    assert millimetres[0, 1] == 1700 and millimetres[1, 2] == 65535
    assert encoder.height_mm(packet) is millimetres


def test_bad_mode_and_config_are_config_errors(tmp_path):
    with pytest.raises(ConfigError, match="output.rerun"):
        RerunSink(tmp_path / "x.rrd", "bogus", OutputConfig(), "x")
    with pytest.raises(ConfigError, match="jpeg_quality"):
        RerunSink(tmp_path / "x.rrd", "save", OutputConfig(jpeg_quality=0), "x")
    with pytest.raises(ConfigError, match="height_map_every"):
        RerunSink(tmp_path / "x.rrd", "save", OutputConfig(height_map_every=0), "x")
    with pytest.raises(ConfigError, match="rrd_index"):
        RerunSink(tmp_path / "x.rrd", "save", OutputConfig(rrd_index="yes"), "x")


@pytest.mark.parametrize("rrd_index, live, indexed", [
    ("auto", False, True),   # a file's run ends: its .rrd gets the index
    ("auto", True, False),   # a live stream may not: no index, memory stays flat
    ("on", True, True),
    ("off", False, False),
])
def test_rrd_index_is_written_for_files_not_live_streams_unless_asked(rrd_index, live, indexed):
    assert writes_index(rrd_index, live) is indexed


def test_rrd_without_index_reads_back_the_same_frames(tmp_path):
    paths = {}
    for live in (False, True):
        paths[live] = tmp_path / f"live_{live}.rrd"
        sink = RerunSink(paths[live], "save", OutputConfig(height_map_every=1), "x", live=live)
        assert sink.indexed is (not live)
        for index in range(6):
            sink.write(make_packet(index))
        sink.close()
    rerun = shutil.which("rerun") or "rerun"
    for path, verifies in ((paths[True], False), (paths[False], True)):
        verify = subprocess.run([rerun, "rrd", "verify", str(path)], capture_output=True, text=True,
                                timeout=60)
        assert (verify.returncode == 0) is verifies, verify.stderr
    indexed, unindexed = rrd_rows(paths[False]), rrd_rows(paths[True])
    assert unindexed.keys() == indexed.keys()
    assert [frame for frame, _ in unindexed["/camera/image"]] == list(range(6))
    assert unindexed["/tracks/1/height"] == indexed["/tracks/1/height"]
    assert paths[True].stat().st_size < paths[False].stat().st_size, "the index is the footer's bytes"


def test_spawn_without_display_is_a_clear_error(tmp_path, monkeypatch):
    monkeypatch.setattr(sys, "platform", "linux")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(HeightpipeError, match="needs a display"):
        RerunSink(tmp_path / "x.rrd", "spawn", OutputConfig(), "x")


def _port_free(port: int) -> bool:
    with socket.socket() as probe:
        return probe.connect_ex(("127.0.0.1", port)) != 0


@pytest.mark.skipif(not (_port_free(9876) and _port_free(9090)), reason="rerun ports in use")
def test_serve_mode_streams_and_still_writes_the_file(tmp_path):
    # A subprocess: the web viewer server lives until its process exits.
    script = (
        "import sys; sys.path[:0] = sys.argv[1:3] + [sys.argv[4]]\n"
        "from pathlib import Path\n"
        "from test_rerun_sink import make_packet\n"
        "from core.config import OutputConfig\n"
        "from stages.rerun_sink import RerunSink\n"
        "sink = RerunSink(Path(sys.argv[3]), 'serve', OutputConfig(), 'served')\n"
        "for i in range(3): sink.write(make_packet(i))\n"
        "sink.close()\n")
    path = tmp_path / "served.rrd"
    result = subprocess.run([sys.executable, "-c", script, str(REPO_ROOT), str(Path(__file__).parent),
                             str(path), str(Path(__file__).parents[1])], capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 0, result.stderr
    assert "web viewer at http://127.0.0.1:9090/?url=rerun%2Bhttp://127.0.0.1:9876/proxy" in result.stderr
    assert [frame for frame, _ in rrd_rows(path, extra_columns=("time",))["/camera/image"]] == [0, 1, 2]


def test_height_map_every_nth_frame_stays_in_view_between(tmp_path):
    """``output.height_map_every = 3``: maps of frames 0, 3, 6 only, and no Clear in between."""
    path = tmp_path / "run.rrd"
    sink = RerunSink(path, "save", OutputConfig(height_map_every=3, ground_overlay=True), "test-run")
    for index in range(8):
        sink.write(make_packet(index))
    sink.close()
    rows = rrd_rows(path)
    assert [frame for frame, row in rows["/height"] if "DepthImage:buffer" in row] == [0, 3, 6]
    assert [frame for frame, row in rows["/camera/ground"] if "SegmentationImage:buffer" in row] == [0, 3, 6]
    assert not any("Clear:is_recursive" in row for _, row in rows["/height"] + rows["/camera/ground"])
    assert len(rows["/camera/image"]) == 8
