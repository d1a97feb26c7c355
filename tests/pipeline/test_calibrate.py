"""`heightpipe calibrate --out`: the fit as a complete calibration JSON that `run` reads back."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from pipeline.calibrate import write_calibration_json
from stages.calibration import angles_from_rotation, load_calibration


def fake_result():
    K = np.array([[800.0, 0, 320], [0, 800.0, 180], [0, 0, 1]])
    return SimpleNamespace(width=640, height=360, K=K, height_m=6.2, pitch_deg=21.5, roll_deg=-1.2,
                           height_std_m=0.3, n_tracks=12, prior=SimpleNamespace(mean_m=1.7, std_m=0.09),
                           focal_source="estimated")


def test_written_calibration_loads_as_the_fitted_camera(tmp_path):
    intrinsics = tmp_path / "intrinsics.json"
    intrinsics.write_text(json.dumps({"image_size": [640, 360], "K": [[800, 0, 320], [0, 800, 180], [0, 0, 1]],
                                      "dist": [-0.1, 0.01, 0, 0, 0]}))
    out = tmp_path / "camera.json"
    write_calibration_json(str(out), fake_result(), str(intrinsics))
    camera = load_calibration(out)
    assert camera.height_m == pytest.approx(6.2)
    pitch, roll, _ = angles_from_rotation(camera.R)
    assert (pitch, roll) == pytest.approx((21.5, -1.2), abs=1e-6)
    assert np.allclose(camera.K, fake_result().K) and np.allclose(camera.dist, [-0.1, 0.01, 0, 0, 0])
    assert "self-calibrated from 12 people" in json.loads(out.read_text())["source"]


def test_readme_calibration_example_loads():
    from media import REPO_ROOT

    camera = load_calibration(REPO_ROOT / "docs" / "calibration_example.json")
    assert camera.height_m == pytest.approx(4.5) and camera.dist is not None
