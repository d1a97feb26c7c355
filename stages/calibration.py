"""The camera model: loading calibrations, building the run's ``CameraInfo``, projecting.

Conventions (OpenCV's, so that any OpenCV calibration drops in):

* camera axes: x right, y down, z forward; pixel centres at integer coordinates;
* world: the ground plane is z = 0, z points up, metres;
* pose: ``x_cam = R @ x_world + t`` (R world-to-camera), so the camera centre is ``-R.T @ t``;
* distortion: OpenCV's coefficient order (k1, k2, p1, p2[, k3[, k4, k5, k6[, s1..s4[, tx, ty]]]]).

Every projection helper below works on *undistorted* pixels of ``camera.K``; points of a raw
(distorted) frame go through :func:`undistort_pixels` first.

Calibration JSON (``[camera] calibration = FILE`` or ``--calibration FILE``). Our layout::

    {
      "image_size": [1920, 1080],                 # width, height of the calibrated frames
      "K": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]],
      "dist": [k1, k2, p1, p2, k3],               # optional, OpenCV order (4-14 numbers)
      "R_world_to_cam": [[...], [...], [...]],    # pose, optional: R and t ...
      "t_world_to_cam_m": [tx, ty, tz],
      # ... or "rvec" (Rodrigues) + "tvec", or "camera_height_m" + "pitch_deg" [+ "roll_deg"]
    }

Also accepted: the Oxford Town Centre layout (``dist_opencv_k1_k2_p1_p2``; its redundant
``rvec``, ``camera_height_m`` are checked against R and t), the names OpenCV's calibration
sample writes (``camera_matrix``, ``distortion_coefficients``, ``image_width``/``image_height``)
and matrices stored as ``{"rows": 3, "cols": 3, "data": [...]}`` (cv2.FileStorage JSON).
A file without a pose is an intrinsic calibration; the pose then comes from ``[camera]``.

``pitch_deg`` is the depression of the optical axis below the horizon (positive = looking
down); ``roll_deg`` the rotation about the optical axis, positive when the horizon's right end
is higher in the image (as synth/camera.py); yaw does not matter for heights and is 0 here
(world +y is the horizontal viewing direction; synth's yaw 90).
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from core.config import CameraConfig
from core.errors import ConfigError
from core.packets import CameraInfo



@dataclasses.dataclass(frozen=True)
class CalibrationConstants:
    """The calibration maths' fixed numbers (the rule is in docs/design.md, Configuration)."""

    assumed_camera_height_m: float = 5.0
    """Camera height assumed when nothing is known, so that a scale-free network output still
    becomes metres: a typical CCTV mast (the generator's cameras stand at 3.5-9.2 m). Such a
    camera has source "none" and every height it gives is flagged."""


CONSTANTS = CalibrationConstants()

# A level camera looking along world +y: camera x = world x, camera y = -world z, camera z = world y.
_LEVEL_CAMERA = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])

_KEYS_K = ("K", "camera_matrix", "cameraMatrix")
_KEYS_DIST = ("dist", "dist_coeffs", "distortion_coefficients", "dist_opencv_k1_k2_p1_p2", "D", "distCoeffs")
_KEYS_R = ("R_world_to_cam", "R")
_KEYS_T = ("t_world_to_cam_m", "tvec", "t")


# --------------------------------------------------------------------------- building cameras

def intrinsics_from_fov(width: int, height: int, fov_deg: float) -> np.ndarray:
    """Square-pixel K with the principal point at the image centre and a horizontal FOV."""
    if not 1.0 <= fov_deg < 179.0:
        raise ConfigError(f"camera.fov_deg must be between 1 and 179 degrees, got {fov_deg}")
    focal = (width / 2.0) / math.tan(math.radians(fov_deg) / 2.0)
    return np.array([[focal, 0.0, (width - 1) / 2.0], [0.0, focal, (height - 1) / 2.0], [0.0, 0.0, 1.0]])


def fov_from_focal(width: int, focal_px: float) -> float:
    """Horizontal field of view (degrees) of a focal length in pixels of a ``width``-wide image:
    what ``[camera] fov_deg`` needs to give ``intrinsics_from_fov`` that focal length back."""
    return math.degrees(2 * math.atan(width / 2 / focal_px))


def rotation_from_angles(pitch_deg: float, roll_deg: float = 0.0, yaw_deg: float = 0.0) -> np.ndarray:
    """World-to-camera R of a camera pitched down by ``pitch_deg`` and rolled by ``roll_deg``.

    Yaw turns the viewing direction from world +y towards +x (clockwise seen from above).
    """
    p, r, y = (math.radians(a) for a in (pitch_deg, roll_deg, yaw_deg))
    pitch = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(p), -math.sin(p)], [0.0, math.sin(p), math.cos(p)]])
    # Positive roll turns the camera clockwise seen from behind it: the horizon's right end rises.
    roll = np.array([[math.cos(r), math.sin(r), 0.0], [-math.sin(r), math.cos(r), 0.0], [0.0, 0.0, 1.0]])
    yaw = np.array([[math.cos(y), -math.sin(y), 0.0], [math.sin(y), math.cos(y), 0.0], [0.0, 0.0, 1.0]])
    return roll @ pitch @ _LEVEL_CAMERA @ yaw


def angles_from_rotation(R: np.ndarray) -> tuple[float, float, float]:
    """(pitch_deg, roll_deg, yaw_deg) of a world-to-camera R; inverse of rotation_from_angles."""
    forward, right = R[2], R[0]
    pitch = math.degrees(math.asin(float(np.clip(-forward[2], -1.0, 1.0))))
    roll = math.degrees(math.atan2(-right[2], -R[1, 2]))
    yaw = math.degrees(math.atan2(forward[0], forward[1]))
    return pitch, roll, yaw


def camera_from_pose(width: int, height: int, K: np.ndarray, height_m: float, pitch_deg: float,
                     roll_deg: float = 0.0, yaw_deg: float = 0.0, dist: np.ndarray | None = None,
                     source: str = "calibration") -> CameraInfo:
    """A fully known camera ``height_m`` above the world origin."""
    R = rotation_from_angles(pitch_deg, roll_deg, yaw_deg)
    t = -R @ np.array([0.0, 0.0, height_m])
    return CameraInfo(width=width, height=height, K=np.asarray(K, float), dist=dist, R=R, t=t,
                      height_m=float(height_m), source=source)


# --------------------------------------------------------------------------- loading JSON

def _matrix(value: Any, shape: tuple[int, ...], where: str) -> np.ndarray:
    """Nested list, flat list or cv2.FileStorage {"rows", "cols", "data"} to an array."""
    if isinstance(value, dict):
        value = value.get("data")
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ConfigError(f"{where} is not a numeric matrix: {value!r}") from None
    if array.size != math.prod(shape) or not np.all(np.isfinite(array)):
        raise ConfigError(f"{where} must hold {math.prod(shape)} finite numbers, got {value!r}")
    return array.reshape(shape)


def _first(data: dict, keys: tuple[str, ...]) -> Any:
    for key in keys:
        if key in data:
            return data[key]
    return None


def _image_size(data: dict, where: str) -> tuple[int, int]:
    size = data.get("image_size")
    if size is None and "image_width" in data and "image_height" in data:
        size = [data["image_width"], data["image_height"]]
    if (not isinstance(size, (list, tuple)) or len(size) != 2
            or not all(isinstance(v, (int, float)) and v > 0 for v in size)):
        raise ConfigError(f"{where}: needs \"image_size\": [width, height] of the calibrated frames")
    return int(size[0]), int(size[1])


def _pose(data: dict, where: str) -> tuple[np.ndarray, np.ndarray] | None:
    """(R, t) from R + t, rvec + tvec, or camera height + pitch (+ roll); None if no pose."""
    import cv2

    R_value, t_value, rvec_value = _first(data, _KEYS_R), _first(data, _KEYS_T), data.get("rvec")
    R = None
    if R_value is not None:
        R = _matrix(R_value, (3, 3), f"{where}: R")
        if abs(np.linalg.det(R) - 1.0) > 1e-3 or np.abs(R @ R.T - np.eye(3)).max() > 1e-3:
            raise ConfigError(f"{where}: R_world_to_cam is not a rotation matrix")
    if rvec_value is not None:
        from_rvec = cv2.Rodrigues(_matrix(rvec_value, (3,), f"{where}: rvec"))[0]
        if R is not None and np.abs(R - from_rvec).max() > 1e-3:
            raise ConfigError(f"{where}: rvec and R_world_to_cam disagree")
        R = from_rvec
    if R is not None:
        if t_value is None:
            raise ConfigError(f"{where}: a rotation without a translation (t_world_to_cam_m)")
        t = _matrix(t_value, (3,), f"{where}: t")
        centre_height = float(-(R.T @ t)[2])
        stated = data.get("camera_height_m")
        if isinstance(stated, (int, float)) and abs(stated - centre_height) > 0.01 * abs(stated) + 0.01:
            raise ConfigError(f"{where}: camera_height_m {stated} does not match the pose "
                              f"(camera centre at z = {centre_height:.3f} m; is t the camera centre "
                              "instead of the world-to-camera translation?)")
        return R, t
    if "camera_height_m" in data and "pitch_deg" in data:
        height_m = float(data["camera_height_m"])
        R = rotation_from_angles(float(data["pitch_deg"]), float(data.get("roll_deg", 0.0)))
        return R, -R @ np.array([0.0, 0.0, height_m])
    return None


def load_calibration(path: str | Path) -> CameraInfo:
    """A calibration JSON as a CameraInfo (R, t and height_m None for an intrinsic-only file)."""
    path = Path(path)
    where = str(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"calibration file not found: {path}") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ConfigError(f"{path} is not a readable JSON calibration: {exc}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path} must hold a JSON object")
    width, height = _image_size(data, where)
    K_value = _first(data, _KEYS_K)
    if K_value is None:
        raise ConfigError(f"{where}: needs the intrinsics \"K\" (3x3)")
    K = _matrix(K_value, (3, 3), f"{where}: K")
    if K[0, 0] <= 0 or K[1, 1] <= 0 or abs(K[2, 2] - 1.0) > 1e-9 or np.any(K[2, :2] != 0):
        raise ConfigError(f"{where}: K must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0")
    dist = None
    dist_value = _first(data, _KEYS_DIST)
    if dist_value is not None:
        dist = np.asarray(dist_value, dtype=float).ravel() if not isinstance(dist_value, dict) \
            else np.asarray(dist_value.get("data"), dtype=float).ravel()
        if dist.size not in (4, 5, 8, 12, 14) or not np.all(np.isfinite(dist)):
            raise ConfigError(f"{where}: distortion must be 4, 5, 8, 12 or 14 OpenCV coefficients")
        if not np.any(dist):
            dist = None
    pose = _pose(data, where)
    camera = CameraInfo(width=width, height=height, K=K, dist=dist, source="calibration",
                        lens_from_file=True)
    if pose is not None:
        camera.R, camera.t = pose
        camera.pose_from = "file"
        camera.height_m = float(camera_centre(camera)[2])
        if camera.height_m <= 0:
            raise ConfigError(f"{where}: the camera centre is not above the ground plane z = 0 "
                              f"(z = {camera.height_m:.3f} m)")
    return camera


def rescale_camera(camera: CameraInfo, width: int, height: int) -> CameraInfo:
    """The same camera for frames resized to width x height (aspect ratio must match)."""
    if (width, height) == (camera.width, camera.height):
        return camera
    sx, sy = width / camera.width, height / camera.height
    if abs(sx / sy - 1.0) > 0.01:
        raise ConfigError(f"the calibration is for {camera.width}x{camera.height} frames but the "
                          f"source is {width}x{height} (a different aspect ratio)")
    K = camera.K.copy()
    # Pixel centres at integers: u' = (u + 0.5) * s - 0.5.
    K[0] *= sx
    K[1] *= sy
    K[0, 2] += 0.5 * sx - 0.5
    K[1, 2] += 0.5 * sy - 0.5
    return dataclasses.replace(camera, width=width, height=height, K=K)


def camera_for_run(config: CameraConfig, width: int, height: int) -> CameraInfo:
    """What the run knows of its camera, from ``[camera]`` and an optional calibration file.

    Source of the result: "calibration" (full pose from a file or from height + pitch),
    "self" (height + pitch marked ``self_calibrated``), "camera-height" (height only: the
    network's scale-free output becomes metres, no geometry) or "none" (nothing: an assumed
    height, every height flagged as uncalibrated).
    """
    if config.height_m < 0:
        raise ConfigError(f"camera.height_m must be > 0 (or 0 = unknown), got {config.height_m}")
    has_angles = config.pitch_deg != 0.0
    if config.calibration:
        camera = rescale_camera(load_calibration(config.calibration), width, height)
        # A pose in [camera] (height and pitch, as `heightpipe calibrate` prints them) takes
        # only the intrinsics from the file; a height alone must agree with the file's pose.
        if camera.R is not None and not (config.height_m > 0 and has_angles):
            if config.height_m > 0 and abs(config.height_m - camera.height_m) > 0.02 * camera.height_m:
                raise ConfigError(f"camera.height_m = {config.height_m} contradicts the calibration "
                                  f"{config.calibration} (camera {camera.height_m:.2f} m above ground)")
            return camera
        K, dist = camera.K, camera.dist
    else:
        K, dist = intrinsics_from_fov(width, height, config.fov_deg), None

    if config.height_m > 0 and has_angles:
        if not 0.0 < config.pitch_deg < 90.0:
            raise ConfigError(f"camera.pitch_deg must be between 0 and 90 (looking down), "
                              f"got {config.pitch_deg}")
        source = "self" if config.self_calibrated else "calibration"
        camera = camera_from_pose(width, height, K, config.height_m, config.pitch_deg,
                                  config.roll_deg, dist=dist, source=source)
        return dataclasses.replace(camera, pose_from="config", lens_from_file=bool(config.calibration))
    if config.height_m > 0:
        return CameraInfo(width=width, height=height, K=K, dist=dist, height_m=config.height_m,
                          source="camera-height", lens_from_file=bool(config.calibration))
    return CameraInfo(width=width, height=height, K=K, dist=dist, height_m=CONSTANTS.assumed_camera_height_m,
                      source="none", lens_from_file=bool(config.calibration))


# --------------------------------------------------------------------------- projection

def is_calibrated(camera: CameraInfo) -> bool:
    """Whether the ground plane is known in the camera: metric geometry is possible."""
    return camera.K is not None and camera.R is not None and camera.t is not None


def has_distortion(camera: CameraInfo) -> bool:
    return camera.dist is not None and bool(np.any(np.asarray(camera.dist) != 0))


def camera_centre(camera: CameraInfo) -> np.ndarray:
    return -camera.R.T @ camera.t


def undistort_pixels(camera: CameraInfo, uv: np.ndarray) -> np.ndarray:
    """Raw-frame pixels to pixels of the undistorted image with the same K (N x 2)."""
    uv = np.asarray(uv, dtype=float).reshape(-1, 2)
    if not has_distortion(camera) or len(uv) == 0:
        return uv
    import cv2

    return cv2.undistortPoints(uv.reshape(-1, 1, 2), camera.K, np.asarray(camera.dist, float),
                               P=camera.K).reshape(-1, 2)


def pixel_rays(camera: CameraInfo, uv: np.ndarray) -> np.ndarray:
    """World directions (N x 3, not normalised) of the rays through undistorted pixels."""
    uv = np.asarray(uv, dtype=float).reshape(-1, 2)
    homogeneous = np.column_stack([uv, np.ones(len(uv))])
    return (camera.R.T @ np.linalg.solve(camera.K, homogeneous.T)).T


def project_points(camera: CameraInfo, points_world: np.ndarray) -> np.ndarray:
    """World points (N x 3) to undistorted pixels (N x 2); NaN behind the camera."""
    points = np.asarray(points_world, dtype=float).reshape(-1, 3)
    cam = points @ camera.R.T + camera.t
    pix = cam @ camera.K.T
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = pix[:, :2] / pix[:, 2:3]
    uv[cam[:, 2] <= 0] = np.nan
    return uv


def pixel_to_ground(camera: CameraInfo, uv: np.ndarray, z_m: float = 0.0) -> np.ndarray:
    """Undistorted pixels to points on the ground plane, or on the horizontal plane ``z_m`` above
    it (N x 2 world x, y); NaN where the ray does not reach it (at or above the horizon)."""
    rays = pixel_rays(camera, uv)
    centre = camera_centre(camera)
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = (z_m - centre[2]) / rays[:, 2]
    ground = centre[:2] + scale[:, None] * rays[:, :2]
    ground[~(scale > 0)] = np.nan
    return ground


def horizon_line(camera: CameraInfo) -> np.ndarray:
    """The ground plane's vanishing line (a, b, c), a*u + b*v + c = 0, with a^2 + b^2 = 1.

    It is l = K^-T R e_z: the image of every horizontal direction lies on it.
    """
    line = np.linalg.solve(camera.K.T, camera.R[:, 2])
    return line / np.hypot(line[0], line[1])


def vertical_vanishing_point(camera: CameraInfo) -> np.ndarray:
    """Homogeneous image point where world verticals meet (K R e_z; third coordinate may be 0)."""
    return camera.K @ camera.R[:, 2]


def heights_from_foot_top(camera: CameraInfo, foot_uv: np.ndarray,
                          top_uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Single-view metrology: heights (N) and ground points (N x 2) from undistorted pixels.

    The foot ray meets the ground at G; the object's top is where the top ray passes the
    vertical through G (the point of the top ray horizontally nearest to G: the least-squares
    meeting of the two lines, exact when the top is above the foot). Valid for any tilt and
    roll; equivalent to the cross-ratio along the line to the vertical vanishing point.
    NaN where the foot is at or above the horizon or the top ray does not pass G in front.
    """
    ground = pixel_to_ground(camera, foot_uv)
    top_rays = pixel_rays(camera, top_uv)
    centre = camera_centre(camera)
    horizontal = top_rays[:, :2]
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.einsum("ij,ij->i", ground - centre[:2], horizontal) / np.einsum("ij,ij->i", horizontal, horizontal)
    heights = centre[2] + scale * top_rays[:, 2]
    heights[~(scale > 0)] = np.nan
    return heights, ground
