"""The per-track filters on their own: box motion, height with per-channel biases, the stature window."""

from __future__ import annotations

import numpy as np
import pytest

from core.config import TrackingConfig
from stages.kalman import (FilterFactory, HeightFilter, MotionFilter, StatureWindow, box_to_z,
                           z_to_box)


@pytest.mark.parametrize("box", [(0.0, 0.0, 10.0, 20.0), (100.5, 40.25, 33.0, 80.0)])
def test_box_state_round_trip(box):
    assert z_to_box(box_to_z(box)) == pytest.approx(box)


def test_a_box_state_never_has_less_than_a_pixel_of_size():
    assert z_to_box(np.array([50.0, 50.0, -3.0, 0.2])) == (49.5, 49.5, 1.0, 1.0)


def _track(filter_: MotionFilter, start: float, step: float, frames: int, size=(20.0, 40.0)) -> None:
    for i in range(1, frames):
        filter_.predict()
        filter_.update((start + step * i, 100.0, *size))


def test_constant_velocity_is_learnt_and_extrapolated():
    motion = MotionFilter((10.0, 100.0, 20.0, 40.0))
    _track(motion, 10.0, 5.0, 30)
    assert motion.velocity == pytest.approx([5.0, 0.0], abs=0.05)
    motion.predict()
    assert motion.box == pytest.approx((10.0 + 5.0 * 30, 100.0, 20.0, 40.0), abs=0.3)


def test_holding_the_size_stops_a_coasting_box_from_shrinking():
    motion = MotionFilter((0.0, 0.0, 40.0, 80.0))
    for i in range(1, 10):
        motion.predict()
        motion.update((0.0, 0.0, 40.0 - 2 * i, 80.0 - 4 * i))
    motion.hold_size()
    size = motion.box[2:]
    for _ in range(20):
        motion.predict()
    assert motion.box[2:] == pytest.approx(size)


@pytest.mark.parametrize("scale", [1.0, 10.0])
def test_gating_distance_is_relative_to_the_box_size(scale):
    """Noise scales with the box: the same relative offset is equally far for a small and a big box."""
    motion = MotionFilter((0.0, 0.0, 10.0 * scale, 20.0 * scale))
    motion.predict()
    near, shifted, far = motion.mahalanobis_sq([
        motion.box,
        (1.0 * scale, 0.0, 10.0 * scale, 20.0 * scale),
        (10.0 * scale, 0.0, 10.0 * scale, 20.0 * scale)])
    assert near == pytest.approx(0.0, abs=1e-9)
    # x variance of the innovation, in units of w^2: start (2/20)^2, + velocity (10/160)^2 and
    # process noise (1/20)^2 from one predict, + measurement noise (1/20)^2. Offset w/10.
    variance = (2 / 20) ** 2 + (10 / 160) ** 2 + 2 * (1 / 20) ** 2
    assert shifted == pytest.approx((1 / 10) ** 2 / variance)   # the same number at both scales
    assert far > TrackingConfig().motion_gate_chi2           # outside the tracker's gate
    assert motion.mahalanobis_sq([]).shape == (0,)


def test_camera_shake_moves_and_scales_the_box():
    motion = MotionFilter((100.0, 50.0, 20.0, 40.0))
    motion.warp(np.array([[2.0, 0.0, 5.0], [0.0, 2.0, -3.0]]))
    # Centre (110, 70) -> (225, 137); the size doubles with the zoom.
    assert motion.box == pytest.approx((225.0 - 20.0, 137.0 - 40.0, 40.0, 80.0))


def test_snapshot_restores_the_exact_state():
    motion = MotionFilter((0.0, 0.0, 10.0, 20.0))
    saved = motion.snapshot()
    _track(motion, 0.0, 3.0, 5)
    motion.restore(saved)
    assert motion.kf.x == pytest.approx(saved.x) and motion.kf.P == pytest.approx(saved.P)
    assert motion.box == (0.0, 0.0, 10.0, 20.0)


def test_without_bias_or_drift_the_height_is_the_mean_of_its_measurements():
    # A constant measured n times with noise s: mean of the readings, variance s^2 / n.
    readings = [1.62, 1.80, 1.71, 1.75, 1.69]
    height = HeightFilter(readings[0], 0.1, process_noise_m=0.0)
    for value in readings[1:]:
        height.predict()
        height.update(value, 0.1)
    assert height.height_m == pytest.approx(np.mean(readings))
    assert height.std_m == pytest.approx(0.1 / np.sqrt(len(readings)))
    assert height.source == "network"


def test_a_channel_bias_is_a_floor_under_the_std():
    """Frames average the white noise away, not a bias the channel has on this object."""
    height = HeightFilter(1.70, 0.1, process_noise_m=0.0, bias_share=0.1)
    for _ in range(500):
        height.predict()
        height.update(1.70, 0.1)
    assert 0.1 * 1.70 <= height.std_m < 0.1 * 1.70 * 1.01


def test_two_channels_settle_by_their_bias_priors():
    """A network with a 20 % bias prior against a geometry with a few pixels: nearly the geometry,
    and a later network-only frame is corrected by the learnt difference."""
    height = HeightFilter(1.50, 0.05, process_noise_m=0.0, bias_share=0.2, geometry_bias_factor=1.0)
    for _ in range(50):
        height.predict()
        height.update(1.50, 0.05, "network")
        height.update(1.75, 0.02, "geometry")
    assert height.source == "fused"
    assert height.updates == {"network": 51, "geometry": 50}
    assert 1.70 < height.height_m < 1.75
    before = height.height_m
    height.update(1.50, 0.05, "network")       # the usual network reading: no pull towards 1.50
    assert height.height_m == pytest.approx(before, abs=0.005)


def test_residual_counts_innovation_standard_deviations():
    height = HeightFilter(1.70, 0.1, process_noise_m=0.0)
    assert height.normalized_residual(1.70, 0.1) == pytest.approx(0.0)
    # State std 0.1 and measurement std 0.1: innovation std sqrt(0.02).
    assert height.normalized_residual(2.00, 0.1) == pytest.approx(0.3 / np.sqrt(0.02))


def test_stature_window_reads_the_top_of_the_gait_not_its_mean():
    window = StatureWindow(size=12, quantile=0.9)
    assert window.add(1.70, 0.0) == 1.70 and window.add(1.60, 0.0) == 1.60   # fewer than 3: as read
    gait = [1.80 - 0.05 * abs(np.sin(np.pi * i / 6)) for i in range(24)]
    estimates = [window.add(h, 0.0) for h in gait]
    assert estimates[-1] == pytest.approx(np.quantile(gait[-12:], 0.9))
    assert estimates[-1] > np.mean(gait[-12:]) + 0.01


def test_stature_window_falls_back_to_the_median_when_noise_dominates():
    window = StatureWindow(size=5, quantile=0.9)
    for value in (1.70, 1.71, 1.69, 1.70, 1.72):
        estimate = window.add(value, 0.5)
    assert estimate == pytest.approx(1.70)


def test_factory_gives_filters_the_configured_noise():
    config = TrackingConfig()
    height = FilterFactory(config).create_height_filter(1.70, 0.1)
    assert height.kf.Q[0, 0] == pytest.approx(config.height_process_noise_m ** 2)
    assert height.kf.P[1, 1] == pytest.approx((config.network_bias_share * 1.70) ** 2)
    assert isinstance(FilterFactory(config).create_motion_filter((0, 0, 5, 5)), MotionFilter)
