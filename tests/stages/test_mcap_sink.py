"""McapSink: Foxglove-schema MCAP that the mcap library and rerun read, and that survives kill -9."""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import cv2
import numpy as np
import pytest
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Message
from mcap.stream_reader import StreamReader
from mcap_protobuf.decoder import DecoderFactory
from rerun.chunk import RrdReader

from core.config import OutputConfig
from core.packets import CameraInfo, FeatureMatches, Frame, FramePacket, Track
from stages.height_rules import RuleEvent
from stages.mcap_sink import McapSink

REPO_ROOT = Path(__file__).resolve().parents[2]
W, H = 64, 48
FPS = 10.0


def make_packet(index: int) -> FramePacket:
    """A 64x48 frame with a 1.72 m object; track 1 confirmed from frame 4, track 3 never."""
    rng = np.random.default_rng(index)
    height = np.zeros((H, W), np.float32)
    height[10:30, 20:30] = 1.72
    points = rng.uniform(0, [W, H], (30, 2)).astype(np.float32)
    tracks = [Track(1, (20, 10, 10, 20), "person", 1.72, 0.04, confirmed=index >= 4,
                    ground_xy_m=(1.5, 7.25)),
              Track(3, (40, 30, 5, 5), "other", 0.6, 0.5, confirmed=False)]
    return FramePacket(
        frame=Frame(index, index / FPS, rng.integers(0, 255, (H, W, 3), dtype=np.uint8)),
        camera=CameraInfo(W, H, K=np.array([[50.0, 0, 32], [0, 50.0, 24], [0, 0, 1]])),
        ground_mask=height < 0.1, height_map=height,
        matches=FeatureMatches(points, points + 1, np.arange(30) < 10), tracks=tracks)


def write_mcap(path: Path, indices: list[int], **config) -> McapSink:
    sink = McapSink(path, OutputConfig(**config), recording_name="test-run")
    for index in indices:
        sink.write(make_packet(index))
    sink.close()
    return sink


def test_mcap_reads_back_with_foxglove_schemas_units_and_one_time_per_frame(tmp_path):
    path = tmp_path / "run.mcap"
    indices = list(range(0, 24, 2))  # --stride 2: source indices, 2.2 s of source time
    sink = write_mcap(path, indices, flush_interval_s=1.0, height_map_scale=2, height_map_every=1)

    with open(path, "rb") as stream:
        reader = make_reader(stream, validate_crcs=True, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        channels = {channel.topic: channel for channel in summary.channels.values()}
        schemas = {topic: summary.schemas[channel.schema_id].name for topic, channel in channels.items()}
        assert schemas == {
            "/tracks": "heightpipe.TrackArray", "/camera/image": "foxglove.CompressedImage",
            "/camera/calibration": "foxglove.CameraCalibration",
            "/camera/height": "foxglove.RawImage", "/camera/ground": "foxglove.RawImage",
            "/camera/annotations": "foxglove.ImageAnnotations",
            "/camera/matches": "foxglove.ImageAnnotations"}
        counts = summary.statistics.channel_message_counts
        assert {topic: counts[channel.id] for topic, channel in channels.items()} == {
            topic: len(indices) for topic in channels}
        assert channels["/camera/height"].metadata["unit"] == "mm"
        assert {chunk.compression for chunk in summary.chunk_indexes} == {"zstd"}
        assert len(summary.chunk_indexes) >= 3, "flush_interval_s=1 closes a chunk every second"
        metadata = {record.name: record.metadata for record in reader.iter_metadata()}
        assert metadata["heightpipe"]["recording_name"] == "test-run"

        by_time: dict[int, dict[str, object]] = defaultdict(dict)
        for _schema, channel, message, decoded in reader.iter_decoded_messages():
            by_time[message.log_time][channel.topic] = decoded

    assert len(by_time) == len(indices), "all messages of a frame share one log_time"
    for (log_time, frame), index in zip(sorted(by_time.items()), indices):
        assert log_time == sink.start_epoch_ns + round(index / FPS * 1e9)
        record = frame["/tracks"]
        assert (record.frame_index, record.time_s) == (index, pytest.approx(index / FPS))
        assert len(record.tracks) == 2, "tentative tracks are recorded too, flagged"
        assert record.tracks[0].confirmed == (index >= 4) and not record.tracks[1].confirmed
        assert (record.tracks[0].ground_position.x_m, record.tracks[0].ground_position.y_m) == (1.5, 7.25)
        assert not record.tracks[1].HasField("ground_position")

    frame = by_time[max(by_time)]
    image = frame["/camera/image"]
    assert image.format == "jpeg"
    assert cv2.imdecode(np.frombuffer(image.data, np.uint8), cv2.IMREAD_COLOR).shape == (H, W, 3)
    height = frame["/camera/height"]
    assert (height.encoding, height.width, height.height, height.step) == ("16UC1", W // 2, H // 2, W)
    millimetres = np.frombuffer(height.data, "<u2").reshape(H // 2, W // 2)
    assert millimetres[5:15, 10:15].min() == 1720 and millimetres[20:, :].max() == 0
    ground = frame["/camera/ground"]
    assert (ground.encoding, ground.width, ground.height) == ("mono8", W, H)
    assert set(np.unique(np.frombuffer(ground.data, np.uint8))) == {0, 255}
    calibration = frame["/camera/calibration"]
    assert list(calibration.K) == [50.0, 0, 32, 0, 50.0, 24, 0, 0, 1]
    assert [text.text for text in frame["/camera/annotations"].texts] == ["1.72 m \u00b14 cm"]
    matches = frame["/camera/matches"].points
    assert sorted(len(group.points) for group in matches) == [20, 40]  # 10 object, 20 background pairs


def test_events_go_to_a_json_channel_at_their_frame(tmp_path):
    path = tmp_path / "run.mcap"
    sink = McapSink(path, OutputConfig(), recording_name="events")
    for index in range(6):
        packet = make_packet(index)
        if index in (2, 5):
            packet.events.append(RuleEvent("tall", 1, "person", index, index / FPS, 1.72, 0.04, "fused",
                                           (20.0, 10.0, 10.0, 20.0), (1.5, 7.25)))
        sink.write(packet)
    sink.close()
    with open(path, "rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        channel = next(c for c in summary.channels.values() if c.topic == "/events")
        schema = summary.schemas[channel.schema_id]
        assert (channel.message_encoding, schema.name, schema.encoding) == ("json", "heightpipe.RuleEvent",
                                                                             "jsonschema")
        frame_times = [m.log_time for _, _, m in reader.iter_messages(topics=["/tracks"])]
        events = [(m.log_time, json.loads(m.data)) for _, _, m in reader.iter_messages(topics=["/events"])]
    assert [log_time for log_time, _ in events] == [frame_times[2], frame_times[5]]
    assert events[0][1] == {"rule": "tall", "track_id": 1, "class": "person", "frame": 2, "time_s": 0.2,
                            "height_m": 1.72, "height_std_m": 0.04, "height_source": "fused",
                            "box": [20.0, 10.0, 10.0, 20.0], "ground_xy_m": [1.5, 7.25],
                            "source_scale": [1.0, 1.0]}


def test_rerun_converts_the_mcap(tmp_path):
    path = tmp_path / "run.mcap"
    write_mcap(path, list(range(6)))
    output = tmp_path / "converted.rrd"
    result = subprocess.run([shutil.which("rerun") or "rerun", "mcap", "convert", str(path),
                             "-o", str(output)], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    image_rows = sum(chunk.num_rows for chunk in RrdReader(output).stream()
                     if chunk.entity_path == "/camera/image" and not chunk.is_static
                     and "EncodedImage:blob" in chunk.to_record_batch().schema.names)
    assert image_rows == 6


_WRITER = """
import sys, time
sys.path.insert(0, sys.argv[1])
from pathlib import Path
sys.path.insert(0, sys.argv[2])
from test_mcap_sink import make_packet
from core.config import OutputConfig
from stages.height_rules import RuleEvent
from stages.mcap_sink import McapSink
sink = McapSink(Path(sys.argv[3]), OutputConfig(flush_interval_s=1.0))
for index in range(1000):
    sink.write(make_packet(index))
    print(index, flush=True)
    time.sleep(0.004)
"""


def test_kill_9_loses_at_most_the_last_flush_interval(tmp_path):
    path = tmp_path / "killed.mcap"
    writer = subprocess.Popen([sys.executable, "-c", _WRITER, str(REPO_ROOT), str(Path(__file__).parent),
                               str(path)], stdout=subprocess.PIPE, text=True)
    last_written = -1
    for line in writer.stdout:
        last_written = int(line)
        if last_written >= 45:  # 4.5 s of source time at 10 fps
            break
    writer.send_signal(signal.SIGKILL)
    writer.wait(timeout=30)
    writer.stdout.close()
    assert last_written >= 45

    recovered = []
    topics: dict[int, str] = {}
    with open(path, "rb") as stream:
        try:
            for record in StreamReader(stream).records:
                if isinstance(record, Channel):
                    topics[record.id] = record.topic
                elif isinstance(record, Message) and topics[record.channel_id] == "/camera/image":
                    recovered.append(record.log_time)
        except McapError:  # the unfinished chunk (length still unset) and no summary or footer
            pass
    frames_per_interval = int(1.0 * FPS)
    assert len(recovered) >= last_written + 1 - frames_per_interval
    assert recovered == sorted(recovered)

    output = tmp_path / "recovered.rrd"
    result = subprocess.run([shutil.which("rerun") or "rerun", "mcap", "convert", "--recover",
                             str(path), "-o", str(output)], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    image_rows = sum(chunk.num_rows for chunk in RrdReader(output).stream()
                     if chunk.entity_path == "/camera/image" and not chunk.is_static
                     and "EncodedImage:blob" in chunk.to_record_batch().schema.names)
    assert image_rows == len(recovered)


def test_height_map_every_nth_frame(tmp_path):
    """``output.height_map_every = 4``: height map and ground mask of frames 0, 4, 8 only."""
    path = tmp_path / "run.mcap"
    write_mcap(path, list(range(10)), height_map_every=4)
    frames = defaultdict(list)
    with open(path, "rb") as stream:
        for _schema, channel, message in make_reader(stream).iter_messages():
            frames[channel.topic].append(message.log_time)
    assert len(frames["/camera/image"]) == len(frames["/tracks"]) == 10
    image_times = frames["/camera/image"]
    for topic in ("/camera/height", "/camera/ground"):
        assert frames[topic] == [image_times[0], image_times[4], image_times[8]]
