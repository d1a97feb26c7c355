"""bench.camera_edges: the camera a height-only run ends with, heads alone and with the edges."""

import pytest

from bench.camera_edges import camera_error, main
from core.packets import HeightCamera
from stages.calibration import camera_from_pose, intrinsics_from_fov


def true_camera():
    return camera_from_pose(320, 240, intrinsics_from_fov(320, 240, 70.0), 6.0, 30.0, 1.0, 40.0)


def test_a_camera_read_exactly_measures_poles_exactly():
    camera = true_camera()
    exact = HeightCamera(source="heads", height_m=6.0, pitch_deg=30.0, roll_deg=1.0, focal_px=float(camera.K[1, 1]),
                         pitch_std_deg=1.0, roll_std_deg=1.0, focal_std_pct=5.0)
    error = camera_error(camera, exact, 320, 240)
    assert error.pole_cm == pytest.approx(0.0, abs=1e-6) and error.pitch_deg == pytest.approx(0.0, abs=1e-9)
    assert error.within_std == (True, True, True) and error.horizon_pct == pytest.approx(0.0, abs=1e-9)


def test_a_steeper_pitch_reads_poles_wrong_and_outside_a_narrow_spread():
    camera = true_camera()
    steeper = HeightCamera(source="heads", height_m=6.0, pitch_deg=34.0, roll_deg=1.0, focal_px=float(camera.K[1, 1]),
                           pitch_std_deg=1.0, roll_std_deg=1.0, focal_std_pct=5.0, edges=7)
    error = camera_error(camera, steeper, 320, 240)
    assert error.pitch_deg == pytest.approx(4.0) and error.pole_cm > 5.0 and error.edges == 7
    assert error.within_std == (False, True, True)


def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys):
    assert main([str(tmp_path)]) == 2
    assert "not a generator dataset" in capsys.readouterr().err
    assert main([str(tmp_path), "--model", str(tmp_path / "none.onnx")]) == 2
    assert capsys.readouterr().err.count("\n") == 1


def test_the_table_on_rendered_sequences(tmp_path, capsys):
    from pipeline.cli import main as cli_main

    assert cli_main(["synth", "--out", str(tmp_path / "d"), "--sequences", "2", "--frames", "15", "--size", "160x120",
                     "--seed", "3", "--split", "test", "--workers", "1", "--no-shadows", "--no-post",
                     "--no-progress"]) == 0
    capsys.readouterr()
    assert main([str(tmp_path / "d"), "--per-sequence"]) == 0
    printed = capsys.readouterr().out
    assert printed.count("| d, heads |") == 1 and printed.count("| d, heads + lines |") == 1
    assert printed.count(" lines; pitch ") == 2
    assert main([str(tmp_path / "d"), "--as-run"]) == 0
    plain = capsys.readouterr().out
    assert plain.count("| d, heads + lines |") == 1
    assert main([str(tmp_path / "d"), "--as-run", "--mirror"]) == 0
    mirrored = capsys.readouterr().out
    assert mirrored.count("| d, heads |") == 1
    assert mirrored != plain    # the heads read the frames and their mirror images: another camera


def test_as_run_reads_the_frames_a_run_told_only_the_height_reads(tmp_path):
    from bench.camera_edges import sequence_cameras
    from core.config import Config
    from pipeline.cli import main as cli_main
    from stages.capture import background_indices
    from stages.heightnet_model import HeightNetModel
    from synth.dataset import list_sequences

    assert cli_main(["synth", "--out", str(tmp_path / "d"), "--sequences", "1", "--frames", "40", "--size", "160x120",
                     "--seed", "4", "--split", "test", "--workers", "1", "--no-shadows", "--no-post",
                     "--no-progress"]) == 0
    sequence = list_sequences(tmp_path / "d")[0]
    model = HeightNetModel("v2")
    info = model.info
    first, _ = sequence_cameras(sequence, model, info.camera_error_correlation, info.camera_spread_scale, 10)
    read, _ = sequence_cameras(sequence, model, info.camera_error_correlation, info.camera_spread_scale, 10, True)
    reading = Config().camera
    wanted = background_indices(len(sequence), sequence.meta.fps, reading.read_scene_frames, reading.read_scene_s)
    assert first.frames == 10 and read.frames == len(wanted) != 10
