"""Camera model: calibration files, the run's camera, projection and single-view metrology.

Checked against real data: the Oxford Town Centre calibration and its annotated head/foot
points (gt_with_geometry.csv), and KITTI frames with true 3D boxes.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest

from core.config import CameraConfig
from core.errors import ConfigError
from core.packets import CameraInfo
from stages.calibration import (CONSTANTS, angles_from_rotation, camera_centre, camera_for_run,
                                camera_from_pose, heights_from_foot_top, horizon_line, intrinsics_from_fov,
                                is_calibrated, load_calibration, pixel_to_ground, project_points,
                                rotation_from_angles, undistort_pixels, vertical_vanishing_point)

SHARED_REAL = Path(__file__).resolve().parents[2].parent / "shared" / "real"
OXFORD = SHARED_REAL / "oxford_towncentre"
OXFORD_CALIBRATION = OXFORD / "calib_opencv.json"
KITTI = SHARED_REAL / "kitti_objects"

needs_oxford = pytest.mark.skipif(not OXFORD_CALIBRATION.is_file(), reason="shared/real/oxford_towncentre missing")
needs_kitti = pytest.mark.skipif(not KITTI.is_dir(), reason="shared/real/kitti_objects missing")


def oxford_rows() -> list[dict]:
    with open(OXFORD / "gt_with_geometry.csv") as f:
        return list(csv.DictReader(f))


def oxford_points(rows) -> tuple[np.ndarray, np.ndarray]:
    foot = np.array([[float(r["foot_u"]), float(r["foot_v"])] for r in rows])
    top = np.array([[float(r["headtop_u"]), float(r["headtop_v"])] for r in rows])
    return foot, top


def write_json(path: Path, data: dict) -> Path:
    path.write_text(json.dumps(data))
    return path


# --------------------------------------------------------------------------- Oxford (real)

@needs_oxford
def test_oxford_calibration_loads_with_its_pose():
    camera = load_calibration(OXFORD_CALIBRATION)
    assert (camera.width, camera.height) == (1920, 1080)
    assert camera.source == "calibration"
    assert camera.height_m == pytest.approx(7.8442, abs=1e-3)
    assert camera_centre(camera) == pytest.approx([-9.0399, -4.9987, 7.8442], abs=1e-3)
    pitch, roll, _ = angles_from_rotation(camera.R)
    assert pitch == pytest.approx(20.037, abs=1e-3)          # the file's depression angle
    assert roll == pytest.approx(1.436, abs=1e-3)            # horizon rises to the right
    assert camera.dist == pytest.approx([-0.6015, 4.7020, -0.00047, -0.0078], abs=1e-4)


@needs_oxford
def test_oxford_horizon_matches_the_file():
    camera = load_calibration(OXFORD_CALIBRATION)
    expected = np.array(json.loads(OXFORD_CALIBRATION.read_text())["horizon_line_abc_pinhole_normalised"])
    line = horizon_line(camera)
    line = line * np.sign(line[1]) * np.sign(expected[1])
    assert line == pytest.approx(expected, rel=1e-6, abs=1e-6)


@needs_oxford
def test_oxford_head_foot_points_reproduce_the_annotated_heights():
    """The csv's height column is the calibration's metrology of its head/foot points."""
    camera = load_calibration(OXFORD_CALIBRATION)
    rows = oxford_rows()
    foot, top = oxford_points(rows)
    heights, ground = heights_from_foot_top(camera, undistort_pixels(camera, foot), undistort_pixels(camera, top))
    expected = np.array([float(r["height_headtop_m"]) for r in rows])
    expected_ground = np.array([[float(r["ground_x_m"]), float(r["ground_y_m"])] for r in rows])
    assert np.abs(heights - expected).max() < 1e-3            # the csv rounds to 1 mm
    assert np.abs(ground - expected_ground).max() < 1e-3
    assert np.median(heights) == pytest.approx(1.80, abs=0.01)


@needs_oxford
def test_oxford_heights_bend_without_undistortion():
    """k1 = -0.60, k2 = 4.70: skipping undistortion costs centimetres, up to decimetres."""
    camera = load_calibration(OXFORD_CALIBRATION)
    foot, top = oxford_points(oxford_rows())
    right, _ = heights_from_foot_top(camera, undistort_pixels(camera, foot), undistort_pixels(camera, top))
    wrong, _ = heights_from_foot_top(camera, foot, top)
    error = np.abs(wrong - right)
    assert error.mean() > 0.02 and error.max() > 0.10


# --------------------------------------------------------------------------- KITTI (real, true 3D)

def read_kitti(index: int):
    values = {}
    for line in (KITTI / f"calib_{index:06d}.txt").read_text().splitlines():
        if ":" in line:
            key, rest = line.split(":", 1)
            values[key] = np.array(rest.split(), float)
    P2 = values["P2"].reshape(3, 4)
    objects = []
    for line in (KITTI / f"label_{index:06d}.txt").read_text().splitlines():
        f = line.split()
        if f[0] != "DontCare":
            objects.append({"cls": f[0], "box": np.array(f[4:8], float), "hwl": np.array(f[8:11], float),
                            "location": np.array(f[11:14], float), "ry": float(f[14])})
    return P2, objects


def kitti_camera(P2: np.ndarray, ground_y: float) -> CameraInfo:
    """World: x = camera x, y = camera forward, z up, ground plane y_cam = ground_y (below the camera)."""
    K = P2[:, :3]
    offset = np.linalg.solve(K, P2[:, 3])              # camera 2's offset from the rectified frame
    R = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    t = -R @ np.array([0.0, 0.0, ground_y]) + offset
    return CameraInfo(width=1242, height=375, K=K, R=R, t=t, height_m=ground_y, source="calibration")


def kitti_objects():
    for index in range(3):
        P2, objects = read_kitti(index)
        for obj in objects:
            yield P2, obj


def box_corners_world(obj) -> np.ndarray:
    """The 3D box's 8 corners in the kitti_camera world of the object's own ground."""
    h, w, length = obj["hwl"]
    x0, y0, z0 = obj["location"]
    c, s = math.cos(obj["ry"]), math.sin(obj["ry"])
    xs = np.array([1, 1, -1, -1, 1, 1, -1, -1]) * length / 2
    zs = np.array([1, -1, -1, 1, 1, -1, -1, 1]) * w / 2
    ys = np.array([0, 0, 0, 0, -1, -1, -1, -1]) * h
    cam = np.stack([c * xs + s * zs + x0, ys + y0, -s * xs + c * zs + z0], axis=1)
    return np.stack([cam[:, 0], cam[:, 2], y0 - cam[:, 1]], axis=1)


@needs_kitti
def test_kitti_3d_boxes_project_onto_the_labelled_2d_boxes():
    for P2, obj in kitti_objects():
        camera = kitti_camera(P2, obj["location"][1])
        uv = project_points(camera, box_corners_world(obj))
        projected = np.array([uv[:, 0].min(), uv[:, 1].min(), uv[:, 0].max(), uv[:, 1].max()])
        # A walking pedestrian's 3D box (stride length) is wider than the person drawn in 2D.
        tolerance = 10.0 if obj["cls"] == "Pedestrian" else 3.0
        assert np.abs(projected - obj["box"]).max() < tolerance, obj["cls"]


@needs_kitti
def test_kitti_heights_from_2d_boxes_on_the_local_ground():
    """Foot = bottom centre of the 2D box, top = top centre, ground through the object's base."""
    errors = {}
    for P2, obj in kitti_objects():
        camera = kitti_camera(P2, obj["location"][1])
        x0, y0, x1, y1 = obj["box"]
        heights, ground = heights_from_foot_top(camera, np.array([[(x0 + x1) / 2, y1]]),
                                                np.array([[(x0 + x1) / 2, y0]]))
        true_height = obj["hwl"][0]
        errors[obj["cls"]] = heights[0] / true_height - 1.0
        # The foot is the box's near edge: the ground point is short of the 3D centre, not beyond it.
        depth_error = ground[0, 1] - obj["location"][2]
        assert -obj["hwl"][2] <= depth_error <= 0.2, obj["cls"]
    assert set(errors) == {"Pedestrian", "Truck", "Car", "Cyclist", "Misc"}
    assert all(abs(e) < 0.07 for e in errors.values()), errors
    assert abs(errors["Pedestrian"]) < 0.02 and abs(errors["Cyclist"]) < 0.02


@needs_kitti
def test_kitti_one_flat_ground_plane_fails_far_away():
    """The road is not flat: one plane at the near ground misjudges the car 58 m away."""
    P2, objects = read_kitti(1)
    near_ground = 1.65                                     # KITTI's nominal camera height
    car = next(o for o in objects if o["cls"] == "Car")
    x0, y0, x1, y1 = car["box"]
    foot, top = np.array([[(x0 + x1) / 2, y1]]), np.array([[(x0 + x1) / 2, y0]])
    flat, _ = heights_from_foot_top(kitti_camera(P2, near_ground), foot, top)
    local, _ = heights_from_foot_top(kitti_camera(P2, car["location"][1]), foot, top)
    assert abs(local[0] / car["hwl"][0] - 1) < 0.05
    assert abs(flat[0] / car["hwl"][0] - 1) > 0.2


# --------------------------------------------------------------------------- synthetic cameras

@pytest.mark.parametrize("pitch,roll,yaw", [(20.0, 0.0, 0.0), (35.0, 3.0, 40.0), (8.0, -2.5, -120.0)])
def test_angles_round_trip(pitch, roll, yaw):
    R = rotation_from_angles(pitch, roll, yaw)
    assert R @ R.T == pytest.approx(np.eye(3), abs=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    assert angles_from_rotation(R) == pytest.approx((pitch, roll, yaw), abs=1e-9)


def test_roll_sign_and_pitch_match_the_synth_generator():
    synth_camera = pytest.importorskip("synth.camera")
    made = synth_camera.make_camera(np.array([0.0, 0.0, 6.0]), 90.0, 25.0, 3.0, 60.0, 640, 480)
    ours = camera_from_pose(640, 480, made.K, 6.0, 25.0, 3.0)
    assert ours.R == pytest.approx(made.R, abs=1e-12)
    assert ours.t == pytest.approx(made.t, abs=1e-12)
    # Positive roll: the horizon's right end is higher (smaller v).
    a, b, c = horizon_line(ours)
    assert -(a * 639 + c) / b < -c / b


def test_horizon_vanishing_point_and_ground_projection_agree():
    camera = camera_from_pose(1280, 720, intrinsics_from_fov(1280, 720, 60.0), 5.0, 25.0, 2.0, yaw_deg=30.0)
    rng = np.random.default_rng(0)
    ground = np.column_stack([rng.uniform(-10, 10, 50), rng.uniform(3, 40, 50)])
    points = np.column_stack([ground, np.zeros(50)])
    uv = project_points(camera, points)
    assert pixel_to_ground(camera, uv) == pytest.approx(ground, abs=1e-9)
    # Far-away horizontal points approach the horizon; verticals meet at the vanishing point.
    forward, right = camera.R[2, :2] / np.linalg.norm(camera.R[2, :2]), camera.R[0, :2]
    far = project_points(camera, [[*(3e7 * forward + 5e6 * right), 0.0], [*(3e7 * forward - 8e6 * right), 0.0]])
    line = horizon_line(camera)
    assert np.abs(far @ line[:2] + line[2]).max() < 0.05
    assert np.isnan(pixel_to_ground(camera, far - [0.0, 5.0])).all()       # above the horizon
    vp = vertical_vanishing_point(camera)
    heights = np.array([0.0, 1.0, 2.5])
    column = project_points(camera, [[2.0, 10.0, h] for h in heights])
    direction = column[1:] - column[0]
    to_vp = vp[:2] / vp[2] - column[0]
    cross = direction[:, 0] * to_vp[1] - direction[:, 1] * to_vp[0]
    assert np.abs(cross / np.linalg.norm(direction, axis=1) / np.linalg.norm(to_vp)).max() < 1e-9


@pytest.mark.parametrize("pitch,roll", [(10.0, 0.0), (30.0, 2.0), (60.0, -3.0)])
def test_metrology_is_exact_for_tilted_cameras(pitch, roll):
    camera = camera_from_pose(1920, 1080, intrinsics_from_fov(1920, 1080, 50.0), 7.0, pitch, roll, yaw_deg=15.0)
    rng = np.random.default_rng(1)
    centre = camera_centre(camera)
    forward = camera.R[2, :2] / np.linalg.norm(camera.R[2, :2])
    distance = rng.uniform(4, 25, 40)
    ground = centre[:2] + distance[:, None] * forward + rng.uniform(-3, 3, (40, 1)) * forward[::-1] * [1, -1]
    heights = rng.uniform(0.5, 4.0, 40)
    foot = project_points(camera, np.column_stack([ground, np.zeros(40)]))
    top = project_points(camera, np.column_stack([ground, heights]))
    measured, measured_ground = heights_from_foot_top(camera, foot, top)
    assert measured == pytest.approx(heights, abs=1e-9)
    assert measured_ground == pytest.approx(ground, abs=1e-9)


# --------------------------------------------------------------------------- calibration files

def test_our_layout_with_height_and_pitch(tmp_path):
    path = write_json(tmp_path / "cam.json", {
        "image_size": [640, 480], "K": [[500, 0, 319.5], [0, 500, 239.5], [0, 0, 1]],
        "dist": [-0.1, 0.01, 0, 0, 0], "camera_height_m": 4.5, "pitch_deg": 30.0, "roll_deg": 1.0})
    camera = load_calibration(path)
    assert camera.height_m == pytest.approx(4.5)
    assert angles_from_rotation(camera.R)[:2] == pytest.approx((30.0, 1.0))
    assert len(camera.dist) == 5


def test_rvec_tvec_and_filestorage_matrices(tmp_path):
    import cv2

    R = rotation_from_angles(22.0, -1.0, 10.0)
    t = -R @ np.array([1.0, 2.0, 6.0])
    rvec = cv2.Rodrigues(R)[0].ravel()
    path = write_json(tmp_path / "cam.json", {
        "image_width": 800, "image_height": 600,
        "camera_matrix": {"type_id": "opencv-matrix", "rows": 3, "cols": 3, "dt": "d",
                          "data": [600, 0, 399.5, 0, 600, 299.5, 0, 0, 1]},
        "distortion_coefficients": {"rows": 1, "cols": 4, "data": [0, 0, 0, 0]},
        "rvec": rvec.tolist(), "tvec": t.tolist()})
    camera = load_calibration(path)
    assert (camera.width, camera.height) == (800, 600)
    assert camera.R == pytest.approx(R, abs=1e-9)
    assert camera.height_m == pytest.approx(6.0)
    assert camera.dist is None                           # all-zero distortion is no distortion


def test_intrinsic_only_file_takes_the_pose_from_config(tmp_path):
    path = write_json(tmp_path / "cam.json", {"image_size": [640, 480], "K": [[500, 0, 320], [0, 500, 240], [0, 0, 1]]})
    assert load_calibration(path).R is None
    camera = camera_for_run(CameraConfig(calibration=str(path), height_m=5.0, pitch_deg=25.0), 640, 480)
    assert is_calibrated(camera) and camera.source == "calibration"
    assert camera.K[0, 0] == 500 and camera.height_m == 5.0
    only_height = camera_for_run(CameraConfig(calibration=str(path), height_m=5.0), 640, 480)
    assert only_height.source == "camera-height" and not is_calibrated(only_height)


@pytest.mark.parametrize("data,message", [
    ({"K": [[500, 0, 320], [0, 500, 240], [0, 0, 1]]}, "image_size"),
    ({"image_size": [640, 480]}, "intrinsics"),
    ({"image_size": [640, 480], "K": [[500, 0, 320], [0, 500, 240]]}, "9 finite numbers"),
    ({"image_size": [640, 480], "K": [[500, 0, 320], [0, 500, 240], [0, 0, 1]], "dist": [0.1, 0.2, 0.3]},
     "distortion"),
    ({"image_size": [640, 480], "K": [[500, 0, 320], [0, 500, 240], [0, 0, 1]],
      "R_world_to_cam": [[1, 0, 0], [0, 1, 0], [0, 0, 2]], "t_world_to_cam_m": [0, 0, 1]}, "rotation"),
    ({"image_size": [640, 480], "K": [[500, 0, 320], [0, 500, 240], [0, 0, 1]],
      "R_world_to_cam": [[1, 0, 0], [0, 0, -1], [0, 1, 0]], "t_world_to_cam_m": [0, -3, 0]}, "above the ground"),
])
def test_bad_calibration_files_raise_config_errors(tmp_path, data, message):
    path = write_json(tmp_path / "bad.json", data)
    with pytest.raises(ConfigError, match=message):
        load_calibration(path)


def test_missing_or_unreadable_file(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_calibration(tmp_path / "nope.json")
    (tmp_path / "broken.json").write_text("{K: ")
    with pytest.raises(ConfigError, match="JSON"):
        load_calibration(tmp_path / "broken.json")


@needs_oxford
def test_translation_mistaken_for_the_camera_centre_is_caught(tmp_path):
    """OpenTraj's loader reads t as the camera centre (camera 12.39 m up, people 2.84 m tall)."""
    data = json.loads(OXFORD_CALIBRATION.read_text())
    data.pop("rvec")
    R = np.array(data["R_world_to_cam"])
    data["t_world_to_cam_m"] = (-R @ np.array(data["t_world_to_cam_m"])).tolist()
    with pytest.raises(ConfigError, match="camera_height_m"):
        load_calibration(write_json(tmp_path / "wrong.json", data))


# --------------------------------------------------------------------------- camera_for_run

def test_camera_for_run_sources():
    nothing = camera_for_run(CameraConfig(), 640, 360)
    assert nothing.source == "none" and not is_calibrated(nothing)
    assert nothing.height_m == CONSTANTS.assumed_camera_height_m
    assert nothing.K[0, 0] == pytest.approx(320 / math.tan(math.radians(30)))
    height_only = camera_for_run(CameraConfig(height_m=7.84), 640, 360)
    assert height_only.source == "camera-height" and height_only.height_m == 7.84 and not is_calibrated(height_only)
    posed = camera_for_run(CameraConfig(height_m=6.0, pitch_deg=20.0, roll_deg=1.0), 640, 360)
    assert posed.source == "calibration" and is_calibrated(posed)
    assert camera_centre(posed)[2] == pytest.approx(6.0)
    self_calibrated = camera_for_run(CameraConfig(height_m=6.0, pitch_deg=20.0, self_calibrated=True), 640, 360)
    assert self_calibrated.source == "self" and is_calibrated(self_calibrated)
    with pytest.raises(ConfigError, match="pitch_deg"):
        camera_for_run(CameraConfig(height_m=6.0, pitch_deg=95.0), 640, 360)
    with pytest.raises(ConfigError, match="fov_deg"):
        camera_for_run(CameraConfig(fov_deg=0.0), 640, 360)


@needs_oxford
def test_camera_for_run_scales_a_calibration_to_a_resized_video():
    full = camera_for_run(CameraConfig(calibration=str(OXFORD_CALIBRATION)), 1920, 1080)
    half = camera_for_run(CameraConfig(calibration=str(OXFORD_CALIBRATION)), 960, 540)
    assert half.K[0, 0] == pytest.approx(full.K[0, 0] / 2)
    assert half.K[:2, 2] == pytest.approx([479.5, 269.5])
    foot, top = oxford_points(oxford_rows()[:50])
    h_full, _ = heights_from_foot_top(full, undistort_pixels(full, foot), undistort_pixels(full, top))
    scaled = lambda p: (p + 0.5) / 2 - 0.5                                        # noqa: E731
    h_half, _ = heights_from_foot_top(half, undistort_pixels(half, scaled(foot)), undistort_pixels(half, scaled(top)))
    assert h_half == pytest.approx(h_full, abs=1e-6)
    with pytest.raises(ConfigError, match="aspect"):
        camera_for_run(CameraConfig(calibration=str(OXFORD_CALIBRATION)), 640, 480)


@needs_oxford
def test_camera_height_flag_must_agree_with_a_calibration():
    ok = camera_for_run(CameraConfig(calibration=str(OXFORD_CALIBRATION), height_m=7.84), 1920, 1080)
    assert ok.height_m == pytest.approx(7.844, abs=1e-3)
    with pytest.raises(ConfigError, match="contradicts"):
        camera_for_run(CameraConfig(calibration=str(OXFORD_CALIBRATION), height_m=5.0), 1920, 1080)


@needs_oxford
def test_a_pose_in_the_config_takes_only_the_intrinsics_from_a_calibration_file():
    """What `heightpipe calibrate --calibration FILE` prints: its own height and pitch, the file's lens."""
    from_file = camera_for_run(CameraConfig(calibration=str(OXFORD_CALIBRATION)), 1920, 1080)
    snippet = CameraConfig(calibration=str(OXFORD_CALIBRATION), height_m=4.8, pitch_deg=13.8,
                           roll_deg=2.0, self_calibrated=True)
    camera = camera_for_run(snippet, 1920, 1080)
    assert camera.source == "self"
    assert camera.height_m == pytest.approx(4.8)
    assert camera.K == pytest.approx(from_file.K)
    assert camera.dist == pytest.approx(from_file.dist)
