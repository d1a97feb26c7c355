import cv2
import numpy as np
import pytest

from pipeline.config import GroundConfig, MatchingConfig
from pipeline.packets import CameraInfo, Frame, FramePacket
from stages.feature_matching import FeatureMatcher


def _scene(shift_x=0.0, object_x=100):
    rng = np.random.default_rng(3)
    texture = cv2.GaussianBlur((rng.random((240, 360)) * 255).astype(np.uint8), (0, 0), 1.5)
    texture = cv2.cvtColor(cv2.equalizeHist(texture), cv2.COLOR_GRAY2BGR)
    shifted = cv2.warpAffine(texture, np.float32([[1, 0, shift_x], [0, 1, 0]]), (360, 240),
                             borderMode=cv2.BORDER_REFLECT)
    image = shifted[:180, :320].copy()
    patch = cv2.resize(texture[:60, :30], (30, 60))[:, :, ::-1]
    image[60:120, object_x:object_x + 30] = patch
    height = np.zeros(image.shape[:2], np.float32)
    height[60:120, object_x:object_x + 30] = 1.7
    return image, height


def _packet(index, image, height):
    packet = FramePacket(frame=Frame(index, index * 0.1, image), camera=CameraInfo(320, 180))
    packet.height_map = height
    return packet


@pytest.mark.parametrize("downscale", [1, 2])
def test_camera_shake_is_recovered_and_object_points_are_flagged(downscale):
    matcher = FeatureMatcher(MatchingConfig(downscale=downscale), GroundConfig())
    matcher.process(_packet(0, *_scene(0.0, object_x=100)))
    packet = matcher.process(_packet(1, *_scene(3.0, object_x=108)))
    m = packet.matches
    assert m is not None and len(m.curr_pts) > 50
    assert m.camera_motion[0, 2] == pytest.approx(3.0, abs=0.5)
    assert m.camera_motion[1, 2] == pytest.approx(0.0, abs=0.5)
    assert m.on_object.sum() >= 5
    object_flow = (m.curr_pts - m.prev_pts)[m.on_object, 0]
    assert np.median(object_flow) == pytest.approx(8.0, abs=1.0)
    background_flow = (m.curr_pts - m.prev_pts)[~m.on_object, 0]
    assert np.median(background_flow) == pytest.approx(3.0, abs=0.5)


def test_first_frame_has_no_matches():
    matcher = FeatureMatcher(MatchingConfig(), GroundConfig())
    assert matcher.process(_packet(0, *_scene())).matches is None
