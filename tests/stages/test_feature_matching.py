import copy

import cv2
import numpy as np
import pytest

from core.config import GroundConfig, MatchingConfig
from core.packets import CameraInfo, Frame, FramePacket
from stages.feature_matching import FeatureMatcher, KeypointDetector


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


def _still_and_drifting_points(n_still: int, n_drifting: int, drift_px: float, seed: int = 0):
    rng = np.random.default_rng(seed)
    prev = rng.uniform(0, 300, (n_still + n_drifting, 2)).astype(np.float32)
    curr = prev + rng.normal(0, 0.1, prev.shape).astype(np.float32)
    curr[n_still:, 0] += drift_px
    return prev, curr


def test_a_still_camera_is_not_given_the_motion_of_a_drifting_shadow():
    """70 background points stand still, 45 (a vehicle's shadow on the road) drift 2.5 px: at
    RANSAC's 3 px a ~1 px shift explains them all, but standing still explains more points
    closely, and the camera is fixed."""
    matcher = FeatureMatcher(MatchingConfig(), GroundConfig())
    motion, agree = matcher._camera_motion(*_still_and_drifting_points(70, 45, 2.5))
    assert np.allclose(motion, np.eye(2, 3))
    assert agree.sum() >= 70


def test_a_hidden_background_gives_no_camera_motion():
    """A bus fills the view: the few background points left say nothing about the camera."""
    matcher = FeatureMatcher(MatchingConfig(), GroundConfig())
    prev, curr = _still_and_drifting_points(3, 5, 40.0)
    motion, _ = matcher._camera_motion(prev, curr)
    assert np.allclose(motion, np.eye(2, 3))
    # A real shake of many points is still recovered.
    prev, curr = _still_and_drifting_points(0, 80, 4.0)
    motion, agree = matcher._camera_motion(prev, curr)
    assert motion[0, 2] == pytest.approx(4.0, abs=0.2) and agree.sum() >= 75


@pytest.mark.parametrize(("width", "max_width", "expected"),
                         [(320, 320, 2), (640, 320, 2), (1920, 320, 6), (1280, 320, 4), (1921, 320, 7),
                          (1920, 0, 2)])
def test_wide_frames_are_matched_on_an_image_at_most_max_width_wide(width, max_width, expected):
    detector = KeypointDetector(MatchingConfig(downscale=2, max_width=max_width), GroundConfig())
    assert detector.downscale(width) == expected


def test_a_wide_frame_reports_points_in_source_pixels():
    image, height = _scene()
    wide_image = cv2.resize(image, (1280, 720), interpolation=cv2.INTER_NEAREST)
    wide_height = cv2.resize(height, (1280, 720), interpolation=cv2.INTER_NEAREST)
    matcher = FeatureMatcher(MatchingConfig(max_width=320), GroundConfig())
    matcher.process(_packet(0, wide_image, wide_height))
    packet = matcher.process(_packet(1, wide_image, wide_height))
    points = packet.matches.curr_pts
    assert len(points) > 0 and points[:, 0].max() > 640 and points[:, 1].max() > 360
    assert np.allclose(packet.matches.curr_pts, packet.matches.prev_pts, atol=1.0)


def test_keypoints_found_by_their_own_stage_give_the_matches_the_matcher_finds_alone():
    """The overlapped run finds keypoints on the network's thread and matches on the caller's:
    the matches must be those of the matcher finding its own keypoints."""
    frames = [_packet(i, *_scene(shift, object_x=100 + 4 * i)) for i, shift in enumerate([0.0, 2.0, 3.5])]
    alone, matcher = FeatureMatcher(MatchingConfig(), GroundConfig()), FeatureMatcher(MatchingConfig(), GroundConfig())
    detector = KeypointDetector(MatchingConfig(), GroundConfig())
    for index, frame in enumerate(frames):
        expected = alone.process(copy.copy(frame)).matches
        packet = detector.process(copy.copy(frame))
        assert packet.keypoints is not None and len(packet.keypoints.keypoints) > 50
        got = matcher.process(packet).matches
        if index == 0:
            assert expected is None and got is None
            continue
        for field in ("prev_pts", "curr_pts", "on_object", "camera_motion"):
            np.testing.assert_array_equal(getattr(got, field), getattr(expected, field))
