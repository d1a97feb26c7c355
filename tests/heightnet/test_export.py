import json

import cv2
import numpy as np
import pytest

from heightnet.predict import HeightPredictor, height_to_png16, predict_to_folder
from core.errors import ConfigError, ModelError, SourceError


def test_export_matches_pytorch_and_carries_the_contract_metadata(exported_model):
    import onnx

    _, report = exported_model
    assert report.max_abs_diff_height < 1e-3 and report.max_abs_diff_ground < 1e-3
    model = onnx.load(str(report.path))
    meta = {p.key: p.value for p in model.metadata_props}
    assert meta["heightpipe.format_version"] == "1"
    assert (meta["heightpipe.input_width"], meta["heightpipe.input_height"]) == ("96", "64")
    assert len(json.loads(meta["heightpipe.mean"])) == 3 and len(json.loads(meta["heightpipe.std"])) == 3
    assert meta["heightpipe.color_order"] == "RGB"
    assert meta["heightpipe.output_units"] == "camera_height_fraction"
    assert meta["heightpipe.architecture"] == "light"
    assert meta["heightpipe.training_data_hash"] == "abc123"
    assert meta["heightpipe.trained_steps"] == "7"
    assert [i.name for i in model.graph.input] == ["image"]
    assert [o.name for o in model.graph.output] == ["height", "ground_logit"]


def test_predict_returns_metres_at_frame_size(exported_model):
    _, report = exported_model
    predictor = HeightPredictor(report.path, threads=1)
    rgb = np.random.default_rng(0).integers(0, 255, (90, 160, 3), dtype=np.uint8)
    one = predictor.predict(rgb, camera_height_m=1.0)
    two = predictor.predict(rgb, camera_height_m=2.0)
    assert one.height_m.shape == (90, 160) and one.ground_probability.shape == (90, 160)
    assert (one.height_m >= 0).all()
    np.testing.assert_allclose(two.height_m, 2 * one.height_m, rtol=1e-5)
    with pytest.raises(ConfigError, match="camera"):
        predictor.predict(rgb)


def test_predict_writes_uint16_millimetre_pngs(exported_model, tmp_path):
    _, report = exported_model
    images = tmp_path / "images"
    images.mkdir()
    rgb = np.random.default_rng(1).integers(0, 255, (60, 80, 3), dtype=np.uint8)
    cv2.imwrite(str(images / "a.png"), rgb)
    cv2.imwrite(str(images / "b.jpg"), rgb)
    predictor = HeightPredictor(report.path, threads=1)
    written = predict_to_folder(images, tmp_path / "out", predictor, camera_height_m=5.0)
    assert [p.name for p in written] == ["a.png", "b.png"]
    png = cv2.imread(str(written[0]), cv2.IMREAD_UNCHANGED)
    assert png.dtype == np.uint16 and png.shape == (60, 80)
    expected = height_to_png16(predictor.predict(cv2.cvtColor(rgb, cv2.COLOR_BGR2RGB), 5.0).height_m)
    assert np.abs(png.astype(int) - expected.astype(int)).max() <= 1
    assert (tmp_path / "out" / "a_color.jpg").is_file()


def test_height_png_is_millimetres_with_ground_zero():
    png = height_to_png16(np.array([[0.0, 1.8], [np.nan, 70.0]]))
    assert png.tolist() == [[0, 1800], [0, 65535]]


def test_missing_inputs_raise_clear_errors(exported_model, tmp_path):
    _, report = exported_model
    with pytest.raises(ModelError):
        HeightPredictor(tmp_path / "none.onnx")
    with pytest.raises(SourceError):
        predict_to_folder(tmp_path / "nothing", tmp_path / "out", HeightPredictor(report.path), 5.0)


def test_cli_predict_reports_a_missing_model(tmp_path, capsys):
    from pipeline.cli import main

    code = main(["predict", str(tmp_path), "--out", str(tmp_path / "o"), "--model",
                 str(tmp_path / "missing.onnx"), "--camera-height", "5"])
    assert code == 2
    assert "height model not found" in capsys.readouterr().err
