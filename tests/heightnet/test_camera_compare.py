"""The comparison's nadir fit: exact offsets give the exact nadir; noise and outliers stay close.

What these guard: that the comparison's verdict on the network's offsets (their nadir is useless)
is the network's, not the fit's.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from heightnet.camera_compare import (fit_nadir, frame_lines, nadir_camera, nadir_distance, nadir_pitch,
                                      nadir_roll, snapped, true_nadir)
from stages.ground_contact import angles_of, camera_from_angles, contact_offsets, pixel_grid, world_rays

W, H = 160, 120


def scene(camera):
    """Flat ground with boxes standing on it: heights below the camera where rays descend."""
    rays = world_rays(camera, pixel_grid(W, H))
    heights = np.zeros((H, W))
    heights[40:100, 20:35] = 1.8
    heights[30:110, 90:120] = 3.0
    heights[5:30, 40:150] = 2.5
    heights[rays[..., 2] >= -1e-3] = np.nan   # sky: no ground below
    return heights, heights == 0


CAMERAS = [(6.0, 10.0, 2.0, 130.0), (4.0, 25.0, -2.5, 110.0), (9.0, 45.0, 1.0, 90.0)]


@pytest.mark.parametrize("height_m, pitch, roll, focal", CAMERAS)
def test_exact_offsets_give_the_exact_nadir(height_m, pitch, roll, focal):
    camera = camera_from_angles(W, H, height_m, math.radians(pitch), math.radians(roll), focal)
    offsets = np.nan_to_num(contact_offsets(camera, *scene(camera)))
    V = fit_nadir(frame_lines(offsets), H)
    f = focal / H
    assert nadir_roll(V) == pytest.approx(math.radians(roll), abs=1e-6)
    assert nadir_distance(V) == pytest.approx(f / math.tan(math.radians(pitch)), rel=1e-5)
    assert nadir_pitch(V, f) == pytest.approx(math.radians(pitch), abs=1e-6)
    truth = true_nadir(camera, H)
    assert nadir_distance(truth) == pytest.approx(nadir_distance(V), rel=1e-5)
    assert nadir_roll(truth) == pytest.approx(nadir_roll(V), abs=1e-6)


@pytest.mark.parametrize("height_m, pitch, roll, focal", CAMERAS)
def test_noisy_offsets_with_outliers_stay_close(height_m, pitch, roll, focal):
    """1 px noise on every offset and 10 % of them wild: roll within 0.5 deg, pitch within 1 deg."""
    camera = camera_from_angles(W, H, height_m, math.radians(pitch), math.radians(roll), focal)
    offsets = np.nan_to_num(contact_offsets(camera, *scene(camera)))
    rng = np.random.default_rng(1)
    above = np.hypot(offsets[..., 0], offsets[..., 1]) > 0
    noisy = offsets + rng.normal(0, 1, offsets.shape) * above[..., None]
    wild = above & (rng.random(above.shape) < 0.1)
    noisy[wild] = rng.normal(0, 15, (wild.sum(), 2))
    V = fit_nadir(frame_lines(noisy), H)
    assert abs(math.degrees(nadir_roll(V)) - roll) < 0.5
    assert abs(math.degrees(nadir_pitch(V, focal / H)) - pitch) < 1.0


def test_nadir_cameras_with_true_heads_are_the_true_camera():
    camera = camera_from_angles(W, H, 5.0, math.radians(30), math.radians(1.5), 120.0)
    V = fit_nadir(frame_lines(np.nan_to_num(contact_offsets(camera, *scene(camera)))), H)
    heads = np.array([math.radians(30), math.radians(1.5), math.log(120.0 / H), -4.0, -4.0, -4.0])
    for mode in ("focal", "pitch", "blend"):
        built = nadir_camera(V, heads, W, H, 1.0, 5.0, mode)
        assert np.allclose(angles_of(built), angles_of(camera), atol=1e-6)
        assert built.K[1, 1] == pytest.approx(120.0, rel=1e-5)


def test_snapping_leaves_exact_offsets_alone():
    camera = camera_from_angles(W, H, 5.0, math.radians(30), math.radians(2.0), 120.0)
    offsets = np.nan_to_num(contact_offsets(camera, *scene(camera)))
    assert np.abs(snapped(camera, offsets) - offsets).max() < 1e-3
    vertical = offsets * np.float32([0, 1])
    assert np.abs(snapped(camera, vertical) - offsets).max() < 1e-3
