"""`heightpipe run` as a user meets it: outputs, bad input, and stopping mid-run."""

import csv
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from media import (REPO_ROOT, default_sigint, make_tiny_height_model, mjpeg_server, write_moving_box_video,
                   write_truncated_avi)

CSV_HEADER = ["frame", "time_s", "track_id", "class", "x", "y", "w", "h", "score", "height_m", "height_std_m",
              "height_source", "frame_damaged", "network_reused", "box_source"]


def heightpipe(*args, timeout=120):
    return subprocess.run([sys.executable, "-m", "pipeline.cli", *map(str, args)], cwd=REPO_ROOT,
                          capture_output=True, text=True, timeout=timeout)


def assert_clean_error(result, message):
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr, result.stderr
    error_lines = [line for line in result.stderr.splitlines() if line.startswith("heightpipe: error:")]
    assert len(error_lines) == 1, result.stderr
    assert message in error_lines[0]


@pytest.fixture
def model_flag(tiny_model):
    return ["--set", f'height.model="{tiny_model}"']


def test_run_writes_rrd_mcap_and_csv(tmp_path, box_video, model_flag):
    from mcap.reader import make_reader

    result = heightpipe("run", box_video, "--out", tmp_path / "out", "--no-progress", *model_flag)
    assert result.returncode == 0, result.stderr
    assert "processed 30 frames" in result.stderr
    for suffix in (".rrd", ".mcap", ".tracks.csv"):
        assert (tmp_path / f"out{suffix}").stat().st_size > 0
    with open(tmp_path / "out.mcap", "rb") as f:
        reader = make_reader(f)
        images = sum(1 for _ in reader.iter_messages(topics=["/camera/image"]))
    assert images == 30
    rows = list(csv.reader(open(tmp_path / "out.tracks.csv")))
    assert rows[0] == CSV_HEADER
    assert len(rows) > 10, "the moving box should become a confirmed track"
    assert len({row[2] for row in rows[1:]}) <= 2


def test_a_confirmed_track_is_reported_from_its_first_detection(tmp_path, box_video, model_flag):
    """The frames a track was tentative in hold its detections: once confirmed, they are written too."""
    rows = {}
    for backfill in ("true", "false"):
        result = heightpipe("run", box_video, "--out", tmp_path / backfill, "--no-progress", "--rerun", "off",
                            "--set", f"tracking.backfill={backfill}", *model_flag)
        assert result.returncode == 0, result.stderr
        rows[backfill] = list(csv.reader(open(tmp_path / f"{backfill}.tracks.csv")))[1:]
    assert rows["false"], "the moving box becomes a track"
    added = [row for row in rows["true"] if row not in rows["false"]]
    assert {row[2] for row in added} == {row[2] for row in rows["false"]}, "every track gains its tentative frame"
    for row in added:   # 10 frames/s: two detections confirm, so each track gains its first frame
        track_frames = [int(r[0]) for r in rows["false"] if r[2] == row[2]]
        assert int(row[0]) == min(track_frames) - 1
    assert len(rows["true"]) == len(rows["false"]) + len(added)


def test_rule_events_reach_every_output_and_the_summary_is_the_objects_table(tmp_path, box_video, tiny_model):
    import json

    from mcap.reader import make_reader

    from media import rrd_rows
    from pipeline.summary import tracks_line
    from stages.objects_table import read_objects_csv

    config = tmp_path / "rules.toml"
    config.write_text(f'[height]\nmodel = "{tiny_model}"\n\n[[rules]]\nname = "moving"\nmin_frames = 3\n')
    result = heightpipe("run", box_video, "--out", tmp_path / "out", "--no-progress", "--config", config)
    assert result.returncode == 0, result.stderr
    events = [json.loads(line) for line in (tmp_path / "out.events.jsonl").read_text().splitlines()]
    objects = read_objects_csv(tmp_path / "out.objects.csv")
    assert events and len(events) == len(objects), "every confirmed track fires the rule once"
    assert {e["track_id"] for e in events} == {o.track_id for o in objects if o.rules_fired == ["moving"]}
    with open(tmp_path / "out.mcap", "rb") as f:
        in_mcap = [json.loads(m.data) for _, _, m in make_reader(f).iter_messages(topics=["/events"])]
    assert [e["track_id"] for e in in_mcap] == [e["track_id"] for e in events]
    assert len(rrd_rows(tmp_path / "out.rrd")["/events"]) == len(events)
    assert f"events: {len(events)} height-rule firings" in result.stderr
    summary_line = next(line for line in result.stderr.splitlines() if line.strip().startswith("tracks:"))
    assert summary_line.strip() == f"tracks: {tracks_line(objects)}"


def test_out_folder_gets_source_name(tmp_path, box_video, model_flag):
    result = heightpipe("run", box_video, "--out", f"{tmp_path}/", "--max-frames", 3, "--rerun", "off",
                        "--no-progress", *model_flag)
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "box.mcap").exists() and not (tmp_path / "box.rrd").exists()


@pytest.mark.parametrize("sources, out, expected", [
    (["a/cam.mp4"], None, ["recordings/cam"]),
    (["a/cam.mp4"], "x/run1", ["x/run1"]),
    (["a/cam.mp4", "b/cam.mp4", "rtsp://10.0.0.5/live"], "site", ["site/cam", "site/cam_2", "site/10_0_0_5_live"]),
    (["a/cam.mp4", "0"], None, ["recordings/cam", "recordings/webcam0"]),
])
def test_one_prefix_per_source(sources, out, expected):
    from core.config import Config
    from pipeline.run_command import source_prefixes

    assert source_prefixes(sources, out, Config()) == [Path(p) for p in expected]


def test_several_sources_run_side_by_side_one_recording_set_each(tmp_path, box_video, model_flag):
    second = tmp_path / "cam2.mp4"
    second.write_bytes(box_video.read_bytes())
    result = heightpipe("run", box_video, second, box_video, "--out", tmp_path / "many", "--rerun", "off",
                        *model_flag, timeout=240)
    assert result.returncode == 0, result.stderr
    assert result.stderr.count("processed 30 frames") == 3
    tables = [tmp_path / "many" / f"{name}.tracks.csv" for name in ("box", "cam2", "box_2")]
    assert all(table.exists() and (tmp_path / "many" / f"{table.name.split('.')[0]}.mcap").exists()
               for table in tables)
    assert tables[0].read_text() == tables[1].read_text() == tables[2].read_text()


def test_one_bad_source_of_several_fails_the_run_but_not_the_others(tmp_path, box_video, model_flag):
    result = heightpipe("run", box_video, tmp_path / "missing.mp4", "--out", f"{tmp_path}/", "--rerun", "off",
                        "--no-progress", *model_flag, timeout=240)
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr
    assert "missing.mp4" in result.stderr and "processed 30 frames" in result.stderr
    assert (tmp_path / "box.tracks.csv").exists()


def test_missing_video(tmp_path, model_flag):
    assert_clean_error(heightpipe("run", tmp_path / "nope.mp4", *model_flag), "no such file")


def test_file_that_is_not_a_video(tmp_path, model_flag):
    path = tmp_path / "text.mp4"
    path.write_text("not a video\n" * 50)
    assert_clean_error(heightpipe("run", path, *model_flag), "not a readable video")


def test_truncated_video_processes_what_decodes_and_says_so(tmp_path, model_flag):
    path = write_truncated_avi(tmp_path / "clip.avi", frames=40)
    result = heightpipe("run", path, "--out", tmp_path / "cut", "--rerun", "off", "--no-progress", *model_flag)
    assert result.returncode == 0, result.stderr
    assert "header claims 40" in result.stderr


def test_frames_of_another_aspect_ratio_are_reported_not_a_crash(tmp_path, box_video, model_flag):
    folder = tmp_path / "frames"
    folder.mkdir()
    capture = cv2.VideoCapture(str(box_video))
    for i in range(20):
        ok, image = capture.read()
        assert ok
        if i >= 10:  # the camera's other stream: another crop from frame 10 on
            image = image[:, : image.shape[0]]
        cv2.imwrite(str(folder / f"{i:03d}.png"), image)
    capture.release()
    result = heightpipe("run", folder, "--out", tmp_path / "out", "--no-progress", *model_flag)
    assert result.returncode == 0, result.stderr
    assert "Traceback" not in result.stderr
    assert "processed 10 frames" in result.stderr
    assert "10 of another aspect ratio (not processed); frame 10 was the first at" in result.stderr


def test_frames_processed_scaled_down_give_tracks_in_the_source_pixels(tmp_path, box_video, model_flag):
    """capture.max_width: the recordings hold the smaller frames, tracks.csv the source's pixels."""
    from mcap.reader import make_reader

    def boxes(out):
        rows = csv.DictReader(open(out.with_name(out.name + ".tracks.csv")))
        return {int(row["frame"]): [float(row[key]) for key in "xywh"] for row in rows}

    full, half = tmp_path / "full", tmp_path / "half"
    for out, width in ((full, 0), (half, 80)):
        result = heightpipe("run", box_video, "--out", out, "--no-progress", *model_flag,
                            "--set", f"capture.max_width={width}")
        assert result.returncode == 0, result.stderr
    assert "160x120 frames processed at 80x60 (capture.max_width = 80" in result.stderr
    full_boxes, half_boxes = boxes(full), boxes(half)
    shared = sorted(set(full_boxes) & set(half_boxes))
    assert len(shared) >= 20, "the walking box is tracked either way"
    errors = np.abs(np.array([full_boxes[i] for i in shared]) - [half_boxes[i] for i in shared])
    assert np.median(errors) <= 2.0, "source pixels: the same box, within a pixel of the half-size frame"
    assert max(half_boxes[i][0] + half_boxes[i][2] for i in shared) > 100, "not the 80 px frame's pixels"
    with open(half.with_name("half.mcap"), "rb") as f:
        from mcap_protobuf.decoder import DecoderFactory

        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        _, _, _, image = next(reader.iter_decoded_messages(topics=["/camera/image"]))
    decoded = cv2.imdecode(np.frombuffer(image.data, np.uint8), cv2.IMREAD_COLOR)
    assert decoded.shape == (60, 80, 3)


def test_unreachable_stream(model_flag):
    result = heightpipe("run", "rtsp://127.0.0.1:9/none", "--set", "capture.connect_attempts=2",
                        "--set", "capture.backoff_s=0.01", *model_flag)
    assert_clean_error(result, "cannot open stream rtsp://127.0.0.1:9/none after 2 attempts")


def test_live_stream_runs_end_to_end_and_writes_every_output(tmp_path, model_flag):
    server, _ = mjpeg_server([40], fps=25)
    try:
        url = f"http://127.0.0.1:{server.server_address[1]}/video.mjpg"
        result = heightpipe("run", url, "--out", tmp_path / "cam", "--no-progress", *model_flag,
                            "--set", "capture.reconnect_attempts=0", "--set", "capture.read_timeout_s=2")
    finally:
        server.shutdown()
    assert result.returncode == 0, result.stderr
    processed = int(re.search(r"processed (\d+) frames", result.stderr).group(1))
    dropped = re.search(r"(\d+) frames dropped while the pipeline was busy", result.stderr)
    assert processed + (int(dropped.group(1)) if dropped else 0) == 40, result.stderr
    assert processed >= 20, "a paced 64x48 stream is easy to keep up with"
    for suffix in (".rrd", ".mcap", ".tracks.csv"):
        assert (tmp_path / f"cam{suffix}").stat().st_size > 0


@pytest.mark.parametrize("live_s", [1, 0])
def test_a_live_stream_told_only_the_height_reads_its_camera_from_its_first_second(tmp_path, live_s):
    """A stream's frames cannot be read twice: its first ``read_scene_live_s`` seconds read the
    camera and the run starts after them, posed; with 0 v2's heads guess the camera in the run,
    and the summary points to `heightpipe calibrate --camera-height` for a better one."""
    from media import pole_scene

    poles = cv2.cvtColor(pole_scene()[0], cv2.COLOR_GRAY2BGR)
    server, _ = mjpeg_server([75], fps=25, sizes_per_connection=[(320, 240)], picture=poles)
    try:
        url = f"http://127.0.0.1:{server.server_address[1]}/video.mjpg"
        result = heightpipe("run", url, "--out", tmp_path / "cam", "--no-progress", "--rerun", "off",
                            "--camera-height", "5", "--set", "capture.reconnect_attempts=0",
                            "--set", "capture.read_timeout_s=2", "--set", f"camera.read_scene_live_s={live_s}")
    finally:
        server.shutdown()
    assert result.returncode == 0, result.stderr
    lines = result.stderr.splitlines()
    camera_line = next(line for line in lines if line.startswith("  camera:"))
    processed = int(re.search(r"processed (\d+) frames", result.stderr).group(1))
    dropped = re.search(r"(\d+) frames dropped while the pipeline was busy", result.stderr)
    processed += int(dropped.group(1)) if dropped else 0
    if live_s:
        taken = int(re.search(r"the first (\d+) frames \(1 s\) read the camera and were not processed",
                              result.stderr).group(1))
        assert 20 <= taken <= 30 and processed + taken == 75, result.stderr
        assert any(line.startswith("  camera read from") for line in lines)
        assert camera_line.startswith("  camera: self-calibrated")
    else:
        assert processed == 75 and not any(line.startswith("  camera read from") for line in lines)
        assert "camera heads" in camera_line
        hint = next(line for line in lines if line.startswith("  hint:"))
        assert "calibrate SOURCE --camera-height H --max-frames" in hint


def test_unknown_config_key(box_video):
    assert_clean_error(heightpipe("run", box_video, "--set", "tracking.min_hitz=3"),
                       "unknown config key 'tracking.min_hitz'")


def test_config_value_of_wrong_type(tmp_path, box_video):
    config = tmp_path / "bad.toml"
    config.write_text('[capture]\nstride = "two"\n')
    assert_clean_error(heightpipe("run", box_video, "--config", config), "capture.stride")


def test_missing_model(tmp_path, box_video):
    assert_clean_error(heightpipe("run", box_video, "--set", f'height.model="{tmp_path}/none.onnx"'),
                       "model file not found")


def test_model_of_wrong_shape(tmp_path, box_video):
    model = make_tiny_height_model(tmp_path / "wrong.onnx", input_shape=[1, 3, 32, 64])
    assert_clean_error(heightpipe("run", box_video, "--set", f'height.model="{model}"'), "input shape")


def _start_run(tmp_path, model_flag, frames=400):
    video = write_moving_box_video(tmp_path / "long.mp4", frames=frames, size=(160, 120))
    prefix = tmp_path / "long"
    process = subprocess.Popen([sys.executable, "-m", "pipeline.cli", "run", str(video), "--out", str(prefix),
                                "--no-progress", "--set", "output.flush_interval_s=0.5", *model_flag],
                               cwd=REPO_ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               preexec_fn=default_sigint)
    csv_path = Path(f"{prefix}.tracks.csv")
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        if csv_path.exists() and len(csv_path.read_text().splitlines()) > 40:
            break
        time.sleep(0.05)
    else:
        process.kill()
        pytest.fail("the run produced no tracks in time")
    return process, prefix


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_stop_signal_finalises_every_output(tmp_path, model_flag, sig):
    from mcap.reader import make_reader

    process, prefix = _start_run(tmp_path, model_flag)
    process.send_signal(sig)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == 130, stderr
    assert "Traceback" not in stderr
    assert f"stopped by {sig.name}" in stderr
    with open(f"{prefix}.mcap", "rb") as f:
        summary = make_reader(f).get_summary()  # needs the summary section a clean close writes
    assert summary is not None
    images = sum(count for channel_id, count in summary.statistics.channel_message_counts.items()
                 if summary.channels[channel_id].topic == "/camera/image")
    processed = int(stderr.split("processed ")[1].split(" frames")[0])
    assert images == processed and 0 < processed < 400
    rrd = subprocess.run(["rerun", "rrd", "verify", f"{prefix}.rrd"], capture_output=True, text=True)
    assert rrd.returncode == 0, rrd.stderr
    rows = list(csv.reader(open(f"{prefix}.tracks.csv")))
    assert int(rows[-1][0]) <= processed


def _recoverable_images(mcap_path) -> int:
    """Frames a linear reader gets back from an MCAP whose writer died (no summary)."""
    from mcap.records import Channel, Message
    from mcap.stream_reader import StreamReader

    topics, images = {}, 0
    with open(mcap_path, "rb") as f:
        try:
            for record in StreamReader(f, skip_magic=False).records:
                if isinstance(record, Channel):
                    topics[record.id] = record.topic
                elif isinstance(record, Message) and topics.get(record.channel_id) == "/camera/image":
                    images += 1
        except Exception:
            pass  # the unfinished last chunk ends the stream: everything before it counts
    return images


def test_kill_9_leaves_mcap_recoverable_to_the_last_second(tmp_path, model_flag):
    process, prefix = _start_run(tmp_path, model_flag)
    time.sleep(0.3)
    process.kill()
    process.communicate(timeout=30)
    rows = list(csv.reader(open(f"{prefix}.tracks.csv")))
    last_frame = max(int(row[0]) for row in rows[1:])
    # flush_interval_s = 0.5 s of a 10 fps video: at most ~5 frames (+ the one in flight) lost
    assert _recoverable_images(f"{prefix}.mcap") >= last_frame + 1 - 7


@pytest.mark.parametrize("flag, message", [
    (["--max-frames", "-1"], "capture.max_frames (--max-frames) must be 0 (all frames) or more"),
    (["--stride", "0"], "capture.stride (--stride) must be at least 1"),
])
def test_negative_limits_are_rejected(box_video, model_flag, flag, message):
    assert_clean_error(heightpipe("run", box_video, *flag, *model_flag), message)


@pytest.fixture
def contact_model(tmp_path):
    """A HeightNet v2-shaped model: every pixel's contact point 3 input pixels below it."""
    import numpy as np

    from media import make_tiny_contact_model

    offsets = np.zeros((48, 64, 2), np.float32)
    offsets[..., 1] = 3.0
    return make_tiny_contact_model(tmp_path / "v2.onnx", offsets, [0.4, 0.0, 0.2, -4.0, -4.0, -4.0])


def test_a_v2_model_without_a_camera_is_one_line_naming_the_flags(box_video, contact_model):
    result = heightpipe("run", box_video, "--rerun", "off", "--set", f'height.model="{contact_model}"')
    assert_clean_error(result, "give --calibration FILE, or --camera-height M")


def test_a_v2_model_with_the_camera_height_says_the_heads_gave_the_rest(tmp_path, box_video, contact_model):
    result = heightpipe("run", box_video, "--out", tmp_path / "v2", "--no-progress", "--rerun", "off",
                        "--camera-height", "5", "--max-frames", "5", "--set", f'height.model="{contact_model}"',
                        "--set", "camera.read_scene_frames=0")
    assert result.returncode == 0, result.stderr
    camera_line = next(line for line in result.stderr.splitlines() if line.startswith("  camera:"))
    assert "camera heads: pitch 22.9° ±7.8°" in camera_line and "mean of 5 frames" in camera_line


@pytest.fixture
def pole_video(tmp_path):
    from media import write_pole_video

    return write_pole_video(tmp_path / "poles.mp4")


def test_told_only_the_height_a_file_run_reads_its_camera_first_and_runs_posed(tmp_path, pole_video, box_video,
                                                                             contact_model):
    """The camera the heads and the scene's lines read from the early frames poses the run: the
    model named decodes with that pose (the self-calibrated [camera] pose), not with the heads
    frame by frame. A video without straight lines keeps the heads."""
    result = heightpipe("run", pole_video, "--out", tmp_path / "v2", "--no-progress", "--rerun", "off",
                        "--camera-height", "5", "--max-frames", "5", "--set", f'height.model="{contact_model}"')
    assert result.returncode == 0, result.stderr
    lines = result.stderr.splitlines()
    read = next(line for line in lines if line.startswith("  camera read from"))
    assert "30 early frames: height 5.00 m given" in read and "straight lines of the scene" in read
    pitch = re.search(r"pitch (\d+\.\d)° ±", read).group(1)
    camera_line = next(line for line in lines if line.startswith("  camera:"))
    assert camera_line.startswith("  camera: self-calibrated") and "self-calibrated [camera] pose" in camera_line
    assert f"pitch {pitch}°" in camera_line and "heads" not in camera_line
    picture = cv2.imread(str(tmp_path / "v2.camera.jpg"))     # the reading, drawn on the scene
    assert picture is not None and picture.shape == (240, 320, 3) and "v2.camera.jpg" in result.stderr
    result = heightpipe("run", box_video, "--out", tmp_path / "box", "--no-progress", "--rerun", "off",
                        "--camera-height", "5", "--max-frames", "5", "--set", f'height.model="{contact_model}"')
    assert result.returncode == 0, result.stderr
    assert not any(line.startswith("  camera read from") for line in result.stderr.splitlines())
    assert "camera heads: pitch 22.9°" in result.stderr and not (tmp_path / "box.camera.jpg").exists()


@pytest.mark.parametrize("flags, v2, read", [
    (["--camera-height", "5"], False, True),           # told only the height: camera read first, then posed (v1)
    (["--camera-height", "5", "--set", "camera.read_scene_frames=0"], True, False),   # not read: v2's heads
    (["--camera-height", "5", "--set", "camera.pitch_deg=20"], False, False),         # a full pose: v1
    (["--camera-height", "5", "--set", 'height.model="v1"'], False, True),            # named: read, then as named
    (["--camera-height", "5", "--set", 'height.model="v1"', "--set", "camera.read_scene_frames=0"], False, False),
])
def test_the_default_model_follows_what_the_run_is_told_of_its_camera(tmp_path, pole_video, flags, v2, read):
    result = heightpipe("run", pole_video, "--out", tmp_path / "run", "--no-progress", "--rerun", "off",
                        "--max-frames", "3", *flags)
    assert result.returncode == 0, result.stderr
    camera_line = next(line for line in result.stderr.splitlines() if line.startswith("  camera:"))
    assert ("HeightNet v2 metres" in camera_line) == v2
    assert any(line.startswith("  camera read from") for line in result.stderr.splitlines()) == read
    hints = [line for line in result.stderr.splitlines() if line.startswith("  hint:")]
    if v2:       # the heads' camera: how to give a better one
        assert len(hints) == 1 and "heightpipe calibrate" in hints[0]
    else:        # v1 named for the height-only case, not read: pointed to v2; posed: nothing to say
        assert len(hints) == ("v1" in " ".join(flags) and not read) and all("height.model=v2" in h for h in hints)


@pytest.fixture
def detector_model(tmp_path):
    """The v2 model above with a declared detection head that always finds a person (score 0.95)
    and a vehicle (0.88) at fixed places, and a cyclist too weak for any threshold."""
    import numpy as np

    from media import make_tiny_contact_model

    offsets = np.zeros((48, 64, 2), np.float32)
    offsets[..., 1] = 3.0
    centre = np.full((3, 12, 16), -10.0, np.float32)
    box = np.zeros((4, 12, 16), np.float32)
    for cls, (row, col), logit, size in ((0, (6, 8), 3.0, (8, 16)), (2, (3, 3), 2.0, (12, 8)),
                                         (1, (9, 12), -3.0, (8, 12))):
        centre[cls, row, col] = logit
        box[2:, row, col] = size
    return make_tiny_contact_model(tmp_path / "det.onnx", offsets, [0.4, 0.0, 0.2, -4.0, -4.0, -4.0],
                                   detection=(["person", "cyclist", "vehicle"], centre, box))


def test_network_objects_run_end_to_end(tmp_path, box_video, detector_model):
    """`objects.source = network` with a model that has a detection head: runs, and its tracks are
    the network's objects (an untrained model: structure, not accuracy)."""
    result = heightpipe("run", box_video, "--out", tmp_path / "net", "--no-progress", "--rerun", "off",
                        "--camera-height", "5", "--max-frames", "6", "--set", f'height.model="{detector_model}"',
                        "--set", "objects.source=network")
    assert result.returncode == 0, result.stderr
    with open(tmp_path / "net.tracks.csv", newline="") as f:
        reader = csv.DictReader(f)
        rows = list(reader)
    assert reader.fieldnames == CSV_HEADER
    # Two objects that never move, found in every frame: confirmed tracks of the network's classes
    # on the second frame, reported from the first (``tracking.backfill``). The moving white box has
    # no network box, but is a third of the frame tall: a big motion blob, an object of its own with
    # its class from its shape.
    classes = {row["track_id"]: row["class"] for row in rows}
    assert sorted(classes.values()) == ["other", "person", "vehicle"]
    assert sum(row["class"] in ("person", "vehicle") for row in rows) == 2 * 6


def test_network_objects_need_a_model_with_a_detection_head(box_video, model_flag):
    result = heightpipe("run", box_video, "--rerun", "off", "--max-frames", "2", "--set", "objects.source=network",
                        *model_flag)
    assert_clean_error(result, "objects.source = 'network' needs a height model with a detection head")
