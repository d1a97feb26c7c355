"""Self-calibration from walking people: recovers known cameras within its stated uncertainty."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest

from core.config import CameraConfig, load_config
from core.packets import GEOMETRY, Detection, Frame, FramePacket, Track
from stages.calibration import (angles_from_rotation, camera_for_run, camera_from_pose, intrinsics_from_fov,
                                is_calibrated, load_calibration, pixel_to_ground, project_points,
                                undistort_pixels)
from stages.geometry import GeometryMeasurer
from stages.self_calibration import (FitSettings, HeadFootCollector, HeightPrior, SelfCalibrationError,
                                     self_calibrate)

OXFORD = Path(__file__).resolve().parents[2].parent / "shared" / "real" / "oxford_towncentre"
# The simulated points carry 1.5 px of noise: the fit is told so (the default is box points' ~20 px).
FAST = FitSettings(bootstrap=25, point_noise_px=1.5)


def walking_people(camera, n_people=25, n_frames=30, noise_px=1.5, seed=0, statures=None):
    """Head and foot points of people walking straight lines at 1.4 m/s (10 fps) in view."""
    rng = np.random.default_rng(seed)
    if statures is None:
        statures = rng.normal(1.70, 0.09, n_people)
    foot, top, ids = [], [], []
    for person, stature in enumerate(statures):
        while True:
            start = pixel_to_ground(camera, [[rng.uniform(0, camera.width), rng.uniform(0.3, 1.0) * camera.height]])[0]
            if np.all(np.isfinite(start)):
                break
        heading = rng.uniform(0, 2 * math.pi)
        for k in range(n_frames):
            x, y = start + k * 0.14 * np.array([math.cos(heading), math.sin(heading)])
            f, t = project_points(camera, [[x, y, 0.0], [x, y, stature]])
            if not (np.all(f >= 0) and np.all(t >= 0) and f[0] < camera.width and f[1] < camera.height
                    and t[0] < camera.width):
                continue
            foot.append(f + rng.normal(0, noise_px, 2))
            top.append(t + rng.normal(0, noise_px, 2))
            ids.append(person)
    return np.array(foot), np.array(top), np.array(ids)


def assert_within(value, truth, std, sigmas, absolute):
    assert abs(value - truth) < sigmas * std, f"{value:.3f} vs {truth:.3f}: more than {sigmas} x {std:.3f}"
    assert abs(value - truth) < absolute, f"{value:.3f} vs {truth:.3f}"


@pytest.mark.parametrize("height_m,pitch,roll,box_points", [
    (6.0, 25.0, 2.0, False),
    (4.0, 12.0, -3.0, False),
    (4.0, 12.0, -3.0, True),      # the object extractor's points: top and foot in the box's centre column
])
def test_recovers_a_known_camera_within_its_uncertainty(height_m, pitch, roll, box_points):
    K = intrinsics_from_fov(1280, 720, 60.0)
    camera = camera_from_pose(1280, 720, K, height_m, pitch, roll)
    foot, top, ids = walking_people(camera, seed=2)
    if box_points:
        top[:, 0] = foot[:, 0]
    result = self_calibrate(foot, top, ids, 1280, 720, K, focal_known=True, settings=FAST)
    assert_within(result.height_m, height_m, result.height_std_m, 3, 0.06 * height_m)
    assert_within(result.pitch_deg, pitch, result.pitch_std_deg, 3, 1.0)
    assert_within(result.roll_deg, roll, result.roll_std_deg, 3, 1.0)
    # The camera height's uncertainty is dominated by the population prior, as it should be.
    assert 0.02 * height_m < result.height_std_m < 0.06 * height_m
    assert result.camera().source == "self"


def test_box_points_as_noisy_as_real_ones_still_bracket_the_camera():
    """Points 20 px off (as the tracker's box tops and bottoms are on Oxford) and the default
    noise model: the estimate is rougher but its stated uncertainty still covers the truth."""
    K = intrinsics_from_fov(1280, 720, 60.0)
    camera = camera_from_pose(1280, 720, K, 6.0, 25.0, 2.0)
    foot, top, ids = walking_people(camera, noise_px=20.0, seed=4)
    result = self_calibrate(foot, top, ids, 1280, 720, K, focal_known=True, settings=FitSettings(bootstrap=25))
    assert_within(result.height_m, 6.0, result.height_std_m, 3, 0.25 * 6.0)
    assert_within(result.pitch_deg, 25.0, result.pitch_std_deg, 3, 5.0)
    assert_within(result.roll_deg, 2.0, result.roll_std_deg, 3, 5.0)


def test_an_assumed_field_of_view_is_part_of_the_uncertainty():
    true_K = intrinsics_from_fov(1280, 720, 60.0)
    camera = camera_from_pose(1280, 720, true_K, 6.0, 25.0, 0.0)
    foot, top, ids = walking_people(camera, seed=3)
    known = self_calibrate(foot, top, ids, 1280, 720, true_K, focal_known=True, settings=FAST)
    assumed = self_calibrate(foot, top, ids, 1280, 720, intrinsics_from_fov(1280, 720, 45.0), settings=FAST)
    assert assumed.focal_source == "assumed" and any("field of view assumed" in n for n in assumed.notes)
    assert abs(assumed.height_m - 6.0) > abs(known.height_m - 6.0)      # the wrong focal length hurts ...
    assert abs(assumed.height_m - 6.0) < 2 * assumed.height_std_m        # ... and the uncertainty says so
    assert assumed.height_std_m > 2 * known.height_std_m


def test_upright_people_cue_estimates_the_focal_length():
    """With head points independent of foot points, head-foot lines fix the vertical vanishing point."""
    true_K = intrinsics_from_fov(1280, 720, 60.0)
    camera = camera_from_pose(1280, 720, true_K, 6.0, 25.0, 2.0)
    foot, top, ids = walking_people(camera, seed=1)
    result = self_calibrate(foot, top, ids, 1280, 720, intrinsics_from_fov(1280, 720, 45.0),
                            settings=FitSettings(bootstrap=25, use_lean=True, point_noise_px=1.5))
    assert result.focal_source == "estimated"
    assert_within(result.K[0, 0], true_K[0, 0], result.focal_std_px, 3, 0.05 * true_K[0, 0])
    assert_within(result.height_m, 6.0, result.height_std_m, 3, 0.3)
    # Box-centre points carry no such cue: the focal length stays assumed.
    top[:, 0] = foot[:, 0]
    boxes = self_calibrate(foot, top, ids, 1280, 720, true_K,
                           settings=FitSettings(bootstrap=5, use_lean=True, point_noise_px=1.5))
    assert boxes.focal_source == "assumed"


def test_blobs_that_are_not_whole_people_are_left_out():
    K = intrinsics_from_fov(1280, 720, 60.0)
    camera = camera_from_pose(1280, 720, K, 6.0, 25.0, 1.0)
    foot, top, ids = walking_people(camera, n_people=20, seed=4)
    # Heads, legs and bags: steady tracks far shorter than people.
    parts = walking_people(camera, n_people=6, seed=5, statures=np.random.default_rng(6).uniform(0.4, 0.9, 6))
    foot = np.vstack([foot, parts[0]])
    top = np.vstack([top, parts[1]])
    ids = np.concatenate([ids, parts[2] + 100])
    result = self_calibrate(foot, top, ids, 1280, 720, K, focal_known=True, settings=FAST)
    assert result.n_tracks <= 20 and any("left out" in note for note in result.notes)
    assert_within(result.height_m, 6.0, result.height_std_m, 3, 0.4)
    assert_within(result.pitch_deg, 25.0, result.pitch_std_deg, 3, 1.0)


def test_too_few_people_is_an_error():
    K = intrinsics_from_fov(640, 480, 60.0)
    camera = camera_from_pose(640, 480, K, 5.0, 30.0)
    foot, top, ids = walking_people(camera, n_people=4, seed=0)
    with pytest.raises(SelfCalibrationError, match="at least 5 people"):
        self_calibrate(foot, top, ids, 640, 480, K, settings=FAST)


def test_refuses_when_most_blobs_disagree():
    """Three people among nine steady blobs of assorted heights: no confident wrong camera."""
    K = intrinsics_from_fov(1280, 720, 60.0)
    camera = camera_from_pose(1280, 720, K, 6.0, 25.0)
    foot, top, ids = walking_people(camera, n_people=12, seed=9,
                                    statures=np.r_[[1.7] * 3, np.linspace(0.3, 3.0, 9)])
    with pytest.raises(SelfCalibrationError, match="look like people of one height"):
        self_calibrate(foot, top, ids, 1280, 720, K, focal_known=True, settings=FAST)


@pytest.mark.skipif(not OXFORD.is_dir(), reason="shared/real/oxford_towncentre missing")
def test_oxford_annotated_people_give_the_calibrated_camera():
    """Real annotations (16 people, 4 s) with the calibration's intrinsics and their 1.80 m."""
    reference = load_calibration(OXFORD / "calib_opencv.json")
    with open(OXFORD / "gt_with_geometry.csv") as f:
        rows = [r for r in csv.DictReader(f) if r["foot_inside_image"] == "1"]
    foot = undistort_pixels(reference, [[float(r["foot_u"]), float(r["foot_v"])] for r in rows])
    top = undistort_pixels(reference, [[float(r["headtop_u"]), float(r["headtop_v"])] for r in rows])
    ids = np.array([int(r["person"]) for r in rows])
    result = self_calibrate(foot, top, ids, 1920, 1080, reference.K, focal_known=True,
                            prior=HeightPrior(mean_m=1.80, std_m=0.09), settings=FAST)
    pitch, roll, _ = angles_from_rotation(reference.R)
    assert_within(result.height_m, reference.height_m, result.height_std_m, 2, 0.4)
    assert abs(result.pitch_deg - pitch) < 0.6 and abs(result.roll_deg - roll) < 1.0


def test_collector_keeps_upright_confirmed_tracks_clear_of_the_border():
    def track(track_id, box, **kw):
        return Track(track_id=track_id, box=box, cls=kw.pop("cls", "person"), height_m=1.7, height_std_m=0.1,
                     confirmed=kw.pop("confirmed", True), updated=kw.pop("updated", True))

    collector = HeadFootCollector(640, 480)
    for frame in range(6):
        collector.add([
            track(1, (100 + frame, 100, 30, 90)),                       # a person: kept
            track(2, (300, 100, 120, 60), cls="other"),                 # wider than tall
            track(3, (200, 100, 30, 90), cls="vehicle"),
            track(4, (400, 100, 30, 90), confirmed=False),
            track(5, (500, 100, 30, 90), updated=False),                # a predicted box
            track(6, (600, 300, 30, 180)),                              # cut by the bottom border
            track(7, (50, 50, 20, 60)) if frame < 3 else track(8, (60, 60, 20, 60)),  # too short
        ])
    foot, top, ids = collector.arrays(min_frames=5)
    assert set(ids) == {1} and len(ids) == 6
    assert foot[0] == pytest.approx([115, 190]) and top[0] == pytest.approx([115, 100])


def test_snippet_configures_a_self_calibrated_camera_that_measures_people(tmp_path):
    K = intrinsics_from_fov(1280, 720, 60.0)
    camera = camera_from_pose(1280, 720, K, 5.0, 20.0, -1.0)
    foot, top, ids = walking_people(camera, seed=7)
    # Through the collector, as `heightpipe calibrate` does (boxes from the points).
    collector = HeadFootCollector(1280, 720)
    for f, t, i in zip(foot, top, ids):
        box = (f[0] - 0.2 * (f[1] - t[1]), t[1], 0.4 * (f[1] - t[1]), f[1] - t[1])
        collector.add([Track(track_id=int(i), box=box, cls="person", height_m=1.7, height_std_m=0.1, confirmed=True)])
    result = self_calibrate(*collector.arrays(), 1280, 720, K, settings=FAST)
    config_path = tmp_path / "camera.toml"
    config_path.write_text(result.config_snippet())
    config = load_config(config_path)
    assert config.camera.self_calibrated and config.camera.height_std_m > 0
    run_camera = camera_for_run(config.camera, 1280, 720)
    assert run_camera.source == "self" and is_calibrated(run_camera)
    assert run_camera.height_m == pytest.approx(result.height_m, abs=0.005)

    # New people measured through the self-calibrated camera: the prior's scale, honest noise.
    new_foot, new_top, _ = walking_people(camera, n_people=10, n_frames=1, seed=8,
                                          statures=np.full(10, 1.80))
    detections = [Detection(box=(0, 0, 1, 1), cls="person", foot_xy=tuple(f), top_xy=tuple(t))
                  for f, t in zip(new_foot, new_top)]
    packet = FramePacket(frame=Frame(0, 0.0, np.zeros((720, 1280, 3), np.uint8)), camera=run_camera,
                         detections=detections)
    GeometryMeasurer(config.camera).process(packet)
    assert config.camera.pitch_std_deg > 0 and config.camera.roll_std_deg > 0
    for d in detections:
        geometry = d.heights[GEOMETRY]
        assert abs(geometry.value_m - 1.80) < 2.5 * geometry.noise_m
        assert geometry.noise_m > 1.80 * result.height_std_m / result.height_m   # the scale's share
        assert d.camera_share > result.height_std_m / result.height_m   # ... and the pose's, for the std


def test_calibrate_command_reports_too_few_people(box_video, capsys):
    from pipeline.cli import main

    code = main(["calibrate", str(box_video), "--no-progress"])
    assert code == 2
    assert "heightpipe: error: self-calibration needs at least 5 people" in capsys.readouterr().err


def test_calibrate_command_rejects_a_bad_prior(box_video, capsys):
    from pipeline.cli import main

    assert main(["calibrate", str(box_video), "--prior-mean", "170", "--no-progress"]) == 2
    assert "--prior-mean" in capsys.readouterr().err


def test_camera_config_pitch_alone_is_not_a_pose():
    assert not is_calibrated(camera_for_run(CameraConfig(pitch_deg=20.0), 640, 480))
