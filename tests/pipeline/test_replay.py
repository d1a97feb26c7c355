"""`heightpipe replay`: an MCAP becomes the same rerun recording that the live sink writes."""

from __future__ import annotations

import shutil
import subprocess

import pytest
from rerun.chunk import RrdReader

from pipeline import cli
from core.config import OutputConfig
from core.packets import FramePacket
from stages.height_rules import RuleEvent
from stages.mcap_sink import McapSink
from stages.rerun_sink import RerunSink
from stages.sink_common import FrameEncoder

from media import make_sink_packet, rrd_rows, write_unfinished_recording


def make_packet(index: int) -> FramePacket:
    """Frame 6 has no height map or matches (it keeps its ground mask); track 1 fires a rule at 8."""
    packet = make_sink_packet(index, with_maps=index != 6)
    if index == 8:
        packet.events.append(RuleEvent("tall", 1, "person", 8, 0.8, 1.72, 0.04, "network",
                                       (20.0, 10.0, 10.0, 20.0), None))
    return packet


def comparable(rows: dict[str, list[tuple[int, dict]]]) -> dict[str, list]:
    """What must match between live and replayed recordings (arrow order may differ)."""
    summary = {}
    for entity, items in rows.items():
        if entity.startswith("/__") or entity == "/status":  # the camera state is not in the MCAP
            continue
        summary[entity] = [
            (frame, sorted(components), sorted(map(str, row.get("Boxes2D:labels") or [])),
             row.get("TextLog:text"), row.get("Points2D:positions"),
             row.get("Scalars:scalars"), sorted(map(tuple, row.get("Arrows2D:origins") or [])),
             row.get("DepthImage:buffer"), row.get("SegmentationImage:buffer"),
             row.get("Pinhole:image_from_camera"))
            for frame, row in items for components in [row.keys()]]
    return summary


def test_replay_draws_what_the_live_sink_draws(tmp_path, capsys):
    indices = [0, 2, 4, 6, 8, 10]
    config = OutputConfig(ground_overlay=True)
    encoder = FrameEncoder.from_config(config)
    live = RerunSink(tmp_path / "run.rrd", "save", config, "run", encoder=encoder)
    recording = McapSink(tmp_path / "run.mcap", config, encoder=encoder)
    for index in indices:
        packet = make_packet(index)
        live.write(packet)
        recording.write(packet)
    live.close()
    recording.close()

    replayed = tmp_path / "replayed.rrd"
    assert cli.main(["replay", str(tmp_path / "run.mcap"), "--save", str(replayed),
                     "--set", "output.ground_overlay=true"]) == 0
    assert "replayed 6 frames" in capsys.readouterr().err
    verify = subprocess.run([shutil.which("rerun") or "rerun", "rrd", "verify", str(replayed)],
                            capture_output=True, text=True, timeout=60)
    assert verify.returncode == 0, verify.stderr
    assert len(RrdReader(replayed).blueprints()) == 1

    live_rows, replay_rows = rrd_rows(tmp_path / "run.rrd"), rrd_rows(replayed)
    assert comparable(replay_rows) == comparable(live_rows)
    # Spot checks of the shared content itself, beyond "same as live".
    assert [frame for frame, _ in replay_rows["/camera/image"]] == indices
    assert [frame for frame, _ in replay_rows["/tracks/1/height"]] == [4, 6, 8, 10]
    labels = dict(replay_rows["/camera/tracks"])[8]["Boxes2D:labels"]
    assert sorted(labels) == ["1.20 m \u00b130 cm", "1.72 m \u00b14 cm"]
    assert [frame for frame, _ in replay_rows["/events"]] == [8]
    assert "/camera/ground" in replay_rows
    live_jpeg = dict(live_rows["/camera/image"])[4]["EncodedImage:blob"]
    assert dict(replay_rows["/camera/image"])[4]["EncodedImage:blob"] == live_jpeg


def test_unfinished_recording_replays_its_complete_chunks(tmp_path, capsys):
    path = tmp_path / "run.mcap"
    write_unfinished_recording(path)  # 3.5 s at 10 fps: chunks closed at 1, 2 and 3 s

    assert cli.main(["replay", str(path), "--save", str(tmp_path / "cut.rrd")]) == 0
    err = capsys.readouterr().err
    assert "warning" in err and "ends early" in err
    frames = [frame for frame, _ in rrd_rows(tmp_path / "cut.rrd")["/camera/image"]]
    assert frames == list(range(len(frames))) and 10 <= len(frames) < 35


@pytest.mark.parametrize("content, message", [
    (None, "MCAP file not found"),
    (b"this is not an mcap file at all", "not an MCAP file"),
    (b"\x89MCAP0\r\n" + b"\x00" * 5, "cannot read MCAP"),
])
def test_missing_or_corrupt_mcap_is_a_one_line_error(tmp_path, capsys, content, message):
    path = tmp_path / "bad.mcap"
    if content is not None:
        path.write_bytes(content)
    assert cli.main(["replay", str(path), "--save", str(tmp_path / "out.rrd")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("heightpipe: error: ") and message in err and "\n" not in err


def test_damaged_frames_are_marked_in_mcap_live_rrd_and_replay(tmp_path, capsys):
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    config = OutputConfig()
    live = RerunSink(tmp_path / "run.rrd", "save", config, "run")
    recording = McapSink(tmp_path / "run.mcap", config)
    for index in range(6):
        packet = make_packet(index)
        packet.frame.damage = "decoder flags it corrupt" if index in (2, 3) else ""
        live.write(packet)
        recording.write(packet)
    live.close()
    recording.close()

    with open(tmp_path / "run.mcap", "rb") as stream:
        logs = [(decoded.level, decoded.message) for _, _, _, decoded in make_reader(
            stream, decoder_factories=[DecoderFactory()]).iter_decoded_messages(topics=["/capture/damage"])]
    assert logs == [(3, "frame 2 damaged, heights not measured: decoder flags it corrupt"),
                    (3, "frame 3 damaged, heights not measured: decoder flags it corrupt")]
    assert cli.main(["replay", str(tmp_path / "run.mcap"), "--save", str(tmp_path / "replayed.rrd")]) == 0
    for rrd in ("run.rrd", "replayed.rrd"):
        rows = rrd_rows(tmp_path / rrd)["/capture/damage"]
        assert [(frame, row["TextLog:level"]) for frame, row in rows] == [(2, ["WARN"]), (3, ["WARN"])]


def test_network_skipped_frames_are_marked_and_keep_the_last_maps_in_mcap_live_rrd_and_replay(tmp_path):
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    config = OutputConfig(height_map_every=1)
    live = RerunSink(tmp_path / "run.rrd", "save", config, "run")
    recording = McapSink(tmp_path / "run.mcap", config)
    for index in range(6):
        packet = make_packet(index)
        packet.network_reused = index in (2, 3)  # a live run behind its network
        live.write(packet)
        recording.write(packet)
    live.close()
    recording.close()

    with open(tmp_path / "run.mcap", "rb") as stream:
        messages = [(channel.topic, decoded) for _, channel, _, decoded in make_reader(
            stream, decoder_factories=[DecoderFactory()]).iter_decoded_messages(
                topics=["/capture/network_skipped", "/camera/height", "/camera/ground"])]
    notes = [(decoded.level, decoded.message) for topic, decoded in messages if topic == "/capture/network_skipped"]
    assert [level for level, _ in notes] == [2, 2]  # info
    assert [message.split(":")[0] for _, message in notes] == ["frame 2", "frame 3"]
    assert all("heights not measured" in message for _, message in notes)
    assert sum(topic == "/camera/height" for topic, _ in messages) == 4  # frames 0, 1, 4, 5
    assert sum(topic == "/camera/ground" for topic, _ in messages) == 4
    assert cli.main(["replay", str(tmp_path / "run.mcap"), "--save", str(tmp_path / "replayed.rrd")]) == 0
    for rrd in ("run.rrd", "replayed.rrd"):
        rows = rrd_rows(tmp_path / rrd)
        assert [(frame, row["TextLog:level"]) for frame, row in rows["/capture/network_skipped"]] == [
            (2, ["INFO"]), (3, ["INFO"])]
        assert [frame for frame, _ in rows["/height"]] == [0, 1, 4, 5], "kept, neither logged again nor cleared"


def test_replay_serves_the_web_viewer(tmp_path):
    import sys
    import urllib.parse

    from bench.live_view import free_port
    from media import REPO_ROOT

    recording = McapSink(tmp_path / "run.mcap", OutputConfig())
    for index in range(4):
        recording.write(make_packet(index))
    recording.close()
    web_port, grpc_port = free_port(), free_port()
    result = subprocess.run(
        [sys.executable, "-m", "pipeline.cli", "replay", str(tmp_path / "run.mcap"), "--web",
         "--set", f"web.web_port={web_port}", "--set", f"web.grpc_port={grpc_port}",
         "--set", "web.keep_serving=false"], cwd=REPO_ROOT, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    proxy = urllib.parse.quote(f"rerun+http://127.0.0.1:{grpc_port}/proxy", safe="")
    assert f"replayed 4 frames from {tmp_path / 'run.mcap'} to http://127.0.0.1:{web_port}/?url={proxy}" \
        in result.stderr
