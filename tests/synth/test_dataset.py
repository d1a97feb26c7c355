"""Writing a sequence and reading it back through the loader API gives the same data."""

from __future__ import annotations

import json

import numpy as np
import pytest

from synth.dataset import CLASS_NAMES, SynthFrame, list_sequences
from synth.writer import write_manifest, write_sequence


@pytest.fixture(scope="module")
def written(tmp_path_factory, street_plan):
    root = tmp_path_factory.mktemp("synth")
    write_sequence(street_plan, root, rgb_format="png")
    write_manifest(root, street_plan.seed)
    return root


def test_loader_round_trip(written, street_plan, street_frames):
    background, frames = street_frames
    (seq,) = list_sequences(written)
    assert len(seq) == len(frames) == street_plan.options.frames
    assert seq.meta.layout == "street_crossing" and seq.meta.split in ("train", "test")
    assert seq.meta.camera.height_m == pytest.approx(5.0)
    np.testing.assert_allclose(seq.meta.camera.K, street_plan.camera.K)
    np.testing.assert_allclose(seq.meta.camera.R, street_plan.camera.R)
    for i, rendered in enumerate(frames):
        f = seq.frame(i)
        assert isinstance(f, SynthFrame)
        assert f.rgb.dtype == np.uint8 and f.rgb.shape == (240, 320, 3)
        assert np.array_equal(f.rgb, rendered.rgb)  # PNG: lossless
        assert np.array_equal(f.depth_m, rendered.depth_m)
        assert np.array_equal(f.bg_depth_m, background.depth_m)
        assert np.array_equal(f.instance, rendered.instance)
        assert np.array_equal(f.semantic, rendered.semantic)
        expected_height = street_plan.camera.height_map(rendered.depth_m)
        finite = np.isfinite(expected_height)
        assert np.array_equal(np.isfinite(f.height_m), finite)
        assert np.abs(f.height_m[finite] - expected_height[finite]).max() < 1e-3
        assert not f.height_m[f.ground].any()
        assert f.time_s == pytest.approx(i / street_plan.options.fps)
        loaded = {o.id: o for o in seq.objects(i)}
        assert set(loaded) == {o.id for o in rendered.objects}
        for o in rendered.objects:
            got = loaded[o.id]
            assert got.cls == o.cls and got.box == o.box
            assert got.height_m == pytest.approx(o.height_m, abs=1e-4)
            assert got.visible_fraction == pytest.approx(o.visible_fraction, abs=1e-4)
            assert got.ground_xy_m == pytest.approx(o.ground_xy_m, abs=1e-4)


def test_gt_is_motchallenge_with_height(written):
    (seq,) = list_sequences(written)
    lines = (seq.path / "gt" / "gt.txt").read_text().splitlines()
    assert lines
    for line in lines:
        frame, oid, x, y, w, h, conf, cls, vis, height = line.split(",")
        assert int(frame) >= 1 and int(oid) >= 1 and conf == "1"
        assert CLASS_NAMES[int(cls)] in ("pedestrian", "cyclist", "car", "van", "truck", "bus")
        assert 0.0 <= float(vis) <= 1.0 and float(height) > 0.5


def test_split_filter_and_manifest(written):
    manifest = json.loads((written / "manifest.json").read_text())
    assert manifest["format"] == "heightpipe-synth/1" and manifest["sequences"] == ["seq00000"]
    (seq,) = list_sequences(written)
    other = "test" if seq.meta.split == "train" else "train"
    assert list_sequences(written, split=other) == []
    assert len(list_sequences(written, split=seq.meta.split)) == 1
    with pytest.raises(ValueError):
        list_sequences(written, split="validation")
