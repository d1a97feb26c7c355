"""Association helpers: the direction term (OC-SORT's momentum)."""

from __future__ import annotations

import numpy as np
import pytest

from stages.association import direction_mismatch


def test_direction_mismatch_is_zero_ahead_one_behind_and_half_aside():
    origin = (100.0, 100.0, 10.0, 20.0)                      # centre (105, 110)
    ahead, behind, aside = (110.0, 100.0, 10.0, 20.0), (90.0, 100.0, 10.0, 20.0), (100.0, 110.0, 10.0, 20.0)
    mismatch = direction_mismatch(np.array([[3.0, 0.0]]), [origin], [ahead, behind, aside])
    assert mismatch[0] == pytest.approx([0.0, 1.0, 0.5])


def test_direction_mismatch_gives_no_evidence_for_a_still_track_or_a_short_step():
    origin = (100.0, 100.0, 10.0, 20.0)
    still = direction_mismatch(np.array([[0.1, 0.0]]), [origin], [(80.0, 100.0, 10.0, 20.0)])
    short = direction_mismatch(np.array([[3.0, 0.0]]), [origin], [(99.0, 100.0, 10.0, 20.0)])
    assert still[0, 0] == 0.0 and short[0, 0] == 0.0
    assert direction_mismatch(np.zeros((0, 2)), [], [origin]).shape == (0, 1)
