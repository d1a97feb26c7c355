"""`heightpipe predict` and the run time with an exported HeightNet v2 network (tiny, untrained)."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from core.config import CameraConfig, TrainV2Config
from core.errors import ConfigError
from core.packets import Frame, FramePacket
from heightnet.predict import HeightPredictor, height_to_png16, predict_to_folder
from pipeline.cli import main
from stages.calibration import camera_centre, camera_for_run, intrinsics_from_fov
from stages.contact_heights import MAX_HEIGHT_M
from stages.ground_contact import PinholeCamera, heights_from_offsets
from stages.height_inference import HeightEstimator
from stages.heightnet_model import HeightNetModel

IN_W, IN_H = 64, 64


@pytest.fixture(scope="module")
def v2_model(tmp_path_factory):
    """A ContactNet with small widths, saved as a training state and exported by export_contact."""
    import torch

    from heightnet.contact_export import export_contact
    from heightnet.contact_model import ContactArchitecture, ContactNet
    from heightnet.contact_train import save_state

    torch.manual_seed(0)
    net = ContactNet(ContactArchitecture(widths=(4, 8, 8, 8)))
    with torch.no_grad():  # the offset head starts at zero (flat ground everywhere): give it a slope
        net.offset_head.weight.normal_(0, 0.05)
        net.offset_head.bias.copy_(torch.tensor([0.0, 0.1]))
    net.eval()
    folder = tmp_path_factory.mktemp("v2")
    config = TrainV2Config(out=str(folder), input_width=IN_W, input_height=IN_H)
    state = folder / "checkpoint.pt"
    save_state(state, net, torch.optim.Adam(net.parameters()), step=1, images=2, config=config)
    path = folder / "heightnet_v2.onnx"
    export_contact(state, path)
    return path


def write_calibration(path, width=640, height=480):
    K = intrinsics_from_fov(width, height, 55.0)
    path.write_text(json.dumps({"image_size": [width, height], "K": K.tolist(), "camera_height_m": 5.5,
                                "pitch_deg": 25.0, "roll_deg": -1.0}))
    return path


def test_an_exported_v2_network_decodes_with_the_calibration_camera_in_the_stage(v2_model, tmp_path):
    model = HeightNetModel(v2_model)
    assert model.info.contact
    camera = camera_for_run(CameraConfig(calibration=str(write_calibration(tmp_path / "cal.json"))), 160, 120)
    image = np.random.default_rng(0).integers(0, 255, (120, 160, 3), dtype=np.uint8)
    out = HeightEstimator(model, camera).process(FramePacket(Frame(0, 0.0, image), camera))
    offsets = model.infer(out.frame).offsets
    assert np.abs(offsets).max() > 0.5, "the test network must predict some offsets"
    pinhole = PinholeCamera(camera.K, camera.R, camera_centre(camera)).window(0, 0, 160, 120, IN_W, IN_H)
    expected = np.clip(heights_from_offsets(pinhole, offsets), 0, MAX_HEIGHT_M)
    np.testing.assert_allclose(out.height_map, cv2.resize(expected, (160, 120), interpolation=cv2.INTER_LINEAR),
                               atol=1e-4)
    assert out.height_camera.source == "calibration"


def test_predict_takes_the_calibration_and_averages_the_heads_over_its_inputs(v2_model, tmp_path):
    images = tmp_path / "images"
    images.mkdir()
    rng = np.random.default_rng(1)
    for name in ("a.png", "b.png", "c.png"):
        cv2.imwrite(str(images / name), rng.integers(0, 255, (120, 160, 3), dtype=np.uint8))
    calibration = write_calibration(tmp_path / "cal.json")
    assert main(["predict", str(images), "--out", str(tmp_path / "cal"), "--model", str(v2_model),
                 "--calibration", str(calibration)]) == 0
    predictor = HeightPredictor(v2_model, threads=1)
    written = predict_to_folder(images, tmp_path / "heads", predictor, camera_height_m=5.5)
    assert len(written) == 3 and predictor.height_camera.source == "heads"
    assert predictor.height_camera.frames == 3, "the inputs of one command are one camera's"
    with_file = cv2.imread(str(tmp_path / "cal" / "a.png"), cv2.IMREAD_UNCHANGED)
    camera = camera_for_run(CameraConfig(calibration=str(calibration)), 160, 120)
    rgb = cv2.cvtColor(cv2.imread(str(images / "a.png")), cv2.COLOR_BGR2RGB)
    direct = HeightPredictor(v2_model, threads=1).predict(rgb, camera=camera)
    assert direct.camera.source == "calibration"
    assert np.abs(with_file.astype(int) - height_to_png16(direct.height_m).astype(int)).max() <= 1


def test_predict_without_a_camera_says_which_flag_to_give(v2_model, tmp_path, capsys):
    image = tmp_path / "a.png"
    cv2.imwrite(str(image), np.zeros((48, 64, 3), np.uint8))
    assert main(["predict", str(image), "--out", str(tmp_path / "out"), "--model", str(v2_model)]) == 2
    error = capsys.readouterr().err.strip()
    assert error.count("\n") == 0 and "give --calibration FILE, or --camera-height M" in error
    with pytest.raises(ConfigError, match="--camera-height"):
        HeightPredictor(v2_model).predict(np.zeros((48, 64, 3), np.uint8))


@pytest.mark.parametrize("configured", ["", "int8", "v2"])
def test_the_model_named_in_the_config_is_the_file_the_run_would_load(configured):
    from heightnet.predict import model_path_from_config
    from stages.heightnet_model import NAMED_MODELS, SHIPPED_MODEL

    assert model_path_from_config(configured) == NAMED_MODELS.get(configured, SHIPPED_MODEL)
