"""GeometryMeasurer and Undistorter: metric heights from foot and top points, honest noise."""

from __future__ import annotations

import csv
import dataclasses
import os
from pathlib import Path

import numpy as np
import pytest

from core.config import CameraConfig
from core.errors import SourceError
from core.packets import GEOMETRY, NETWORK, CameraInfo, Detection, Frame, FramePacket, Measurement
from stages.calibration import (camera_for_run, camera_from_pose, heights_from_foot_top, intrinsics_from_fov,
                                load_calibration, project_points, undistort_pixels)
from stages.geometry import CONSTANTS, GeometryMeasurer
from stages.undistortion import Undistorter

SHARED_REAL = Path(__file__).resolve().parents[2].parent / "shared" / "real"
OXFORD = SHARED_REAL / "oxford_towncentre"
OXFORD_CALIBRATION = OXFORD / "calib_opencv.json"
needs_oxford = pytest.mark.skipif(not OXFORD_CALIBRATION.is_file(), reason="shared/real/oxford_towncentre missing")


def packet_with(camera: CameraInfo, detections: list[Detection], image: np.ndarray | None = None) -> FramePacket:
    if image is None:
        image = np.zeros((camera.height, camera.width, 3), np.uint8)
    return FramePacket(frame=Frame(index=0, time_s=0.0, image=image), camera=camera, detections=detections)


def detection(foot, top, cls="person") -> Detection:
    return Detection(box=(min(foot[0], top[0]) - 5, top[1], 10, foot[1] - top[1]),
                     heights={NETWORK: Measurement(1.0, 0.15, "test")}, cls=cls,
                     foot_xy=(float(foot[0]), float(foot[1])), top_xy=(float(top[0]), float(top[1])))


def oxford_detections() -> tuple[list[Detection], list[dict]]:
    with open(OXFORD / "gt_with_geometry.csv") as f:
        rows = list(csv.DictReader(f))
    detections = [detection((float(r["foot_u"]), float(r["foot_v"])), (float(r["headtop_u"]), float(r["headtop_v"])))
                  for r in rows]
    for d, r in zip(detections, rows):
        d.foot_cut = r["foot_inside_image"] != "1"   # what the extractor flags: the foot is not in the image
    return detections, rows


# --------------------------------------------------------------------------- Oxford (real)

@needs_oxford
def test_oxford_annotations_give_the_annotated_heights_and_ground_points():
    camera = load_calibration(OXFORD_CALIBRATION)           # raw frames: points undistorted in the stage
    detections, rows = oxford_detections()
    GeometryMeasurer(CameraConfig()).process(packet_with(camera, detections))
    measured = [(d, r) for d, r in zip(detections, rows) if GEOMETRY in d.heights]
    # Rows whose foot is cut by the frame's edge have no measurement.
    assert all(r["foot_inside_image"] == "1" for _, r in measured)
    assert len(measured) >= 0.95 * sum(r["foot_inside_image"] == "1" for r in rows)
    errors = np.array([d.heights[GEOMETRY].value_m - float(r["height_headtop_m"]) for d, r in measured])
    assert np.abs(errors).max() < 1e-3
    ground = np.array([d.ground_xy_m for d, _ in measured])
    expected = np.array([[float(r["ground_x_m"]), float(r["ground_y_m"])] for _, r in measured])
    assert np.abs(ground - expected).max() < 1e-3
    noise = np.array([d.heights[GEOMETRY].noise_m for d, _ in measured])
    assert np.all((noise > 0.01) & (noise < 0.2))


@needs_oxford
def test_undistorted_frames_and_undistorted_points_agree():
    """Undistorter first (frames remapped, camera without dist) or points undistorted in geometry."""
    raw_camera = camera_for_run(CameraConfig(calibration=str(OXFORD_CALIBRATION)), 1920, 1080)
    undistorter = Undistorter(raw_camera)
    assert undistorter.camera.dist is None and np.array_equal(undistorter.camera.K, raw_camera.K)
    raw, _ = oxford_detections()
    raw = raw[:100]
    undistorted = [dataclasses.replace(d) for d in raw]
    foot = undistort_pixels(raw_camera, [d.foot_xy for d in raw])
    top = undistort_pixels(raw_camera, [d.top_xy for d in raw])
    for d, f, t in zip(undistorted, foot, top):
        d.foot_xy, d.top_xy = tuple(f), tuple(t)
    measurer = GeometryMeasurer(CameraConfig())
    measurer.process(packet_with(raw_camera, raw))
    measurer.process(packet_with(undistorter.camera, undistorted))
    a = np.array([d.height(GEOMETRY) for d in raw])
    b = np.array([d.height(GEOMETRY) for d in undistorted])
    # The border test is made on each frame's own pixels, so a foot on the bottom edge may differ.
    both = ~np.isnan(a) & ~np.isnan(b)
    assert both.sum() >= 0.9 * (~np.isnan(a)).sum() and np.abs(a[both] - b[both]).max() < 1e-6


@needs_oxford
def test_undistorter_moves_distorted_dots_to_their_pinhole_positions():
    import cv2

    camera = camera_for_run(CameraConfig(calibration=str(OXFORD_CALIBRATION)), 1920, 1080)
    # Dots on the ground, drawn where the real (distorting) lens puts them.
    xs, ys = np.meshgrid(np.arange(-2.0, 14.0, 3.0), np.arange(2.0, 16.0, 3.0))
    world = np.column_stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)])
    pinhole = project_points(camera, world)
    rvec = cv2.Rodrigues(camera.R)[0]
    distorted = cv2.projectPoints(world, rvec, camera.t, camera.K, camera.dist)[0].reshape(-1, 2)
    inside = np.all((distorted > 20) & (distorted < [1900, 1060]), axis=1) & \
        np.all((pinhole > 20) & (pinhole < [1900, 1060]), axis=1)
    assert inside.sum() >= 10
    image = np.zeros((1080, 1920, 3), np.uint8)
    for u, v in distorted[inside]:
        cv2.circle(image, (int(round(u * 16)), int(round(v * 16))), 6 * 16, (255, 255, 255), -1, cv2.LINE_AA, 4)
    undistorter = Undistorter(camera)
    packet = undistorter.process(packet_with(camera, [], image))
    assert packet.camera is undistorter.camera and packet.camera.dist is None
    gray = packet.frame.image[:, :, 0].astype(float)
    for u, v in pinhole[inside]:
        x0, y0 = int(u) - 15, int(v) - 15
        patch = gray[y0:y0 + 31, x0:x0 + 31]
        py, px = np.mgrid[0:31, 0:31]
        centroid = np.array([(patch * px).sum(), (patch * py).sum()]) / patch.sum() + [x0, y0]
        assert np.hypot(*(centroid - [u, v])) < 0.5
    with pytest.raises(SourceError, match="1920x1080"):
        undistorter.process(packet_with(dataclasses.replace(camera, width=640, height=480), []))


# --------------------------------------------------------------------------- synthetic cameras

def test_uncalibrated_camera_gets_no_geometry():
    for camera in (camera_for_run(CameraConfig(), 640, 480), camera_for_run(CameraConfig(height_m=5.0), 640, 480)):
        d = detection((320, 400), (320, 300))
        GeometryMeasurer(CameraConfig()).process(packet_with(camera, [d]))
        assert GEOMETRY not in d.heights and d.ground_xy_m is None


def test_points_cut_by_the_border_are_not_measured():
    camera = camera_from_pose(640, 480, intrinsics_from_fov(640, 480, 60), 5.0, 30.0)
    foot_cut = dataclasses.replace(detection((320, 479.5), (320, 380)), foot_cut=True)
    top_cut = dataclasses.replace(detection((320, 300), (320, 0.5)), top_cut=True)
    whole = detection((320, 300), (320, 200))
    GeometryMeasurer(CameraConfig()).process(packet_with(camera, [foot_cut, top_cut, whole]))
    assert foot_cut.ground_xy_m is None and GEOMETRY not in foot_cut.heights
    assert top_cut.ground_xy_m is not None and GEOMETRY not in top_cut.heights
    assert GEOMETRY in whole.heights


def _person_at(camera, x, y, height_m):
    foot, top = project_points(camera, [[x, y, 0.0], [x, y, height_m]])
    return detection(foot, top)


def test_a_person_whose_feet_are_below_the_frame_gets_a_lower_bound():
    """Feet below the frame's bottom edge: the blob's lowest point is farther away than the feet,
    so the height through it is too low, never too high; whole people get no bound."""
    camera = camera_from_pose(640, 480, intrinsics_from_fov(640, 480, 60), 5.0, 30.0)
    bounds = []
    for x, y in [(0.0, 2.5), (0.0, 3.0), (0.0, 3.5)]:   # less and less of the person cut off
        cut = _person_at(camera, x, y, 1.80)
        assert cut.foot_xy[1] > 480                      # the feet are out of the frame
        cut.foot_xy = (cut.foot_xy[0], 479.5)            # the blob ends at the frame's edge
        cut.foot_cut = True
        whole = _person_at(camera, x, y + 4.0, 1.80)
        GeometryMeasurer(CameraConfig()).process(packet_with(camera, [cut, whole]))
        assert GEOMETRY not in cut.heights
        assert 0.0 < cut.min_height_m < 1.80
        assert whole.min_height_m is None and whole.heights[GEOMETRY].value_m == pytest.approx(1.80, abs=0.01)
        bounds.append(cut.min_height_m)
    assert bounds == sorted(bounds) and bounds[-1] > 1.5     # the bound tightens as less is cut


def test_pixel_noise_is_propagated_honestly():
    """The stage's pixel-noise std agrees with a Monte Carlo of +-point_noise_px on both points."""
    camera = camera_from_pose(1280, 720, intrinsics_from_fov(1280, 720, 60), 6.0, 25.0, 1.0)
    people = [_person_at(camera, x, y, 1.75) for x, y in [(-3, 8), (0, 15), (4, 22), (1, 30)]]
    measurer = GeometryMeasurer(CameraConfig(point_noise_px=2.0))
    foot = np.array([d.foot_xy for d in people])
    top = np.array([d.top_xy for d in people])
    stated = measurer._pixel_noise(camera, foot, top)
    rng = np.random.default_rng(0)
    samples = [heights_from_foot_top(camera, foot + rng.normal(0, 2, foot.shape), top + rng.normal(0, 2, top.shape))[0]
               for _ in range(3000)]
    assert stated == pytest.approx(np.std(samples, axis=0), rel=0.1)
    assert np.all(np.diff(stated) > 0)                        # farther people: fewer pixels, more noise
    measurer.process(packet_with(camera, people))
    assert [d.heights[GEOMETRY].value_m for d in people] == pytest.approx([1.75] * 4, abs=1e-9)
    assert all(d.heights[GEOMETRY].noise_m >= s for d, s in zip(people, stated))


def test_self_calibrated_camera_height_uncertainty_widens_the_noise_and_is_a_share_of_the_height():
    config = CameraConfig(height_m=6.0, pitch_deg=25.0, self_calibrated=True)
    camera = camera_for_run(config, 1280, 720)
    exact = _person_at(camera, 0, 12, 1.75)
    uncertain = dataclasses.replace(exact)
    GeometryMeasurer(config).process(packet_with(camera, [exact]))
    GeometryMeasurer(dataclasses.replace(config, height_std_m=0.6)).process(packet_with(camera, [uncertain]))
    wide, narrow = uncertain.heights[GEOMETRY], exact.heights[GEOMETRY]
    assert wide.value_m == narrow.value_m
    # 10 % of the camera height is 10 % of the object's height, added in quadrature ...
    assert wide.noise_m == pytest.approx(np.hypot(narrow.noise_m, 0.175), rel=1e-6)
    # ... but it is no bias of this object: every object and the network's scale share it.
    assert wide.bias_m == narrow.bias_m <= narrow.noise_m
    # It is the same on every frame and every channel: the tracker adds it to the std it reports
    # (frames must not average it away).
    assert (exact.camera_share, uncertain.camera_share) == (0.0, pytest.approx(0.1))


@pytest.mark.parametrize("stds, moved", [
    (dict(pitch_std_deg=1.0), dict(pitch_deg=26.0)),
    (dict(roll_std_deg=1.0), dict(roll_deg=1.0)),
    (dict(focal_std_pct=5.0), dict(fov_deg=None)),
])
def test_a_self_calibrated_pose_s_stated_spread_is_the_height_error_it_makes(stds, moved):
    """Each of pitch, roll and focal length moved by its std changes a person's geometry height by
    what ``camera_share`` says; a calibration file's pose is exact and makes none."""
    config = CameraConfig(height_m=6.0, pitch_deg=25.0, self_calibrated=True, **stds)
    camera = camera_for_run(config, 1280, 720)
    person = _person_at(camera, 2, 12, 1.75)
    GeometryMeasurer(config).process(packet_with(camera, [person]))
    if moved.get("fov_deg", 0) is None:   # 5 % longer focal length, the same pose
        K = camera.K.copy()
        K[:2, :2] *= 1.05
        other = dataclasses.replace(camera, K=K)
    else:
        other = camera_for_run(dataclasses.replace(config, **moved), 1280, 720)
    height, _ = heights_from_foot_top(other, np.array([person.foot_xy]), np.array([person.top_xy]))
    assert person.camera_share == pytest.approx(abs(height[0] / 1.75 - 1.0), rel=1e-6)
    assert person.camera_share > 0.001
    from_file = dataclasses.replace(camera, pose_from="")           # a calibration file's pose
    again = _person_at(camera, 2, 12, 1.75)
    GeometryMeasurer(config).process(packet_with(from_file, [again]))
    assert again.camera_share == 0.0


def test_long_objects_get_more_noise_than_people():
    camera = camera_from_pose(1280, 720, intrinsics_from_fov(1280, 720, 60), 6.0, 25.0)
    person = _person_at(camera, 0, 15, 1.5)
    car = _widened(person, 200)                     # the same foot and top, 2.7 m wide there
    GeometryMeasurer(CameraConfig()).process(packet_with(camera, [person, car]))
    assert (person.cls, car.cls) == ("person", "vehicle")
    assert car.heights[GEOMETRY].value_m == person.heights[GEOMETRY].value_m
    assert car.heights[GEOMETRY].noise_m > 3 * person.heights[GEOMETRY].noise_m
    # The shape term follows the class (which flickers): only the pixels are a per-object bias.
    assert car.heights[GEOMETRY].bias_m == pytest.approx(person.heights[GEOMETRY].bias_m)


def _widened(d: Detection, width_px: float) -> Detection:
    """The same foot and top points under a box ``width_px`` wide (a car's front or flank)."""
    x, y, w, h = d.box
    return dataclasses.replace(d, box=(x + w / 2 - width_px / 2, y, width_px, h), cls="other")


def test_objects_are_classed_by_their_height_and_width_in_metres():
    """The network's height misses by half on generator people: the calibrated camera measures
    both the height and the width at the foot."""
    camera = camera_from_pose(1280, 720, intrinsics_from_fov(1280, 720, 60), 6.0, 25.0)
    walker, child, bike, car, bin_ = (_person_at(camera, 0, 15, 1.75), _person_at(camera, 2, 15, 1.1),
                                      _person_at(camera, -2, 15, 1.8), _person_at(camera, 4, 15, 1.5),
                                      _person_at(camera, -4, 15, 0.6))
    bike, car = _widened(bike, 110), _widened(car, 180)        # ~1.5 m and ~2.4 m at 15 m
    for d in (walker, child, bin_):
        d.classify("vehicle", "objects")                       # whatever the network's height said
    GeometryMeasurer(CameraConfig()).process(packet_with(camera, [walker, child, bike, car, bin_]))
    assert [d.cls for d in (walker, child, bike, car, bin_)] == ["person", "person", "cyclist", "vehicle", "other"]
    assert {d.cls_source for d in (walker, child, bike, car, bin_)} == {"geometry"}   # who decided it


# --------------------------------------------------------------------------- generator frames

@pytest.fixture(scope="module")
def synth_sequence(tmp_path_factory):
    """Six rendered frames of a street with a known camera (MuJoCo, ~8 s)."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    sequence_module = pytest.importorskip("synth.sequence")
    writer = pytest.importorskip("synth.writer")
    dataset = pytest.importorskip("synth.dataset")
    options = sequence_module.SequenceOptions(frames=6, sizes=((640, 480),), shadows=False, post_effects=False,
                                              pedestrians=(10, 12), vehicles=(2, 3))
    plan = sequence_module.plan_sequence(3, 0, options)
    root = tmp_path_factory.mktemp("synth")
    try:
        writer.write_sequence(plan, root)
    except Exception as exc:  # no EGL/OSMesa on this machine
        pytest.skip(f"cannot render synth frames: {exc}")
    return dataset.SynthSequence(root / plan.name)


def _coarse(generator_class: str) -> str:
    return {"pedestrian": "person", "cyclist": "cyclist"}.get(generator_class, "vehicle")


def _mask_detections(sequence, index):
    """Detections the way the object extractor makes them: box edges, centre column."""
    frame = sequence.frame(index)
    camera = sequence.meta.camera
    pairs = []
    for truth in sequence.objects(index):
        mask = frame.instance == truth.id
        if truth.visible_fraction < 0.95 or mask.sum() < 30:
            continue
        ys, xs = np.nonzero(mask)
        x0, x1, y0, y1 = xs.min(), xs.max() + 1, ys.min(), ys.max() + 1
        if y0 <= 2 or y1 >= camera.height - 2 or x0 <= 2 or x1 >= camera.width - 2:
            continue
        cls = _coarse(truth.cls)
        pairs.append((Detection(box=(x0, y0, x1 - x0, y1 - y0), cls=cls,
                                foot_xy=((x0 + x1) / 2, float(y1)), top_xy=((x0 + x1) / 2, float(y0))), truth))
    return pairs


def test_generator_frames_heights_and_ground_positions(synth_sequence):
    c = synth_sequence.meta.camera
    camera = CameraInfo(width=c.width, height=c.height, K=c.K, R=c.R, t=c.t, height_m=c.height_m,
                        source="calibration")
    measurer = GeometryMeasurer(CameraConfig())
    people, others = [], []
    for index in range(len(synth_sequence)):
        pairs = _mask_detections(synth_sequence, index)
        measurer.process(packet_with(camera, [d for d, _ in pairs]))
        for d, truth in pairs:
            assert GEOMETRY in d.heights
            (people if truth.cls == "pedestrian" else others).append((d, truth))
    assert len(people) >= 10
    # The class in metres (geometry height, width at the foot): people are people, vehicles are
    # vehicles (a cyclist seen head-on is as narrow as a walker: either class may be right there).
    assert np.mean([d.cls == "person" for d, _ in people]) > 0.9
    vehicles = [d for d, t in others if _coarse(t.cls) == "vehicle"]
    assert vehicles and all(d.cls == "vehicle" for d in vehicles)
    errors = np.array([d.heights[GEOMETRY].value_m - t.height_m for d, t in people])
    noise = np.array([d.heights[GEOMETRY].noise_m for d, _ in people])
    assert np.abs(errors).max() < 0.15 and abs(np.mean(errors)) < 0.06
    assert np.mean(np.abs(errors) < 2 * noise) > 0.9              # the stated noise covers the error
    # The box's bottom is the nearer foot, not the body's centre: decimetres at 640x480.
    ground = np.array([np.hypot(*np.subtract(d.ground_xy_m, t.ground_xy_m)) for d, t in people])
    assert np.median(ground) < 0.4 and ground.max() < 0.8
    for d, truth in others:                                       # vehicles: biased high, but within noise
        assert abs(d.heights[GEOMETRY].value_m - truth.height_m) < 3 * d.heights[GEOMETRY].noise_m


def _person_read_low(camera: CameraInfo, x_m: float, y_m: float, height_m: float, share: float) -> Detection:
    """A person with exact foot and top points whose network height reads ``share`` of the truth."""
    d = _person_at(camera, x_m, y_m, height_m)
    d.add_height(NETWORK, Measurement(share * height_m, 0.15, "test"))
    return d


def test_network_heights_are_rescaled_by_their_ratio_to_geometry_on_people():
    camera = camera_from_pose(640, 480, intrinsics_from_fov(640, 480, 60), 6.0, 25.0)
    measurer = GeometryMeasurer(CameraConfig())
    rng = np.random.default_rng(0)
    for frame in range(CONSTANTS.scale_min_samples + 5):
        people = [_person_read_low(camera, rng.uniform(-3, 3), rng.uniform(10, 20), rng.uniform(1.6, 1.9), 0.7)]
        # A cut person: no geometry, only the network sees it; and a vehicle, which neither feeds
        # the scale nor gets it.
        cut = dataclasses.replace(_person_read_low(camera, 0.0, 15.0, 1.8, 0.7), foot_cut=True)
        car = _widened(_person_read_low(camera, 2.0, 12.0, 1.5, 0.3), 120)
        measurer.process(packet_with(camera, people + [cut, car]))
        if frame < CONSTANTS.scale_min_samples - 1:
            assert cut.height() == pytest.approx(0.7 * 1.8)           # too few ratios yet: untouched
            # ... but as unsure as an unknown scale makes it (half its height), not 0.15 m.
            prior = CONSTANTS.network_prior_scale_noise * 0.7 * 1.8
            assert cut.heights[NETWORK].noise_m == pytest.approx(np.hypot(0.15, prior))
    assert measurer.network_scale.scale == pytest.approx(1 / 0.7, rel=0.02)
    assert GEOMETRY not in cut.heights and cut.height() == pytest.approx(1.8, rel=0.02)
    # A scale learnt on thin people is not a vehicle's: its network height is left as it is.
    assert car.cls == "vehicle" and car.height() == pytest.approx(0.3 * 1.5)
    # The scale is known now (every person read 0.7x): back to the base noise, rescaled.
    assert cut.heights[NETWORK].noise_m == pytest.approx(0.15 / 0.7, rel=0.02)


def test_network_rescaling_can_be_switched_off():
    camera = camera_from_pose(640, 480, intrinsics_from_fov(640, 480, 60), 6.0, 25.0)
    measurer = GeometryMeasurer(CameraConfig(rescale_network=False))
    for _ in range(CONSTANTS.scale_min_samples + 5):
        person = _person_read_low(camera, 0.0, 15.0, 1.8, 0.7)
        measurer.process(packet_with(camera, [person]))
    assert person.height() == pytest.approx(0.7 * 1.8) and measurer.network_scale is None
