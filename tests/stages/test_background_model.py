"""The background model's mask clean-up."""

from __future__ import annotations

import numpy as np

from stages.background_model import drop_small_pieces


def test_sensor_noise_specks_are_dropped_but_thin_legs_stay():
    mask = np.zeros((40, 40), bool)
    mask[5:25, 10:16] = True                                   # a body ...
    mask[25:35, 11] = mask[25:35, 14] = True                   # ... on one-pixel legs
    mask[30, 30] = mask[2, 2] = True                          # single-pixel noise
    mask[20:22, 35:37] = True                                  # a 4-pixel speck
    kept = drop_small_pieces(mask, 8)
    assert kept[5:35, 10:16].sum() == mask[5:35, 10:16].sum()
    assert not kept[30, 30] and not kept[2, 2] and not kept[20:22, 35:37].any()
