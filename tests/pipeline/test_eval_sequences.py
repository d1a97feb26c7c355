"""Running the stage chain over a generator sequence (the part of eval-tracks that is the pipeline)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from core.config import Config
from pipeline.eval_sequences import OracleHeights, build_eval_chain, camera_info, run_setup


def test_true_heights_learn_no_network_scale():
    """True height maps are metric and exact: the geometry stage must not rescale them, nor doubt
    their scale, and the height filter gives them no per-object bias (the model's keep theirs)."""
    camera = SimpleNamespace(width=320, height=240, K=np.diag([300.0, 300.0, 1.0]), R=np.eye(3),
                             t=np.array([0.0, 0.0, 5.0]), height_m=5.0)
    sequence = SimpleNamespace(meta=SimpleNamespace(camera=camera))
    chain = build_eval_chain(sequence, Config(), "oracle", geometry=True)
    assert [name for name, _ in chain.stages] == ["heights", "keypoints", "matching", "objects", "geometry", "tracking"]
    assert isinstance(chain.stage("heights"), OracleHeights)
    assert chain.stage("geometry").network_scale is None
    assert chain.stage("tracking").tracker.config.network_bias_share == 0.0
    assert Config().tracking.network_bias_share > 0.0


def _sequence():
    camera = SimpleNamespace(width=320, height=240, K=np.diag([300.0, 300.0, 1.0]), R=np.eye(3),
                             t=np.array([0.0, 0.0, 5.0]), height_m=5.0)
    return SimpleNamespace(meta=SimpleNamespace(camera=camera))


def test_a_run_told_only_the_camera_height_knows_no_pose_and_fuses_no_geometry():
    """``eval-tracks --camera height`` with ``[camera] read_scene_frames = 0``: what ``heightpipe run
    --camera-height H`` knows when it does not read the camera from its first frames, no more."""
    not_read = Config()
    not_read.camera.read_scene_frames = 0
    exact = camera_info(_sequence())
    told = camera_info(_sequence(), not_read, "height")
    assert exact.source == "calibration" and exact.R is not None
    assert (told.source, told.height_m, told.R) == ("camera-height", 5.0, None)
    assert told.K[1, 1] != 300.0                     # the default lens ([camera] fov_deg), not the true one
    assert camera_info(_sequence(), known="height").K[1, 1] == told.K[1, 1]   # the default config's
    chain = build_eval_chain(_sequence(), not_read, "oracle", geometry=True, known="height")
    assert "geometry" not in [name for name, _ in chain.stages]
    config, _ = run_setup(_sequence(), not_read, "height")
    assert (config.height.model, config.objects.source) == ("v2", "network")   # v2's heads guess the rest
    with pytest.raises(ValueError, match="lens"):
        camera_info(_sequence(), Config(), "lens")


def _sequence_of(picture: np.ndarray, count: int):
    frames = [SimpleNamespace(rgb=picture)] * count

    class Sized(SimpleNamespace):
        def __len__(self):
            return len(frames)

    return Sized(meta=SimpleNamespace(camera=_sequence().meta.camera, fps=10.0), frame=lambda i: frames[i])


def test_told_the_height_and_the_scene_the_run_has_a_self_calibrated_pose():
    """``eval-tracks --camera scene``: the pose ``calibrate --camera-height`` reads from the frames
    (here plain grey ones: the heads alone), with the true height, taken as self-calibrated."""
    sequence = _sequence_of(np.full((240, 320, 3), 120, np.uint8), 4)   # grey: the heads alone
    posed = camera_info(sequence, Config(), "scene")
    assert posed.source == "self" and posed.R is not None and posed.height_m == pytest.approx(5.0)
    chain = build_eval_chain(sequence, Config(), "oracle", geometry=True, known="scene", camera=posed)
    assert "geometry" in [name for name, _ in chain.stages]


def test_told_only_the_height_the_run_reads_its_camera_from_its_first_frames_as_heightpipe_run_does():
    """``--camera height`` by default: the pose from the frames a run reads ahead, when the scene's
    lines agree, then the model a posed run picks (v1 and its moving objects) with the geometry
    channel; without lines, v2 and its heads as before."""
    import cv2

    from media import pole_scene

    sequence = _sequence_of(cv2.cvtColor(pole_scene()[0], cv2.COLOR_GRAY2RGB), 30)   # lines to read
    config, camera = run_setup(sequence, Config(), "height")
    assert camera.source == "self" and camera.R is not None and camera.height_m == pytest.approx(5.0)
    assert config.camera.self_calibrated and config.camera.pitch_deg > 0
    assert (config.height.model, config.objects.source) == ("", "blobs")
    chain = build_eval_chain(sequence, Config(), "model", geometry=True, known="height")
    assert "geometry" in [name for name, _ in chain.stages]
    grey = _sequence_of(np.full((240, 320, 3), 120, np.uint8), 30)    # no lines: the heads in the run
    config, camera = run_setup(grey, Config(), "height")
    assert camera.source == "camera-height" and config.height.model == "v2"
