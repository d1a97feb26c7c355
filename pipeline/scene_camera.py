"""Told only its camera's height, a run reads the rest of the camera from the video's first frames.

Most users know how high their camera hangs and nothing else. HeightNet v2's camera heads guess
pitch, roll and focal length from each frame, and the scene's straight lines sharpen the guess
(``stages/vertical_edges.py``); ``heightpipe calibrate --camera-height`` prints that camera as a
``[camera]`` pose. A run over a file does the same by itself before its first frame, from frames
spread over the video's first seconds (``[camera] read_scene_frames``, ``read_scene_s``), a live
stream from its first seconds (``read_scene_live_s``: those frames are not processed), and
then runs as a posed one: the model a full pose picks (``core.config.model_for_camera``: v1 and
its moving objects), the geometry channel, heights flagged as self-calibrated.

Why (docs/results.md, 2026-12-04 eleventh session): on held-out generator sequences, tracked
people were 25-34 cm off with the heads guessing the camera during the run, 15-24 posed from
the scene; v2 posed instead reads real people short (Oxford Town Centre: its detection boxes end
above the feet), so the posed run keeps v1. Only a camera the scene's straight lines agreed with
poses a run (``pose_from_scene``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Iterator

import numpy as np

from core.config import HEIGHT_ONLY_MODEL, Config, model_for_camera, told_height_only
from core.errors import ConfigError
from core.packets import HeightCamera

MIN_PITCH_DEG = 0.5
"""A camera read as this level or looking up is not posed: ``[camera]`` cannot say "level"
(pitch 0 means unknown), and a CCTV camera looking up sees no ground to measure on."""


def knows_height_only(config: Config) -> bool:
    """Whether a run with ``config`` knows its camera's height and none of its pose: no pitch in
    ``[camera]``, and no calibration file or one with the lens alone (read here)."""
    from stages.calibration import load_calibration

    camera = config.camera
    if not told_height_only(camera, file_has_pose=False):
        return False
    return not camera.calibration or load_calibration(camera.calibration).R is None


def model_for(config: Config) -> Config:
    """``core.config.model_for_camera`` for ``config``, its calibration file read for a pose."""
    return model_for_camera(config, file_has_pose=not knows_height_only(config))


def reads_scene(config: Config) -> bool:
    """Whether a run with ``config`` reads its camera from the first frames (when it can)."""
    camera = config.camera
    if camera.read_scene_frames < 0 or not camera.read_scene_s > 0 or camera.read_scene_live_s < 0:
        raise ConfigError(f"camera.read_scene_frames must be 0 (off) or more, camera.read_scene_s above 0 and "
                          f"camera.read_scene_live_s 0 (off) or more, got {camera.read_scene_frames}, "
                          f"{camera.read_scene_s} and {camera.read_scene_live_s}")
    return config.camera.read_scene_frames > 0 and knows_height_only(config)


@dataclass
class SceneReading:
    """The camera read from a scene, and the picture of the reading (``stages/scene_picture.py``:
    the lines that agreed, the horizon, 1.70 m bars), which a run writes beside its outputs."""

    camera: HeightCamera
    picture: np.ndarray


def pose_from_scene(config: Config, images: list[np.ndarray], model=None,
                    needs_lines: bool = True) -> tuple[Config, SceneReading | None]:
    """``config`` with ``[camera]`` posed by the camera read from ``images`` (BGR frames at the
    run's size), and that reading; ``config`` unchanged and None when it knows more of its camera
    than the height (``knows_height_only``), there are no images, the camera read is level or looking up, or (with
    ``needs_lines``) no straight lines of the scene agreed with the heads.

    Why a run needs the lines: without them the camera read is the heads' guess alone, which v2
    makes anyway frame by frame, its offsets erring together with it; posed with that guess (v1,
    moving objects) the held-out scenes without lines (night, rain, parks: 4 of trk_val20, 2 of
    trk_test40) tracked worse (HOTA 0.20 against 0.28, 0.28 against 0.45) for no better height.
    ``heightpipe calibrate --camera-height`` prints even that guess, marked worth checking.

    ``model``: a loaded v2 ``HeightNetModel`` to read with (one is loaded when it is None or a v1).
    """
    from stages.calibration import camera_for_run, fov_from_focal
    from stages.contact_heights import read_scene
    from stages.heightnet_model import HeightNetModel
    from stages.scene_picture import scene_camera_picture

    if not images or not knows_height_only(config):
        return config, None
    if model is None or not model.info.contact:
        model = HeightNetModel(HEIGHT_ONLY_MODEL, config.height.threads, mirror=config.height.mirror)
    height, width = images[0].shape[:2]
    # A lens-only file's focal length is used as given (and its distortion removed: read_scene).
    used, reader = read_scene(model, images, camera_for_run(config.camera, width, height))
    if used is None or not MIN_PITCH_DEG <= used.pitch_deg < 90.0 or (needs_lines and not used.edges):
        return config, None
    posed = replace(config.camera, pitch_deg=round(used.pitch_deg, 2), roll_deg=round(used.roll_deg, 2),
                    fov_deg=round(fov_from_focal(width, used.focal_px), 2), self_calibrated=True,
                    pitch_std_deg=round(used.pitch_std_deg, 2), roll_std_deg=round(used.roll_std_deg, 2),
                    focal_std_pct=round(used.focal_std_pct, 1))
    picture = scene_camera_picture(reader.samples.median(), used, width, reader.edge_fit)
    return replace(config, camera=posed), SceneReading(used, picture)


def opening_images(frames: Iterator, count: int, span_s: float) -> tuple[list[np.ndarray], int]:
    """Up to ``count`` images spread over the first ``span_s`` seconds of ``frames`` (``Frame``s
    of a live stream, taken from it), and how many frames were taken. Each slot of ``span_s /
    count`` seconds keeps its first frame, so nothing piles up in memory at any frame rate."""
    if count <= 0 or span_s <= 0:
        return [], 0
    images: list[np.ndarray] = []
    taken, start = 0, None
    for frame in frames:
        taken += 1
        start = frame.time_s if start is None else start
        elapsed = frame.time_s - start
        if elapsed >= len(images) * span_s / count and len(images) < count:
            images.append(frame.image)
        if elapsed >= span_s * (count - 1) / count:
            break
    return images, taken
