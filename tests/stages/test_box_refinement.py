"""The box refiner at run time: crops, edge moves, the ONNX file's contract, which model it refines."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from core.errors import ConfigError, ModelError
from heightnet.box_refiner import CROP_SIZE, MARGIN, BoxRefinerNet, export_refiner
from stages.box_refinement import (SHIPPED_REFINER, BoxRefiner, box_crops, crop_window, file_digest, moved_edges,
                                   refiner_for)
from stages.heightnet_model import SHIPPED_MODEL, SHIPPED_V2_MODEL


def _refiner_file(tmp_path, left_share: float = 0.0, digest: str = "abc") -> str:
    """A refiner whose only output is ``left_share`` on the left edge (its crop read for nothing)."""
    torch.manual_seed(0)
    net = BoxRefinerNet()
    with torch.no_grad():
        net.edges.bias.copy_(torch.tensor([left_share, 0.0, 0.0, 0.0]))
    path = tmp_path / "refiner.onnx"
    export_refiner(net, path, digest)
    return str(path)


def test_the_crop_window_grows_the_box_by_its_margin():
    window = crop_window(np.array([[10, 20, 30, 60]]), (0.5, 0.25))
    np.testing.assert_allclose(window, [[0, 10, 40, 70]])


def test_a_box_fills_the_middle_of_its_crop():
    # A dark 20 x 40 block on a light image, boxed exactly: with half the width added at each
    # side the block spans the crop's middle half of columns, and (a quarter of the height above
    # and below) its middle two thirds of rows.
    image = np.full((120, 160, 3), 200, np.uint8)
    image[40:80, 70:90] = 20
    crop = box_crops(image, np.array([[70, 40, 90, 80]], np.float32), (32, 64), (0.5, 0.25))[0]
    dark = crop[..., 0] < 110
    columns, rows = np.flatnonzero(dark.any(0)), np.flatnonzero(dark.any(1))
    assert (columns.min(), columns.max()) == (8, 23)
    assert abs(rows.min() - 64 / 6) <= 1 and abs(rows.max() + 1 - 64 * 5 / 6) <= 1


@pytest.mark.parametrize("edges, expected", [
    ([0.1, 0.0, 0.0, 0.0], [12.0, 20.0, 30.0, 60.0]),      # left edge in by a tenth of the width
    ([0.0, -0.05, 0.0, 0.05], [10.0, 18.0, 30.0, 62.0]),   # taller by a twentieth at each end
    ([0.6, 0.0, -0.6, 0.0], [10.0, 20.0, 30.0, 60.0]),     # would be narrower than a pixel: kept
])
def test_edges_move_by_shares_of_the_box(edges, expected):
    moved = moved_edges(np.array([[10, 20, 30, 60]], np.float32), np.array([edges], np.float32))
    np.testing.assert_allclose(moved[0], expected, atol=1e-5)


def test_the_refiner_moves_only_the_classes_it_was_trained_on(tmp_path):
    refiner = BoxRefiner(_refiner_file(tmp_path, left_share=0.1))
    assert refiner.crop_size == CROP_SIZE and refiner.margin == MARGIN and refiner.classes == ("person",)
    image = np.random.default_rng(0).integers(0, 255, (96, 128, 3), dtype=np.uint8)
    boxes = np.array([[10, 10, 30, 50], [60, 20, 100, 60]], np.float32)
    refined = refiner.refine(image, boxes, ["person", "vehicle"])
    np.testing.assert_allclose(refined[0], [12, 10, 30, 50], atol=1e-4)
    np.testing.assert_array_equal(refined[1], boxes[1])
    np.testing.assert_array_equal(refiner.refine(image, boxes[1:], ["vehicle"]), boxes[1:])


def test_auto_refines_only_the_model_the_refiner_was_trained_on(tmp_path):
    assert refiner_for("off", SHIPPED_V2_MODEL) is None
    if SHIPPED_REFINER.is_file():
        assert refiner_for("auto", SHIPPED_V2_MODEL) is not None
        assert refiner_for("auto", SHIPPED_MODEL) is None
    named = refiner_for(_refiner_file(tmp_path, digest=file_digest(SHIPPED_MODEL)), SHIPPED_V2_MODEL)
    assert named is not None and named.trained_on == file_digest(SHIPPED_MODEL)


def test_bad_settings_and_files_are_one_clear_error(tmp_path):
    with pytest.raises(ConfigError, match="box_refiner"):
        refiner_for("", SHIPPED_V2_MODEL)
    with pytest.raises(ModelError, match="not found"):
        refiner_for(str(tmp_path / "missing.onnx"), SHIPPED_V2_MODEL)
    with pytest.raises(ModelError, match="not a box refiner"):
        BoxRefiner(SHIPPED_MODEL)
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(b"not onnx")
    with pytest.raises(ModelError, match="not a loadable ONNX model"):
        BoxRefiner(junk)


def _sample_frame() -> np.ndarray:
    import cv2

    capture = cv2.VideoCapture(str(Path(__file__).resolve().parents[2] / "recordings" / "sample.mp4"))
    capture.set(cv2.CAP_PROP_POS_FRAMES, 60)
    ok, frame = capture.read()
    capture.release()
    assert ok
    return frame


def test_the_model_refines_its_person_boxes_from_the_image_it_read(tmp_path):
    from stages.heightnet_model import HeightNetModel

    frame = _sample_frame()
    model = HeightNetModel("v2", detection_min_score=0.1)
    plain = model.run(frame).detections
    model.box_refiner = BoxRefiner(_refiner_file(tmp_path, left_share=0.1))
    refined = model.run(frame).detections
    people = np.array([c == "person" for c in plain.classes])
    assert people.any() and refined.classes == plain.classes
    widths = plain.boxes[:, 2] - plain.boxes[:, 0]
    np.testing.assert_allclose(refined.boxes[people, 0], plain.boxes[people, 0] + 0.1 * widths[people], atol=1e-3)
    np.testing.assert_array_equal(refined.boxes[people, 1:], plain.boxes[people, 1:])
    np.testing.assert_array_equal(refined.boxes[~people], plain.boxes[~people])


def test_a_network_mode_run_refines_the_shipped_v2_by_default_and_no_other_run_does():
    from core.config import load_config
    from pipeline.stage_chain import load_height_model

    network = ["height.model=v2", "objects.source=network"]
    v2 = load_height_model(load_config(None, network))
    assert (v2.box_refiner is not None) == SHIPPED_REFINER.is_file()
    assert load_height_model(load_config(None, [*network, "height.box_refiner=off"])).box_refiner is None
    # Blobs mode reads no network box: nothing to refine.
    assert load_height_model(load_config(None, ["height.model=v2"])).box_refiner is None
    assert load_height_model(load_config(None, ["height.model=v1"])).box_refiner is None
