"""The camera heads' running mean: weighted by inverse variance, spread not shrunk by repetition."""

import math

import numpy as np
import pytest

from stages.camera_heads import HeadsAverage


def test_weighted_mean_and_per_frame_spread():
    heads = HeadsAverage()
    assert np.isnan(heads.mean).all() and heads.frames == 0
    heads.add([0.2, 0.0, 0.1, math.log(0.01), 0.0, 0.0])   # sure: std 0.1
    heads.add([0.6, 0.2, 0.3, math.log(0.04), 0.0, 0.0])   # less sure: std 0.2
    assert heads.mean[0] == pytest.approx((100 * 0.2 + 25 * 0.6) / 125)
    assert heads.mean[1:] == pytest.approx([0.1, 0.2])
    assert heads.std[0] == pytest.approx(math.sqrt(2 / 125))


def test_repeating_a_frame_does_not_make_the_heads_surer():
    """Frames of one camera share the heads' error: the spread is per frame, not a standard error."""
    heads = HeadsAverage()
    for _ in range(100):
        heads.add([0.3, 0.0, 0.0, math.log(0.25), math.log(0.25), math.log(0.25)])
    assert heads.std == pytest.approx([0.5, 0.5, 0.5])
    assert heads.mean == pytest.approx([0.3, 0.0, 0.0])


def test_non_finite_frames_are_skipped_and_wild_variances_clipped():
    heads = HeadsAverage()
    heads.add([np.nan, 0.0, 0.0, 0.0, 0.0, 0.0])
    assert heads.frames == 0
    heads.add([0.1, 0.0, 0.0, -1e6, 0.0, 0.0])
    heads.add([0.5, 0.0, 0.0, 0.0, 0.0, 0.0])
    assert heads.frames == 2 and np.isfinite(heads.mean).all()
    assert 0.1 < heads.mean[0] < 0.1 + 1e-6
