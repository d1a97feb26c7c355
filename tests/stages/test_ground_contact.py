"""Ground-contact offsets: exact targets, the closed-form decode, crops and flips, torch = NumPy."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from stages.ground_contact import (PinholeCamera, angles_of, camera_from_angles, contact_offsets,
                               heights_from_offsets, torch_heights_from_offsets)
from stages.calibration import rotation_from_angles


def scene(camera: PinholeCamera, width: int, height: int):
    """A height map of flat ground with a 1.8 m wall 12 m ahead and a 4 m box to the left."""
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    rays = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(camera.K).T @ camera.R
    with np.errstate(divide="ignore", invalid="ignore"):
        s_ground = np.where(rays[..., 2] < 0, -camera.C[2] / rays[..., 2], np.inf)
        s_ground[s_ground > 500.0] = np.inf      # the world ends 500 m away, as a render's does
        heights = np.where(np.isfinite(s_ground), 0.0, np.nan)
        dist = s_ground.copy()
        for y_wall, x_range, top in ((12.0, (-2.0, 3.0), 1.8), (20.0, (-9.0, -5.0), 4.0)):
            s = (y_wall - camera.C[1]) / rays[..., 1]
            x = camera.C[0] + s * rays[..., 0]
            z = camera.C[2] + s * rays[..., 2]
            hit = (s > 0) & (s < dist) & (x > x_range[0]) & (x < x_range[1]) & (z >= 0) & (z <= top)
            heights = np.where(hit, z, heights)
            dist = np.where(hit, s, dist)
    ground = np.isfinite(heights) & (heights == 0)
    return heights.astype(np.float32), ground


CAMERAS = [  # height, pitch, roll (deg), vertical focal (px), aspect
    (3.5, 12.0, 0.0, 200.0, 1.0),
    (6.4, 30.0, 2.5, 150.0, 1.0),
    (9.2, 48.0, -3.0, 120.0, 0.75),
]


@pytest.mark.parametrize("cam", CAMERAS)
def test_decode_of_exact_offsets_gives_the_height_map(cam):
    height_m, pitch, roll, focal, aspect = cam
    camera = camera_from_angles(160, 120, height_m, math.radians(pitch), math.radians(roll), focal, aspect)
    heights, ground = scene(camera, 160, 120)
    offsets = contact_offsets(camera, heights, ground)
    labelled = np.isfinite(heights)
    assert (heights[labelled] > 0.5).sum() > 100          # the walls are in view
    assert np.all(offsets[ground] == 0)
    decoded = heights_from_offsets(camera, np.nan_to_num(offsets))
    assert np.abs(decoded - heights)[labelled].max() < 1e-4


def test_offsets_point_down_to_the_foot_of_a_wall():
    camera = camera_from_angles(160, 120, 5.0, math.radians(25), 0.0, 150.0)
    heights, ground = scene(camera, 160, 120)
    offsets = contact_offsets(camera, heights, ground)
    wall = np.isfinite(heights) & (heights > 1.0) & (heights < 1.9)
    v, u = np.nonzero(wall)
    foot = np.stack([u, v], -1) + offsets[v, u]
    # Every wall pixel's contact point lies on the wall's foot line (z = 0 at y = 12 m), which
    # projects below the pixel; its height is 0 there on the map.
    assert np.all(offsets[v, u, 1] > 0)
    rows = np.round(foot[:, 1]).astype(int).clip(0, 119)
    cols = np.round(foot[:, 0]).astype(int).clip(0, 159)
    assert np.median(heights[rows, cols]) < 0.2


def test_window_camera_keeps_the_decode_exact_for_crops_and_flips():
    camera = camera_from_angles(160, 120, 6.4, math.radians(30), math.radians(1.5), 150.0)
    heights, ground = scene(camera, 160, 120)
    x0, y0, w, h = 20, 30, 80, 60
    crop = heights[y0:y0 + h, x0:x0 + w]
    for flip in (False, True):
        window = camera.window(x0, y0, w, h, w, h, flip)
        offsets = contact_offsets(camera, heights, ground)[y0:y0 + h, x0:x0 + w]
        expected = crop
        if flip:
            offsets = offsets[:, ::-1] * np.float32([-1, 1])
            expected = crop[:, ::-1]
        decoded = heights_from_offsets(window, np.nan_to_num(offsets))
        labelled = np.isfinite(expected)
        assert np.abs(decoded - expected)[labelled].max() < 1e-4


def test_torch_decode_matches_numpy():
    camera = camera_from_angles(64, 48, 7.8, math.radians(35), math.radians(-2), 60.0)
    rng = np.random.default_rng(0)
    offsets = rng.normal(0, 4, (48, 64, 2)).astype(np.float32)
    offsets[..., 1] = np.abs(offsets[..., 1])
    expected = heights_from_offsets(camera, offsets)
    got = torch_heights_from_offsets(torch.from_numpy(offsets).permute(2, 0, 1)[None],
                                     torch.tensor(camera.K, dtype=torch.float32)[None],
                                     torch.tensor(camera.R, dtype=torch.float32)[None],
                                     torch.tensor(camera.C, dtype=torch.float32)[None])
    assert np.allclose(got[0, 0].numpy(), expected, atol=2e-3)


@pytest.mark.parametrize("pitch,roll", [(10.0, 0.0), (30.0, 2.0), (50.0, -3.0)])
def test_camera_angles_follow_the_calibration_conventions(pitch, roll):
    camera = camera_from_angles(320, 240, 5.0, math.radians(pitch), math.radians(roll), 250.0)
    assert np.allclose(camera.R, rotation_from_angles(pitch, roll), atol=1e-12)
    got_pitch, got_roll = angles_of(camera)
    assert got_pitch == pytest.approx(math.radians(pitch), abs=1e-9)
    assert got_roll == pytest.approx(math.radians(roll), abs=1e-9)
