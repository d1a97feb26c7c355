"""Height ground truth: world z from depth, the paper's Eq. 3, and true object heights."""

from __future__ import annotations

import numpy as np

from synth.dataset import ground_mask


def test_ground_height_is_zero_and_sky_is_nan(street_plan, street_frames):
    background, _ = street_frames
    height = street_plan.camera.height_map(background.depth_m)
    ground = ground_mask(background.semantic)
    assert ground.mean() > 0.2
    # Painted layers sit at most 0.6 mm above the plane; float32 depth adds ~0.01 mm.
    assert np.abs(height[ground]).max() < 1e-3
    sky = background.semantic == 0
    assert np.array_equal(np.isnan(height), sky)
    assert np.array_equal(np.isinf(background.depth_m), sky)


def test_eq3_matches_world_z_within_1mm(street_plan, street_frames):
    """H = C_h (D_bg - D_fg) / D_bg on mover pixels in front of flat ground (z-depth works too)."""
    background, frames = street_frames
    camera = street_plan.camera
    checked = 0
    for frame in frames:
        over_ground = (frame.instance > 0) & ground_mask(background.semantic)
        d_fg, d_bg = frame.depth_m[over_ground], background.depth_m[over_ground]
        eq3 = camera.height_m * (d_bg - d_fg) / d_bg
        world_z = camera.height_map(frame.depth_m)[over_ground]
        assert np.abs(eq3 - world_z).max() < 1e-3
        checked += over_ground.sum()
    assert checked > 100


def test_rendered_heights_match_true_object_heights(street_plan, street_frames):
    """On an unoccluded object the height map's maximum is its true height, within a few cm.

    The true height is the top of the object's surface this frame (stature minus the gait's
    dip for pedestrians). The map only samples pixel centres, so it may fall short by up to
    about one pixel's footprint at the object, and never overshoots.
    """
    _, frames = street_frames
    camera = street_plan.camera
    fine, all_errors = [], []
    for frame in frames:
        height = camera.height_map(frame.depth_m)
        for obj in frame.objects:
            mask = frame.instance == obj.id
            if not mask.any():
                continue
            top = float(height[mask].max())
            assert top <= obj.height_m + 1e-3, (obj, top)
            x, y, w, h = obj.box
            inside = x > 0 and y > 0 and x + w < camera.width and y + h < camera.height
            if obj.visible_fraction > 0.99 and inside:
                footprint = float(np.median(frame.depth_m[mask])) / camera.K[1, 1]  # metres per pixel
                error = obj.height_m - top
                assert error <= 1.5 * footprint + 0.01, (obj, top, footprint)
                all_errors.append(error)
                if footprint <= 0.04:
                    fine.append(error)
    assert len(all_errors) >= 5 and len(fine) >= 2
    assert max(fine) < 0.05, fine
