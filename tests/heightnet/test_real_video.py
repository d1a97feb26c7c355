"""The shipped model on real CCTV frames: people must come out higher than the ground around them."""

from pathlib import Path

import pytest

OXFORD = Path(__file__).resolve().parents[2] / ".." / "shared" / "real" / "oxford_towncentre"


def test_shipped_model_puts_oxford_people_above_their_surroundings():
    from heightnet.predict import HeightPredictor
    from stages.heightnet_model import SHIPPED_MODEL
    from heightnet.real_check import check_people

    if not (OXFORD / "oxford_snipped.mp4").is_file():
        pytest.skip("real clips not available (../shared/real)")
    predictor = HeightPredictor(SHIPPED_MODEL, threads=2)
    if predictor.metadata.get("heightpipe.trained_steps") == "0":
        pytest.skip("the shipped model is the untrained placeholder")
    checks = check_people(predictor, OXFORD / "oxford_snipped.mp4", OXFORD / "gt_with_geometry.csv",
                          every=50)
    assert len(checks) >= 10
    higher = sum(c.torso_m > c.around_m + 0.1 for c in checks)
    assert higher >= 0.8 * len(checks), f"only {higher}/{len(checks)} people above their surroundings"
