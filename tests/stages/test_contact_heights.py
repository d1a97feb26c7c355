"""A ground-contact (v2) network at run time: the camera taken in order, and metres from its offsets."""

import json
import math

import numpy as np
import pytest

from media import make_tiny_contact_model, make_tiny_height_model
from core.config import CameraConfig, GroundConfig
from core.errors import ConfigError, ModelError
from core.packets import CameraInfo, Frame, FramePacket
from stages.calibration import camera_centre, camera_for_run, intrinsics_from_fov, rotation_from_angles
from stages.camera_heads import camera_from_heads
from stages.contact_heights import MAX_HEIGHT_M, ContactHeights, camera_source
from stages.ground_contact import PinholeCamera, contact_offsets, heights_from_offsets
from stages.ground_segmentation import GroundSegmenter
from stages.height_inference import HeightEstimator
from stages.heightnet_model import HeightNetModel, ModelOutput

IN_W, IN_H = 64, 48
HEIGHT_M, PITCH_DEG, ROLL_DEG, FOV_DEG = 6.0, 30.0, 2.0, 60.0


def write_calibration(path, width, height):
    """A calibration file with a pose (camera height, pitch, roll) for frames of width x height."""
    K = intrinsics_from_fov(width, height, FOV_DEG)
    path.write_text(json.dumps({"image_size": [width, height], "K": K.tolist(), "camera_height_m": HEIGHT_M,
                                "pitch_deg": PITCH_DEG, "roll_deg": ROLL_DEG}))
    return path


def height_scene() -> tuple[np.ndarray, np.ndarray]:
    """Input-size height map (a person and a van on flat ground) and its ground mask."""
    height = np.zeros((IN_H, IN_W), np.float32)
    height[20:40, 10:18] = 1.8
    height[14:40, 34:56] = 3.2
    return height, height == 0


def true_input_camera(camera: CameraInfo) -> PinholeCamera:
    return PinholeCamera(camera.K, camera.R, camera_centre(camera)).window(
        0, 0, camera.width, camera.height, IN_W, IN_H)


def output_with(offsets, heads=np.zeros(6)) -> ModelOutput:
    return ModelOutput(None, np.zeros((IN_H, IN_W), np.float32), offsets=offsets,
                       camera=np.asarray(heads, np.float32))


def packet(image, camera):
    return FramePacket(frame=Frame(0, 0.0, image), camera=camera)


@pytest.fixture
def calibrated(tmp_path):
    """The run camera from a calibration file made on 16:9 frames (squashed to the 4:3 input)."""
    config = CameraConfig(calibration=str(write_calibration(tmp_path / "cal.json", 1280, 720)))
    return camera_for_run(config, 128, 72)


# ------------------------------------------------------------------ exact offsets: the wiring

def test_exact_offsets_decode_to_the_height_map_with_a_calibration_file(calibrated):
    height, ground = height_scene()
    offsets = contact_offsets(true_input_camera(calibrated), height, ground)
    metres, used = ContactHeights().decode(output_with(offsets), calibrated, (IN_W, IN_H))
    assert np.abs(metres - height).max() < 0.01
    assert used.source == "calibration" and used.height_m == pytest.approx(HEIGHT_M)
    assert (used.pitch_deg, used.roll_deg) == (pytest.approx(PITCH_DEG), pytest.approx(ROLL_DEG))
    assert used.pitch_std_deg == 0.0


def test_exact_offsets_and_exact_heads_decode_to_the_height_map_with_only_the_camera_height(calibrated):
    """The heads' camera on a squashed frame: pitch, roll and log(fy / image height) as trained."""
    height, ground = height_scene()
    truth = true_input_camera(calibrated)
    offsets = contact_offsets(truth, height, ground)
    heads = [math.radians(PITCH_DEG), math.radians(ROLL_DEG), math.log(truth.K[1, 1] / IN_H), 0, 0, 0]
    only_height = CameraInfo(128, 72, height_m=HEIGHT_M, source="camera-height")
    metres, used = ContactHeights().decode(output_with(offsets, heads), only_height, (IN_W, IN_H))
    assert np.abs(metres - height).max() < 0.01
    assert used.source == "heads" and used.frames == 1
    assert used.focal_px == pytest.approx(calibrated.K[1, 1])
    assert used.pitch_std_deg == pytest.approx(math.degrees(1.0))


def test_exact_offsets_through_the_stage_and_the_onnx_model(tmp_path):
    """Network (fixed outputs) -> HeightEstimator -> height map, frames at the input size."""
    height, ground = height_scene()
    camera = camera_for_run(CameraConfig(calibration=str(write_calibration(tmp_path / "c.json", 640, 480))),
                            IN_W, IN_H)
    offsets = contact_offsets(true_input_camera(camera), height, ground)
    model = HeightNetModel(make_tiny_contact_model(tmp_path / "v2.onnx", offsets, np.zeros(6)))
    out = HeightEstimator(model, camera).process(packet(np.zeros((IN_H, IN_W, 3), np.uint8), camera))
    assert out.height_map.dtype == np.float32 and out.height_map.shape == (IN_H, IN_W)
    assert np.abs(out.height_map - height).max() < 0.01
    assert out.height_camera.source == "calibration"


# ------------------------------------------------------------------ the stage with a v2 model

def test_calibration_file_decode_equals_the_closed_form_with_that_camera(tmp_path, calibrated):
    offsets = np.random.default_rng(0).normal(0, 6, (IN_H, IN_W, 2)).astype(np.float32)
    model = HeightNetModel(make_tiny_contact_model(tmp_path / "v2.onnx", offsets, np.zeros(6)))
    image = np.full((72, 128, 3), 40, np.uint8)
    out = HeightEstimator(model, calibrated).process(packet(image, calibrated))
    expected = np.clip(heights_from_offsets(true_input_camera(calibrated), offsets), 0, MAX_HEIGHT_M)
    import cv2

    np.testing.assert_allclose(out.height_map, cv2.resize(expected, (128, 72), interpolation=cv2.INTER_LINEAR),
                               atol=1e-4)
    assert out.height_map.max() <= MAX_HEIGHT_M and out.height_map.min() >= 0.0


def test_heads_are_averaged_over_frames_by_their_inverse_variance(tmp_path):
    """Dark and bright frames read different pitches with different confidence: the camera used
    is the weighted mean of both, not the last frame's."""
    offsets = np.random.default_rng(1).normal(0, 4, (IN_H, IN_W, 2)).astype(np.float32)
    bias = np.array([0.5, 0.01, 0.2, -2.0, -1.0, -3.0])
    slope = np.array([0.1, 0.02, 0.05, 1.0, 0.0, 0.0])   # dark frame: brightness -1, bright: +1
    model = HeightNetModel(make_tiny_contact_model(tmp_path / "v2.onnx", offsets, bias, slope))
    camera = CameraInfo(IN_W, IN_H, height_m=5.0, source="camera-height")
    stage = HeightEstimator(model, camera)
    dark = stage.process(FramePacket(Frame(0, 0.0, np.zeros((IN_H, IN_W, 3), np.uint8)), camera))
    assert dark.height_camera.pitch_deg == pytest.approx(math.degrees(0.4), abs=1e-4)
    bright = stage.process(FramePacket(Frame(1, 0.1, np.full((IN_H, IN_W, 3), 255, np.uint8)), camera))
    readings = np.array([bias - slope, bias + slope])
    weight = np.exp(-readings[:, 3:])
    mean = (weight * readings[:, :3]).sum(0) / weight.sum(0)
    used = bright.height_camera
    assert used.source == "heads" and used.frames == 2
    assert used.pitch_deg == pytest.approx(math.degrees(mean[0]), abs=1e-4)
    assert mean[0] < 0.5, "the dark frame's reading is the surer one (log-variance -3 against -1)"
    assert used.pitch_std_deg == pytest.approx(math.degrees(math.sqrt(2 / weight[:, 0].sum())), abs=1e-4)
    assert used.roll_deg == pytest.approx(math.degrees(mean[1]), abs=1e-4)
    assert used.focal_px == pytest.approx(math.exp(mean[2]) * IN_H, rel=1e-5)
    assert used.focal_std_pct == pytest.approx(math.expm1(math.sqrt(math.exp(-3))) * 100, rel=1e-4)
    expected = np.clip(heights_from_offsets(camera_from_heads(mean, IN_W, IN_H, (IN_W, IN_H), 5.0), offsets),
                       0, MAX_HEIGHT_M)
    np.testing.assert_allclose(bright.height_map, expected, atol=1e-4)


def test_an_intrinsic_calibration_gives_the_focal_length_and_the_heads_the_rest(tmp_path):
    K = intrinsics_from_fov(IN_W, IN_H, 50.0)
    lens = tmp_path / "lens.json"
    lens.write_text(json.dumps({"image_size": [IN_W, IN_H], "K": K.tolist()}))
    camera = camera_for_run(CameraConfig(calibration=str(lens), height_m=4.0), IN_W, IN_H)
    assert camera.source == "camera-height" and camera.lens_from_file
    offsets = np.zeros((IN_H, IN_W, 2), np.float32)
    _, used = ContactHeights().decode(output_with(offsets, [0.3, 0.0, 0.0, 0, 0, 0]), camera, (IN_W, IN_H))
    assert used.source == "heads" and used.focal_given and used.focal_px == pytest.approx(K[1, 1])


def test_a_pose_in_the_config_is_used_as_given():
    camera = camera_for_run(CameraConfig(height_m=HEIGHT_M, pitch_deg=PITCH_DEG, roll_deg=ROLL_DEG), IN_W, IN_H)
    assert camera_source(camera) == "config"
    height, ground = height_scene()
    offsets = contact_offsets(true_input_camera(camera), height, ground)
    metres, used = ContactHeights().decode(output_with(offsets, [1.0, 1.0, 1.0, 0, 0, 0]), camera, (IN_W, IN_H))
    assert np.abs(metres - height).max() < 0.01, "the heads are not consulted"
    assert used.source == "config"
    self_calibrated = camera_for_run(CameraConfig(height_m=5.0, pitch_deg=20.0, self_calibrated=True), IN_W, IN_H)
    assert camera_source(self_calibrated) == "self"


def test_without_a_camera_a_v2_model_is_one_clear_line(tmp_path):
    model = HeightNetModel(make_tiny_contact_model(tmp_path / "v2.onnx", np.zeros((IN_H, IN_W, 2)), np.zeros(6)))
    nothing = camera_for_run(CameraConfig(), IN_W, IN_H)
    with pytest.raises(ConfigError) as error:
        HeightEstimator(model, nothing)
    message = str(error.value)
    assert "\n" not in message and "--calibration FILE" in message and "--camera-height" in message
    # heightpipe calibrate asks for what stands above the ground only: an assumed height will do
    stage = HeightEstimator(model, nothing, assumed_camera_ok=True)
    out = stage.process(packet(np.zeros((IN_H, IN_W, 3), np.uint8), nothing))
    assert out.height_camera.source == "assumed"


def test_ground_is_zero_and_the_height_method_is_refused(tmp_path):
    height, ground = height_scene()
    camera = CameraInfo(IN_W, IN_H, height_m=5.0, source="camera-height")
    model = HeightNetModel(make_tiny_contact_model(tmp_path / "v2.onnx", np.full((IN_H, IN_W, 2), 3.0), np.zeros(6)))
    image = np.zeros((IN_H, IN_W, 3), np.uint8)
    image[10:30, 20:40] = 255
    out = GroundSegmenter(GroundConfig(), model).process(packet(image, camera))
    out = HeightEstimator(model, camera).process(out)
    assert out.ground_mask[0, 0] and not out.ground_mask[20, 30]
    assert out.height_map[out.ground_mask].max() == 0.0 and out.height_map[20, 30] > 0
    with pytest.raises(ConfigError, match="ground.method"):
        GroundSegmenter(GroundConfig(method="height"), model)


# ------------------------------------------------------------------ the model file

def test_outputs_are_read_by_name_and_unknown_ones_ignored(tmp_path):
    offsets = np.ones((IN_H, IN_W, 2), np.float32)
    model = HeightNetModel(make_tiny_contact_model(tmp_path / "v2.onnx", offsets, np.arange(6), extra_outputs=True))
    assert model.info.contact and "centre_logit" not in model.output_names
    out = model.infer(Frame(0, 0.0, np.zeros((90, 120, 3), np.uint8)))
    assert out.height is None and out.offsets.shape == (IN_H, IN_W, 2)
    assert out.camera.tolist() == pytest.approx(list(range(6)))
    assert out.ground_probability.shape == (90, 120)


def test_a_v2_model_without_its_camera_output_is_rejected(tmp_path):
    import onnx

    path = make_tiny_contact_model(tmp_path / "v2.onnx", np.zeros((IN_H, IN_W, 2)), np.zeros(6))
    model = onnx.load(str(path))
    kept = [o for o in model.graph.output if o.name != "camera"]
    del model.graph.output[:]
    model.graph.output.extend(kept)
    onnx.save(model, str(path))
    with pytest.raises(ModelError, match="missing output 'camera'"):
        HeightNetModel(path)


def test_v1_models_load_and_measure_as_before(tmp_path):
    model = HeightNetModel(make_tiny_height_model(tmp_path / "v1.onnx"))
    assert not model.info.contact
    camera = CameraInfo(IN_W, IN_H, height_m=5.0, source="camera-height")
    out = HeightEstimator(model, camera).process(packet(np.full((IN_H, IN_W, 3), 255, np.uint8), camera))
    assert out.height_map[10, 10] == pytest.approx(0.45 * 5.0, rel=0.02)
    assert out.height_camera is None
    # a v1 model without a camera keeps decoding with the assumed height, as before
    HeightEstimator(model, camera_for_run(CameraConfig(), IN_W, IN_H))


def test_config_pose_rotation_matches_the_heads_convention():
    """The heads' pitch and roll (camera_from_angles) are the calibration's pitch_deg and roll_deg."""
    heads = camera_from_heads([math.radians(PITCH_DEG), math.radians(ROLL_DEG), 0.0], IN_W, IN_H, (IN_W, IN_H), 5.0)
    np.testing.assert_allclose(heads.R, rotation_from_angles(PITCH_DEG, ROLL_DEG), atol=1e-12)


def test_a_known_focal_length_moves_the_heads_pitch_by_how_far_their_focal_length_was_off():
    """Gaussian conditioning: with pitch and focal errors correlated at -0.8, heads that read the
    focal length 0.3 (log) short read the pitch too high by 0.8 x (std_p / std_f) x 0.3."""
    from stages.contact_heights import given_focal

    mean = np.array([0.60, 0.01, np.log(1.0)])
    std = np.array([0.10, 0.02, 0.30])
    correlation = np.array([[1.0, 0.1, -0.8], [0.1, 1.0, 0.0], [-0.8, 0.0, 1.0]])
    conditioned, spread, after = given_focal(mean, std, correlation, np.log(1.0) + 0.3)
    assert conditioned[0] == pytest.approx(0.60 - 0.8 * (0.10 / 0.30) * 0.3)
    assert conditioned[1] == pytest.approx(0.01) and conditioned[2] == pytest.approx(0.3)
    assert spread[0] == pytest.approx(0.10 * np.sqrt(1 - 0.8 ** 2)) and spread[1] == pytest.approx(0.02)
    assert spread[2] < 1e-5 and after[0, 2] == after[2, 0] == 0.0
    assert after[0, 1] == pytest.approx(0.1 / np.sqrt(1 - 0.8 ** 2))
    unrelated, _, _ = given_focal(mean, std, np.eye(3), np.log(1.0) + 0.3)
    assert unrelated[0] == pytest.approx(0.60)                 # uncorrelated errors: the pitch stays
