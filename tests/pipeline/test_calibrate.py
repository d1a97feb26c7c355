"""`heightpipe calibrate --out`: the fit as a complete calibration JSON that `run` reads back."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from pipeline.calibrate import write_calibration_json
from stages.calibration import angles_from_rotation, load_calibration


def fake_result():
    K = np.array([[800.0, 0, 320], [0, 800.0, 180], [0, 0, 1]])
    return SimpleNamespace(width=640, height=360, K=K, height_m=6.2, pitch_deg=21.5, roll_deg=-1.2,
                           height_std_m=0.3, n_tracks=12, prior=SimpleNamespace(mean_m=1.7, std_m=0.09),
                           focal_source="estimated")


def test_written_calibration_loads_as_the_fitted_camera(tmp_path):
    intrinsics = tmp_path / "intrinsics.json"
    intrinsics.write_text(json.dumps({"image_size": [640, 360], "K": [[800, 0, 320], [0, 800, 180], [0, 0, 1]],
                                      "dist": [-0.1, 0.01, 0, 0, 0]}))
    out = tmp_path / "camera.json"
    write_calibration_json(str(out), fake_result(), str(intrinsics))
    camera = load_calibration(out)
    assert camera.height_m == pytest.approx(6.2)
    pitch, roll, _ = angles_from_rotation(camera.R)
    assert (pitch, roll) == pytest.approx((21.5, -1.2), abs=1e-6)
    assert np.allclose(camera.K, fake_result().K) and np.allclose(camera.dist, [-0.1, 0.01, 0, 0, 0])
    assert "self-calibrated from 12 people" in json.loads(out.read_text())["source"]


def test_readme_calibration_example_loads():
    from media import REPO_ROOT

    camera = load_calibration(REPO_ROOT / "docs" / "calibration_example.json")
    assert camera.height_m == pytest.approx(4.5) and camera.dist is not None


@pytest.mark.parametrize("calibrate_frames, total, max_frames, stride, spread", [
    (300, 90_000, 0, 1, 300),      # an hour of video: 300 frames over all of it
    (300, 300, 0, 1, 0),           # no longer than that: every frame, from the start
    (300, None, 0, 1, 0),          # a stream (no length): from the start
    (300, 90_000, 500, 1, 0),      # --max-frames: from the start, as asked
    (300, 90_000, 0, 5, 0),        # --stride: likewise
    (0, 90_000, 0, 1, 0),          # calibrate_frames = 0: every frame
])
def test_calibrate_reads_a_long_recording_spread_over_it(calibrate_frames, total, max_frames, stride, spread):
    from core.config import Config
    from pipeline.calibrate import spread_count

    config = Config()
    config.camera.calibrate_frames = calibrate_frames
    config.capture.max_frames, config.capture.stride = max_frames, stride
    assert spread_count(config, total) == spread


def test_calibrate_on_a_longer_clip_says_it_read_frames_spread_over_it(box_video, capsys):
    from pipeline.cli import main

    assert main(["calibrate", str(box_video), "--camera-height", "5", "--no-progress",
                 "--set", "camera.calibrate_frames=20"]) == 0
    assert "camera from 20 frames spread over its 30" in capsys.readouterr().err


def test_told_the_height_calibrate_reads_the_camera_from_the_scene(box_video, capsys):
    """`calibrate --camera-height`: the v2 heads (and any straight lines) give a whole pose as a
    [camera] snippet a run takes as calibrated, no people needed."""
    import tomllib

    from core.config import CameraConfig
    from pipeline.cli import main
    from stages.calibration import camera_for_run, is_calibrated

    assert main(["calibrate", str(box_video), "--camera-height", "5", "--max-frames", "15", "--no-progress"]) == 0
    printed = capsys.readouterr()
    camera = tomllib.loads(printed.out)["camera"]
    assert camera["height_m"] == 5.0 and camera["self_calibrated"] is True
    assert 0 < camera["pitch_deg"] < 90 and 1 < camera["fov_deg"] < 179 and abs(camera["roll_deg"]) < 30
    assert "camera from 15 frames" in printed.err
    assert is_calibrated(camera_for_run(CameraConfig(**camera), 640, 480))
    assert main(["calibrate", str(box_video), "--camera-height", "5", "--max-frames", "4", "--no-progress"]) == 0
    assert "too few frames for the scene's lines (13 needed)" in capsys.readouterr().err


def test_told_the_height_calibrate_reads_a_live_stream_too(capsys):
    """`calibrate --camera-height --max-frames N` reads a stream's camera from its first frames,
    to keep (a run reads only its first seconds)."""
    import tomllib

    from media import mjpeg_server
    from pipeline.cli import main

    server, _ = mjpeg_server([40], fps=25)
    try:
        url = f"http://127.0.0.1:{server.server_address[1]}/video.mjpg"
        code = main(["calibrate", url, "--camera-height", "5", "--max-frames", "15", "--no-progress",
                     "--set", "capture.reconnect_attempts=0", "--set", "capture.read_timeout_s=2"])
    finally:
        server.shutdown()
    printed = capsys.readouterr()
    assert code == 0, printed.err
    assert tomllib.loads(printed.out)["camera"]["self_calibrated"] is True
    assert "camera from 15 frames" in printed.err


def test_told_the_height_calibrate_draws_the_camera_it_read(tmp_path, capsys):
    """`--picture`: the scene's median with the lines that agreed, the horizon and 1.70 m bars."""
    import cv2

    from media import write_pole_video
    from pipeline.cli import main

    video = write_pole_video(tmp_path / "poles.mp4")
    picture = tmp_path / "camera.png"
    assert main(["calibrate", str(video), "--camera-height", "6", "--picture", str(picture), "--no-progress"]) == 0
    assert f"wrote {picture}" in capsys.readouterr().err
    image = cv2.imread(str(picture))
    assert image.shape == (240, 320, 3)
    green = (image[..., 1] > 180) & (image[..., 0] < 120) & (image[..., 2] < 120)
    white = np.all(image > 235, axis=2)
    assert green.sum() > 100 and white.sum() > 100        # the poles that agreed, the bars


def test_told_the_height_and_the_lens_calibrate_reads_undistorted_frames_with_the_file_s_focal(tmp_path, capsys):
    import tomllib

    from media import write_lens_calibration, write_pole_video
    from pipeline.cli import main

    lens = write_lens_calibration(tmp_path / "lens.json", dist=[0.02, 0.0, 0.0, 0.0])
    video = write_pole_video(tmp_path / "poles.mp4")
    assert main(["calibrate", str(video), "--camera-height", "6", "--calibration", str(lens), "--no-progress"]) == 0
    printed = capsys.readouterr()
    camera = tomllib.loads(printed.out)["camera"]
    assert camera["calibration"] == str(lens) and "fov_deg" not in camera and "focal_std_pct" not in camera
    assert 27.0 < camera["pitch_deg"] < 33.0 and "focal 216 px" in printed.err


@pytest.mark.parametrize("flags, message", [
    (["--camera-height", "0"], "--camera-height must be the mounting height in metres"),
    (["--camera-height", "5", "--set", 'height.model="v1"'], "needs a HeightNet v2 model"),
    (["--camera-height", "5", "--out", "camera.json"], "save the [camera] snippet instead"),
    (["--picture", "camera.png"], "--picture draws the camera read from the scene: give --camera-height too"),
    (["--camera-height", "5", "--picture", "/no/such/folder/camera.png"], "cannot write the picture"),
])
def test_calibrate_from_the_scene_refuses_in_one_line(box_video, capsys, flags, message):
    from pipeline.cli import main

    assert main(["calibrate", str(box_video), *flags, "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
