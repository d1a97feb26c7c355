"""The shipped sample clip decodes and agrees with its ground truth."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from synth.camera import SynthCamera
from synth.scene import CLASS_NAMES

RECORDINGS = Path(__file__).resolve().parents[2] / "recordings"


@pytest.fixture(scope="module")
def sample():
    video, gt_dir = RECORDINGS / "sample.mp4", RECORDINGS / "sample_gt"
    if not video.is_file():
        pytest.skip("recordings/sample.mp4 not rendered (python -m synth.sample)")
    return video, gt_dir, json.loads((gt_dir / "meta.json").read_text())


def test_sample_is_a_small_10_to_20_s_640x360_clip(sample):
    video, gt_dir, meta = sample
    size = video.stat().st_size + sum(p.stat().st_size for p in gt_dir.rglob("*") if p.is_file())
    assert size <= 10 * 1024 * 1024
    cap = cv2.VideoCapture(str(video))
    frames = 0
    while True:
        ok, image = cap.read()
        if not ok:
            break
        assert image.shape == (360, 640, 3)
        frames += 1
    cap.release()
    assert frames == meta["frames_written"]
    assert 10.0 <= frames / meta["fps"] <= 20.0


def test_sample_truth_is_consistent(sample):
    _, gt_dir, meta = sample
    camera = SynthCamera.from_json(meta["camera"])
    assert camera.height_m == pytest.approx(6.4) and meta["time_of_day"] == "day"
    rows = np.loadtxt(gt_dir / "gt.txt", delimiter=",")
    classes = {CLASS_NAMES[int(c)] for c in rows[:, 7]}
    assert {"pedestrian", "car"} <= classes
    assert rows[:, 0].min() == 1 and rows[:, 0].max() <= meta["frames_written"]
    people = rows[[CLASS_NAMES[int(c)] == "pedestrian" for c in rows[:, 7]]]
    assert 1.0 <= people[:, 9].min() and people[:, 9].max() <= 2.0
    # A stored height map: ground 0, objects up to the tallest true height, sky 65535.
    height_mm = cv2.imread(str(gt_dir / "heights" / "000000.png"), cv2.IMREAD_UNCHANGED)
    assert height_mm.dtype == np.uint16 and height_mm.shape == (360, 640)
    finite = height_mm[height_mm != 65535]
    assert (finite == 0).mean() > 0.3
    # The foot point of every object projects inside (or near) its box.
    world = np.loadtxt(gt_dir / "world.txt", delimiter=",")
    assert world.shape[0] == rows.shape[0]
    for row, (frame, oid, x, y) in zip(rows[::25], world[::25]):
        assert row[0] == frame and row[1] == oid
        (u, v), = camera.project(np.array([[x, y, 0.0]]))[0]
        bx, by, bw, bh = row[2:6]
        if row[8] > 0.9 and 0 < bx and bx + bw < 639 and by + bh < 359:
            assert bx - 3 <= u <= bx + bw + 3 and by - 3 <= v <= by + bh + 5
