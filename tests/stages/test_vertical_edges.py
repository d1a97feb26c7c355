"""The scene's vertical edges and the camera heads: the vanishing point, the fit, the sampling."""

import math

import cv2
import numpy as np
import pytest

from core.packets import CameraInfo
from media import pole_scene as media_pole_scene
from media import project
from stages.contact_heights import ContactHeights
from stages.ground_contact import camera_from_angles
from stages.heightnet_model import ModelOutput
from stages.vertical_edges import (FIRST_FIT_SAMPLES, MIN_EDGES, REFIT_MAX_FRAMES, SAMPLE_EVERY, FrameSamples,
                                   edge_residuals, fit_to_edges, ground_families, horizon, point_on_horizon,
                                   scene_segments, vanishing_point)

W, H = 320, 240
TRUE = np.array([math.radians(30.0), math.radians(2.0), math.log(0.9)])   # pitch, roll, log(focal / height)
HEADS_STD = np.array([math.radians(6.0), math.radians(1.1), 0.3])
CORRELATION = np.array([[1.0, 0.0, -0.8], [0.0, 1.0, 0.0], [-0.8, 0.0, 1.0]])


def pole_scene(values=TRUE, poles=8, seed=0):
    """A grey picture of poles standing on flat ground, 6 m below a camera of ``values``, and the
    poles' image segments (foot to top) (``media.pole_scene``)."""
    image, segments, _ = media_pole_scene(values, (W, H), poles, seed)
    return image, segments


@pytest.mark.parametrize("pitch_deg, focal", [(30.0, 200.0), (45.0, 300.0), (15.0, 150.0)])
def test_a_level_cameras_verticals_meet_below_the_centre_at_f_cot_pitch(pitch_deg, focal):
    point = vanishing_point(np.array([math.radians(pitch_deg), 0.0, math.log(focal / H)]), W, H)
    u, v = point[:2] / point[2]
    assert u == pytest.approx((W - 1) / 2)
    assert v - (H - 1) / 2 == pytest.approx(focal / math.tan(math.radians(pitch_deg)))


def test_a_level_camera_has_its_vanishing_point_at_infinity_straight_down():
    point = vanishing_point(np.array([0.0, 0.0, 0.0]), W, H)
    assert point[2] == pytest.approx(0.0, abs=1e-12) and abs(point[0]) < 1e-9 * abs(point[1])
    segments = np.array([[10.0, 10.0, 10.0, 60.0], [10.0, 10.0, 30.0, 60.0]])
    slanted = math.hypot(20, 50) / 2 * math.sin(math.atan2(20, 50))     # half its length x sin(its angle)
    assert np.abs(edge_residuals(point, segments)) == pytest.approx([0.0, slanted])


def test_an_edge_misses_by_half_its_length_times_the_sine_of_its_angle():
    point = np.array([100.0, 1000.0, 1.0])
    along = np.array([[100.0, 0.0, 100.0, 50.0]])           # points straight at it
    turned = np.array([[100.0 - 25 * math.sin(0.1), 25.0 - 25 * math.cos(0.1),
                        100.0 + 25 * math.sin(0.1), 25.0 + 25 * math.cos(0.1)]])
    assert abs(edge_residuals(point, along)[0]) < 1e-9
    assert abs(edge_residuals(point, turned)[0]) == pytest.approx(25 * math.sin(0.1), rel=0.02)


def f_cot_pitch(values):
    """Where the verticals meet, below the centre, in image heights: what the edges measure."""
    return math.exp(values[2]) / math.tan(values[0])


def test_the_edges_pull_a_wrong_heads_estimate_to_the_true_camera():
    """The heads' errors go along their horizon (pitch up, focal length down); the edges fix where
    the verticals meet, which is across it, so together they pin all three."""
    image, _ = pole_scene()
    segments, _ = scene_segments(image)
    assert len(segments) >= 8
    heads = TRUE + np.array([math.radians(4.0), math.radians(-1.5), -0.12])
    fit = fit_to_edges(heads, HEADS_STD, CORRELATION, segments, W, H)
    assert fit is not None and fit.edges >= 8
    assert f_cot_pitch(fit.values) == pytest.approx(f_cot_pitch(TRUE), rel=0.02)
    assert abs(math.degrees(fit.values[0] - TRUE[0])) < 1.0 < math.degrees(abs(heads[0] - TRUE[0]))
    assert abs(math.degrees(fit.values[1] - TRUE[1])) < 0.5
    assert abs(fit.values[2] - TRUE[2]) < 0.05
    assert np.all(fit.std < HEADS_STD)          # the edges add knowledge: the spread narrows


def test_lines_that_are_not_vertical_are_gated_out():
    _, poles = pole_scene()
    rng = np.random.default_rng(1)
    clutter = np.column_stack([rng.uniform(0, W, 40), rng.uniform(0, H, 40)])
    clutter = np.column_stack([clutter, clutter + rng.uniform(10, 40, (40, 1)) * np.array([1.0, 0.1])])  # flat
    heads = TRUE + np.array([math.radians(3.0), 0.0, -0.08])
    fit = fit_to_edges(heads, HEADS_STD, CORRELATION, np.vstack([poles, clutter]), W, H)
    assert fit is not None and fit.edges == len(poles)
    assert f_cot_pitch(fit.values) == pytest.approx(f_cot_pitch(TRUE), rel=0.01)
    assert abs(math.degrees(fit.values[0] - TRUE[0])) < 1.0


def test_too_few_edges_leave_the_heads_alone():
    _, poles = pole_scene(poles=MIN_EDGES - 1)
    assert fit_to_edges(TRUE, HEADS_STD, CORRELATION, poles, W, H) is None
    assert fit_to_edges(TRUE, HEADS_STD, CORRELATION, np.zeros((0, 4)), W, H) is None


def test_a_known_focal_length_stays_put():
    _, poles = pole_scene()
    heads = TRUE + np.array([math.radians(4.0), 0.0, 0.0])
    fit = fit_to_edges(heads, np.array([HEADS_STD[0], HEADS_STD[1], 1e-6]), CORRELATION * 0 + np.eye(3), poles, W, H)
    assert fit.values[2] == pytest.approx(TRUE[2], abs=1e-5)
    assert abs(math.degrees(fit.values[0] - TRUE[0])) < 0.5


def test_segments_on_the_ground_are_told_apart():
    image, _ = pole_scene()
    ground = np.zeros((H, W), bool)
    upright, on_ground = scene_segments(image, ground)
    assert len(upright) >= 8 and len(on_ground) == 0
    upright, on_ground = scene_segments(image, ~ground)
    assert len(upright) == 0 and len(on_ground) >= 8


def test_samples_are_taken_every_few_frames_and_fits_come_at_doubling_counts():
    samples = FrameSamples()
    image = np.zeros((H, W, 3), np.uint8)
    due = [frame for frame in range(1, 1000) if samples.add(image, None)]
    sampled = range(1, 1000, SAMPLE_EVERY)
    assert due[0] == sampled[FIRST_FIT_SAMPLES - 1]
    for before, after in zip(due, due[1:]):   # the first sampled frame at double the count, or 300 on
        assert after == min(f for f in sampled if f >= before + min(before, REFIT_MAX_FRAMES))


def poles_told_only_the_height():
    """A frame of poles, the network's output on it with heads 4 degrees of pitch off (and the
    focal length along), and a run camera that knows only its 6 m height."""
    image, _ = pole_scene()
    heads = np.concatenate([TRUE + np.array([math.radians(4.0), 0.0, -0.1]), 2 * np.log(HEADS_STD / 2.0)])
    output = ModelOutput(None, np.full((H, W), -5.0, np.float32), offsets=np.zeros((48, 64, 2), np.float32),
                         camera=heads.astype(np.float32))
    return cv2.cvtColor(image, cv2.COLOR_GRAY2BGR), output, CameraInfo(W, H, height_m=6.0, source="camera-height")


def test_a_run_told_only_the_height_sharpens_its_heads_with_the_edges():
    """ContactHeights end to end: frames of poles, heads off by 4 degrees of pitch."""
    bgr, output, told_height = poles_told_only_the_height()
    sharpened = ContactHeights(spread_scale=(2.0, 2.0, 2.0), error_correlation=CORRELATION, vertical_edges=True)
    alone = ContactHeights(spread_scale=(2.0, 2.0, 2.0), error_correlation=CORRELATION)
    for _ in range(SAMPLE_EVERY * FIRST_FIT_SAMPLES):
        _, used = sharpened.decode(output, told_height, (W, H), bgr)
        _, heads_only = alone.decode(output, told_height, (W, H), bgr)
    assert heads_only.edges == 0 and heads_only.pitch_deg == pytest.approx(34.0, abs=0.01)
    assert used.edges >= 8 and abs(used.pitch_deg - 30.0) < 1.5
    assert used.pitch_std_deg < heads_only.pitch_std_deg


def test_the_camera_line_says_how_many_edges_agreed():
    from core.packets import HeightCamera
    from stages.sink_common import height_camera_text

    camera = HeightCamera(source="heads", height_m=6.0, pitch_deg=30.2, roll_deg=1.9, focal_px=216.0,
                          pitch_std_deg=1.1, roll_std_deg=0.4, focal_std_pct=6.0, frames=60)
    assert "from the network's camera heads: pitch" in height_camera_text(camera)
    sharpened = height_camera_text(HeightCamera(**{**camera.__dict__, "edges": 16}))
    assert "camera heads and 16 straight lines of the scene: pitch 30.2° ±1.1°" in sharpened


def test_the_config_key_reaches_the_height_stage(tmp_path):
    from core.config import Config, HeightConfig
    from media import make_tiny_contact_model
    from pipeline.stage_chain import build_stage_chain

    heads = [0.4, 0.0, 0.2, -4, -4, -4]
    model = make_tiny_contact_model(tmp_path / "v2.onnx", np.zeros((48, 64, 2), np.float32), heads)
    camera = CameraInfo(64, 48, height_m=5.0, source="camera-height")
    for on in (False, True):
        config = Config(height=HeightConfig(model=str(model), vertical_edges=on))
        chain = build_stage_chain(config, camera)
        height = dict(chain.stages)["height"]
        assert (height.contact.samples is not None) == on


def ground_lines(values=TRUE, directions=((1.0, 0.0), (0.3, 1.0)), per_family=10):
    """Image segments of parallel lines on flat ground 6 m below a camera of ``values``: a
    family per world direction (kerbs, lane markings), 3 m long, side by side."""
    camera = camera_from_angles(W, H, 6.0, values[0], values[1], math.exp(values[2]) * H)
    segments = []
    for dx, dy in directions:
        d = np.array([dx, dy, 0.0]) / math.hypot(dx, dy)
        side = np.array([-d[1], d[0], 0.0])
        for k in range(per_family):
            start = np.array([0.0, 12.0, 0.0]) + (k - per_family / 2) * 0.8 * side - 1.5 * d
            segments.append(project(camera, [start, start + 3.0 * d]).ravel())
    return np.array(segments)


def test_a_point_on_the_horizon_by_its_angle():
    line = horizon(TRUE, W, H)
    for angle in (0.0, 0.7, -1.2, math.pi / 2):
        point = point_on_horizon(line, angle, W, H)
        assert abs(line @ point) < 1e-9 * np.abs(point).max()
    assert point_on_horizon(line, math.pi / 2, W, H)[2] == pytest.approx(0.0, abs=1e-12)   # at infinity


def test_parallel_ground_lines_are_found_as_families():
    covariance = np.diag(HEADS_STD) @ CORRELATION @ np.diag(HEADS_STD)
    families = ground_families(ground_lines(), TRUE + np.array([0.03, 0.0, -0.05]), covariance, W, H)
    assert sorted(len(f.segments) for f in families) == [10, 10]
    rng = np.random.default_rng(2)
    scatter = np.column_stack([rng.uniform(0, W, (30, 2)), rng.uniform(H / 2, H, (30, 2))])[:, [0, 2, 1, 3]]
    assert ground_families(scatter, TRUE, covariance, W, H) == []       # no chance families


def test_ground_lines_fix_the_horizon_the_edges_cannot():
    """Heads off along the direction the verticals cannot see (their f cot pitch kept): only the
    ground lines, which meet on the horizon, bring the camera back."""
    _, poles = pole_scene()
    pitch = TRUE[0] + math.radians(5.0)
    along = np.array([pitch, TRUE[1], math.log(math.exp(TRUE[2]) * math.tan(pitch) / math.tan(TRUE[0]))])
    vertical_only = fit_to_edges(along, HEADS_STD, np.eye(3), poles, W, H)
    with_ground = fit_to_edges(along, HEADS_STD, np.eye(3), poles, W, H, ground_lines())
    assert abs(math.degrees(vertical_only.values[0] - TRUE[0])) > 3.0
    assert abs(math.degrees(with_ground.values[0] - TRUE[0])) < 0.5
    assert abs(with_ground.values[2] - TRUE[2]) < 0.02 and with_ground.edges == len(poles) + 20


def heads_along_the_horizon(pitch_off_deg):
    """The heads off in the one way ground lines alone cannot see: pitch and focal length moved
    together so the horizon (f tan pitch) stays where it is."""
    pitch = TRUE[0] + math.radians(pitch_off_deg)
    return np.array([pitch, TRUE[1], math.log(math.exp(TRUE[2]) * math.tan(TRUE[0]) / math.tan(pitch))])


def test_two_families_at_right_angles_fix_the_focal_length_without_verticals():
    """No verticals (an open car park): two families put the horizon right, and only that they
    cross at right angles on the ground (bays and lanes, tiles) says the focal length."""
    ground = ground_lines(directions=((1.0, 1.0), (-1.0, 1.0)))
    heads = heads_along_the_horizon(6.0)
    fit = fit_to_edges(heads, HEADS_STD, np.eye(3), np.zeros((0, 4)), W, H, ground)
    assert fit is not None and len(fit.families) == 2
    assert abs(math.degrees(fit.values[0] - TRUE[0])) < 0.5
    assert abs(fit.values[2] - TRUE[2]) < 0.05
    assert fit.std[0] < HEADS_STD[0] / 2         # and it says so
    assert fit.square


def test_families_far_from_right_angles_are_not_bent_to_them():
    """A road meeting another at 45 degrees is no grid: the fit leaves pitch and focal length
    along the horizon to the heads, as it did before the right-angle rule."""
    ground = ground_lines(directions=((1.0, 0.0), (1.0, 1.0)))
    heads = heads_along_the_horizon(6.0)
    fit = fit_to_edges(heads, HEADS_STD, np.eye(3), np.zeros((0, 4)), W, H, ground)
    assert fit is not None and len(fit.families) == 2
    assert abs(math.degrees(fit.values[0] - heads[0])) < 1.0       # stayed with the heads
    assert not fit.square
    assert f_tan_pitch(fit.values) == pytest.approx(f_tan_pitch(TRUE), rel=0.02)   # the horizon is right


def test_families_are_searched_again_around_the_fitted_horizon():
    """Heads 5 degrees off in roll: a family meeting far out to the side lies well off their
    horizon, outside the band searched first; the poles right the roll, and the search around
    the fitted horizon finds it."""
    _, poles = pole_scene()
    ground = ground_lines(directions=((0.15, 1.0), (1.0, -0.15)))     # one ahead, one far to the side
    heads = TRUE + np.array([0.0, math.radians(5.0), 0.0])
    std = np.array([HEADS_STD[0], math.radians(2.0), HEADS_STD[2]])
    covariance = np.diag(std) ** 2
    assert len(ground_families(ground, heads, covariance, W, H)) == 1
    fit = fit_to_edges(heads, std, np.eye(3), poles, W, H, ground)
    assert sorted(len(f) for f in fit.families) == [10, 10]
    assert fit.edges == len(poles) + 20
    assert abs(math.degrees(fit.values[1] - TRUE[1])) < 0.3


def f_tan_pitch(values):
    """Where the horizon crosses the middle column, above the centre, in image heights."""
    return math.exp(values[2]) * math.tan(values[0])


def test_the_camera_alone_is_the_camera_decode_reports():
    """``heads_camera`` (calibrate, the bench) skips the heights but not the camera's state."""
    bgr, output, told_height = poles_told_only_the_height()
    decoding = ContactHeights(error_correlation=CORRELATION, vertical_edges=True)
    reading = ContactHeights(error_correlation=CORRELATION, vertical_edges=True)
    for _ in range(SAMPLE_EVERY * FIRST_FIT_SAMPLES):
        _, decoded = decoding.decode(output, told_height, (W, H), bgr)
        assert reading.heads_camera(output, told_height, bgr) == decoded
    assert decoded.edges >= 8
