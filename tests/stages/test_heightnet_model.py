from pathlib import Path

import numpy as np
import pytest

from media import make_tiny_height_model
from core.config import GroundConfig
from core.errors import ModelError
from core.packets import CameraInfo, Frame, FramePacket
from stages.ground_segmentation import GroundSegmenter
from stages.height_inference import HeightEstimator
from stages.heightnet_model import SHIPPED_MODEL, HeightNetModel


def _packet(image, camera_height=5.0):
    h, w = image.shape[:2]
    return FramePacket(frame=Frame(0, 0.0, image), camera=CameraInfo(w, h, height_m=camera_height))


def test_metadata_drives_input_size_and_units(tiny_model):
    model = HeightNetModel(tiny_model)
    assert (model.info.input_width, model.info.input_height) == (64, 48)
    assert model.info.output_units == "camera_height_fraction"


def test_height_map_is_metres_at_frame_size_and_zero_on_ground(tiny_model):
    model = HeightNetModel(tiny_model)
    image = np.zeros((90, 120, 3), np.uint8)
    image[20:60, 40:70] = 255
    packet = GroundSegmenter(GroundConfig(), model).process(_packet(image, camera_height=5.0))
    packet = HeightEstimator(model).process(packet)
    assert packet.height_map.shape == (90, 120) and packet.height_map.dtype == np.float32
    # white pixels: 3 channels x 0.15 x (255/255-0.5)/0.5 = 0.45 of camera height
    assert packet.height_map[40, 55] == pytest.approx(0.45 * 5.0, rel=0.02)
    assert packet.ground_mask[5, 5] and not packet.ground_mask[40, 55]
    assert packet.height_map[packet.ground_mask].max() == 0.0


def test_network_runs_once_per_frame(tiny_model):
    model = HeightNetModel(tiny_model)
    packet = _packet(np.zeros((48, 64, 3), np.uint8))
    first = model.infer(packet.frame)
    assert model.infer(packet.frame) is first


def test_missing_model_file(tmp_path):
    with pytest.raises(ModelError, match="model file not found"):
        HeightNetModel(tmp_path / "none.onnx")


def test_not_an_onnx_file(tmp_path):
    path = tmp_path / "bad.onnx"
    path.write_bytes(b"\x00garbage" * 50)
    with pytest.raises(ModelError, match="not a loadable ONNX model"):
        HeightNetModel(path)


def test_wrong_input_shape_is_rejected(tmp_path):
    path = make_tiny_height_model(tmp_path / "m.onnx", width=64, height=48, input_shape=[1, 3, 32, 64])
    with pytest.raises(ModelError, match="input shape"):
        HeightNetModel(path)


def test_model_without_metadata_is_rejected(tmp_path):
    import onnx

    path = make_tiny_height_model(tmp_path / "m.onnx")
    model = onnx.load(str(path))
    del model.metadata_props[:]
    onnx.save(model, str(path))
    with pytest.raises(ModelError, match="lacks heightpipe metadata"):
        HeightNetModel(path)


@pytest.mark.skipif(not SHIPPED_MODEL.exists(), reason="no shipped model yet")
def test_shipped_model_loads():
    model = HeightNetModel()
    out = model.infer(Frame(0, 0.0, np.zeros((360, 640, 3), np.uint8)))
    assert out.height.shape == (360, 640)


def test_shipped_int8_model_loads_with_the_fp32_metadata_and_agrees_with_it():
    """``height.model = "int8"``: the quantised model reads like the FP32 one, to a few per cent."""
    import cv2

    from stages.heightnet_model import SHIPPED_INT8_MODEL

    fp32, int8 = HeightNetModel(""), HeightNetModel("int8")
    assert int8.path == SHIPPED_INT8_MODEL and int8.info == fp32.info
    capture = cv2.VideoCapture(str(SHIPPED_MODEL.parents[2] / "recordings" / "sample.mp4"))
    ok, image = capture.read()
    capture.release()
    assert ok
    a, b = fp32.infer(Frame(0, 0.0, image)), int8.infer(Frame(0, 0.0, image))
    # ONNX Runtime's int8 kernels differ by CPU: 6.8 % of the mean height on an AVX2 machine
    # without VNNI (2026-12-08), under 5 % on the machines before it.
    assert np.mean(np.abs(a.height - b.height)) < 0.08 * np.mean(np.abs(a.height)) + 1e-3


def test_the_shipped_v2_model_is_named_v2():
    from stages.heightnet_model import HeightNetModel

    model = HeightNetModel("v2", threads=1)
    assert model.info.contact


@pytest.mark.parametrize("text, expected", [
    (None, (1.0, 1.0, 1.0)),                 # older models: not measured
    ("[2.2, 1.1, 2.3]", (2.2, 1.1, 2.3)),
    ("[2.2, 1.1]", "three positive"),
    ("[2.2, -1, 2.3]", "three positive"),
    ("[2.2, NaN, 2.3]", "three positive"),
    ("two", "malformed"),
])
def test_the_camera_spread_scale_in_the_metadata(text, expected):
    from stages.heightnet_model import _read_spread_scale

    meta = {} if text is None else {"heightpipe.camera_spread_scale": text}
    if isinstance(expected, tuple):
        assert _read_spread_scale(Path("m.onnx"), meta) == expected
    else:
        with pytest.raises(ModelError, match=expected):
            _read_spread_scale(Path("m.onnx"), meta)


@pytest.mark.parametrize("text, expected", [
    (None, ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))),      # not measured: independent
    ("[[1, 0, -0.8], [0, 1, 0], [-0.8, 0, 1]]", ((1.0, 0.0, -0.8), (0.0, 1.0, 0.0), (-0.8, 0.0, 1.0))),
    ("[[1, 0], [0, 1]]", "3 x 3 correlation"),
    ("[[1, 0, -0.8], [0, 1, 0], [0.8, 0, 1]]", "3 x 3 correlation"),   # not symmetric
    ("[[2, 0, 0], [0, 1, 0], [0, 0, 1]]", "3 x 3 correlation"),        # not ones on the diagonal
    ("[[1, 0, 1.2], [0, 1, 0], [1.2, 0, 1]]", "3 x 3 correlation"),    # not positive definite
    ("[[1, 0, NaN], [0, 1, 0], [NaN, 0, 1]]", "3 x 3 correlation"),
    ("one", "malformed"),
])
def test_the_camera_error_correlation_in_the_metadata(text, expected):
    from stages.heightnet_model import _read_error_correlation

    meta = {} if text is None else {"heightpipe.camera_error_correlation": text}
    if isinstance(expected, tuple):
        assert _read_error_correlation(Path("m.onnx"), meta) == expected
    else:
        with pytest.raises(ModelError, match=expected):
            _read_error_correlation(Path("m.onnx"), meta)


@pytest.mark.parametrize("contact, expected", [(False, 1), (True, 2)])
def test_threads_by_the_model_unless_asked(tmp_path, monkeypatch, contact, expected):
    """``threads = 0``: one thread for v1 (the other stages run on the second core beside it), two
    for the slower v2; at most the cores there are; a number asked for is the number used."""
    from media import make_tiny_contact_model

    import stages.heightnet_model as heightnet_model

    if contact:
        offsets = np.zeros((48, 64, 2), np.float32)
        path = make_tiny_contact_model(tmp_path / "v2.onnx", offsets, [0.4, 0.0, 0.2, -4.0, -4.0, -4.0])
    else:
        path = make_tiny_height_model(tmp_path / "v1.onnx")
    monkeypatch.setattr(heightnet_model.os, "sched_getaffinity", lambda _pid: {0, 1, 2, 3})
    model = HeightNetModel(path, threads=0)
    assert model.threads == expected
    assert model.session.get_session_options().intra_op_num_threads == expected
    assert HeightNetModel(path, threads=3).session.get_session_options().intra_op_num_threads == 3
    monkeypatch.setattr(heightnet_model.os, "sched_getaffinity", lambda _pid: {0})
    assert HeightNetModel(path, threads=0).threads == 1


def test_negative_threads_are_a_config_error(tiny_model):
    from core.errors import ConfigError

    with pytest.raises(ConfigError, match="height.threads must be 0"):
        HeightNetModel(tiny_model, threads=-1)


def test_most_threads_is_the_setting_or_the_larger_model_share_capped_to_the_cores(monkeypatch):
    """What `heightpipe predict` and the side-by-side cameras ask for: ``threads = 0`` on one core
    is one thread, not the two the v2 model would take on a larger machine."""
    import stages.heightnet_model as heightnet_model
    from stages.heightnet_model import most_threads

    monkeypatch.setattr(heightnet_model.os, "sched_getaffinity", lambda _pid: {0, 1, 2, 3})
    assert most_threads(0) == 2
    assert most_threads(3) == 3
    monkeypatch.setattr(heightnet_model.os, "sched_getaffinity", lambda _pid: {0})
    assert most_threads(0) == 1
    assert most_threads(3) == 3
