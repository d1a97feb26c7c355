"""Told only the camera height, a run poses itself with the camera read from its first frames."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from core.config import Config
from core.errors import ConfigError
from pipeline.scene_camera import pose_from_scene, reads_scene


def _config(**camera) -> Config:
    config = Config()
    return replace(config, camera=replace(config.camera, **camera))


@pytest.mark.parametrize("camera, reads", [
    (dict(height_m=6.0), True),                                  # the height alone: read the rest
    (dict(height_m=6.0, read_scene_frames=0), False),            # switched off
    (dict(height_m=6.0, pitch_deg=20.0), False),                 # a pose given
    (dict(height_m=6.0, calibration="posed"), False),            # a calibration file with a pose
    (dict(height_m=6.0, calibration="lens"), True),              # ... with the lens alone: read the rest
    (dict(), False),                                             # nothing known: no metres to pose
])
def test_only_a_run_told_just_the_camera_height_reads_the_scene(tmp_path, camera, reads):
    if "calibration" in camera:
        camera = {**camera, "calibration": _lens_file(tmp_path, pose=camera["calibration"] == "posed")}
    assert reads_scene(_config(**camera)) == reads


@pytest.mark.parametrize("camera", [dict(height_m=6.0, read_scene_frames=-1), dict(height_m=6.0, read_scene_s=0.0),
                                    dict(height_m=6.0, read_scene_live_s=-1.0)])
def test_impossible_reading_settings_are_a_config_error(camera):
    with pytest.raises(ConfigError, match="camera.read_scene_frames must be 0"):
        reads_scene(_config(**camera))


def _contact_model(tmp_path, pitch_rad: float):
    from media import make_tiny_contact_model
    from stages.heightnet_model import HeightNetModel

    offsets = np.zeros((48, 64, 2), np.float32)
    path = make_tiny_contact_model(tmp_path / "v2.onnx", offsets, [pitch_rad, 0.02, np.log(0.9), -4.0, -4.0, -4.0])
    return HeightNetModel(str(path), 1)


def _pole_frames(count: int = 15) -> list[np.ndarray]:
    """Frames of poles (30 degrees of pitch, 2 of roll): lines the heads' 22.9 degrees give way to."""
    import cv2

    from media import pole_scene

    return [cv2.cvtColor(pole_scene()[0], cv2.COLOR_GRAY2BGR)] * count


GREY = [np.full((240, 320, 3), 100, np.uint8)] * 15


def test_the_camera_read_poses_the_config_as_a_self_calibrated_camera(tmp_path):
    model = _contact_model(tmp_path, 0.4)
    told = _config(height_m=6.0)
    posed, reading = pose_from_scene(told, _pole_frames(), model)
    used = reading.camera
    assert reading.picture.shape == (240, 320, 3)
    assert used is not None and used.frames == 15 and used.height_m == pytest.approx(6.0) and used.edges >= 8
    assert 26.0 < used.pitch_deg < 31.0 and 1.0 < used.roll_deg < 3.0     # the lines', not the heads' 22.9
    camera = posed.camera
    assert camera.self_calibrated and camera.height_m == 6.0 and camera.calibration == ""
    assert camera.pitch_deg == pytest.approx(used.pitch_deg, abs=0.005)
    assert camera.roll_deg == pytest.approx(used.roll_deg, abs=0.005)
    assert camera.fov_deg != told.camera.fov_deg           # the read focal length, not the default lens
    assert (camera.pitch_std_deg, camera.roll_std_deg, camera.focal_std_pct) == pytest.approx(
        (used.pitch_std_deg, used.roll_std_deg, used.focal_std_pct), abs=0.05)
    assert (posed.height, posed.objects) == (told.height, told.objects)   # the model is the caller's to pick


def test_without_lines_a_run_is_not_posed_by_the_heads_alone_but_calibrate_s_snippet_is(tmp_path):
    """The heads alone are what v2 guesses frame by frame anyway (and its offsets err with them)."""
    model = _contact_model(tmp_path, 0.4)
    told = _config(height_m=6.0)
    assert pose_from_scene(told, GREY, model) == (told, None)
    posed, reading = pose_from_scene(told, GREY, model, needs_lines=False)
    assert reading.camera.edges == 0 and posed.camera.pitch_deg == pytest.approx(np.degrees(0.4), abs=0.01)


@pytest.mark.parametrize("pitch_rad", [0.0, -0.1])
def test_a_camera_read_as_level_or_looking_up_leaves_the_run_unposed(tmp_path, pitch_rad):
    """[camera] cannot say "level" (pitch 0 is "unknown"): such a camera keeps the heads in the run."""
    told = _config(height_m=6.0)
    assert pose_from_scene(told, GREY, _contact_model(tmp_path, pitch_rad), needs_lines=False) == (told, None)


def test_nothing_to_read_or_nothing_to_read_it_for_leaves_the_config_as_it_is(tmp_path):
    model = _contact_model(tmp_path, 0.4)
    told, posed = _config(height_m=6.0), _config(height_m=6.0, pitch_deg=20.0)
    assert pose_from_scene(told, [], model) == (told, None)                # a stream that sent nothing
    assert pose_from_scene(posed, _pole_frames(), model) == (posed, None)  # a pose given: nothing to read


def _stream(fps: float, seconds: float):
    from core.packets import Frame

    for index in range(int(fps * seconds)):
        yield Frame(index, index / fps, np.full((4, 4, 3), index, np.uint8))


@pytest.mark.parametrize("fps, count, span, kept, taken", [
    (25.0, 5, 2.0, [0, 10, 20, 30, 40], 41),    # one frame per 0.4 s slot, stops once the last slot began
    (25.0, 30, 2.0, None, 50),                  # slots shorter than two frames: one frame each
    (2.0, 30, 5.0, [0, 1, 2, 3, 4, 5, 6, 7, 8, 9], 10),   # a slow stream: what there is, then it ends
    (25.0, 0, 2.0, [], 0),                      # off: nothing taken from the stream
])
def test_a_live_stream_gives_its_first_seconds_spread_over_slots(fps, count, span, kept, taken):
    from pipeline.scene_camera import opening_images

    stream = _stream(fps, 6.0 if fps > 2 else 5.0)
    images, used = opening_images(stream, count, span)
    assert used == taken
    values = [int(image[0, 0, 0]) for image in images]
    if kept is not None:
        assert values == kept
    else:
        assert len(values) == 30 and values == sorted(set(values)) and values[-1] == 49
    following = next(stream, None)            # the stream goes on where the reading stopped
    assert following is None if fps == 2.0 else following.index == taken


def _lens_file(tmp_path, pose: bool = False):
    from media import write_lens_calibration

    return str(write_lens_calibration(tmp_path / ("posed.json" if pose else "lens.json"), pose=pose))


def test_a_lens_only_calibration_file_leaves_the_height_the_only_part_of_the_pose_known(tmp_path):
    from pipeline.scene_camera import knows_height_only, model_for

    lens, posed = _lens_file(tmp_path), _lens_file(tmp_path, pose=True)
    assert knows_height_only(_config(height_m=6.0, calibration=lens))
    assert not knows_height_only(_config(height_m=6.0, calibration=posed))
    assert not knows_height_only(_config(calibration=lens))                  # no height: nothing to pose
    # Not read (or not readable): v2 and its heads, with the file's focal length, as for no file.
    not_read = _config(height_m=6.0, calibration=lens, read_scene_frames=0)
    assert (model_for(not_read).height.model, model_for(not_read).objects.source) == ("v2", "network")
    assert model_for(_config(height_m=6.0, calibration=posed)).height.model == ""


def test_with_a_lens_only_file_the_scene_gives_pitch_and_roll_and_the_file_the_focal_length(tmp_path):
    model = _contact_model(tmp_path, 0.4)
    told = _config(height_m=6.0, calibration=_lens_file(tmp_path))
    posed, reading = pose_from_scene(told, _pole_frames(), model)
    assert reading.camera.focal_given and reading.camera.focal_px == pytest.approx(216.0)
    assert 28.0 < reading.camera.pitch_deg < 32.0 and reading.camera.edges >= 8
    assert posed.camera.calibration == told.camera.calibration and posed.camera.self_calibrated
    assert posed.camera.focal_std_pct == 0.0
