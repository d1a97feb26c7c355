"""The fixed CCTV camera: pose sampling, intrinsics, and depth -> height back-projection.

Conventions (shared with the rest of heightpipe): OpenCV camera axes (x right, y down,
z forward), ``x_cam = R @ x_world + t``, world z up with the ground at z = 0. Pixel centres
sit at integer coordinates, so the principal point of an undistorted W x H render is
((W - 1) / 2, (H - 1) / 2). ``fov_deg`` is the horizontal field of view.

Only NumPy here: the dataset loader imports this module without MuJoCo.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

PAPER_HEIGHTS_M = (3.5, 5.0, 6.4, 7.8, 9.2)
HEIGHT_RANGE_M = (3.5, 9.2)
PITCH_RANGE_DEG = (10.0, 50.0)
FOV_RANGE_DEG = (40.0, 100.0)
ROLL_MAX_DEG = 3.0


@dataclass
class SynthCamera:
    width: int
    height: int
    K: np.ndarray  # 3x3 float64
    R: np.ndarray  # 3x3 world -> camera
    t: np.ndarray  # (3,) metres
    height_m: float
    pitch_deg: float
    roll_deg: float
    fov_deg: float
    yaw_deg: float = 0.0

    @property
    def position(self) -> np.ndarray:
        return -self.R.T @ self.t

    @property
    def fovy_deg(self) -> float:
        return math.degrees(2 * math.atan((self.height / 2) / self.K[1, 1]))

    def project(self, points_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates (N, 2) and camera z-depth (N,) of world points (N, 3)."""
        cam = points_world @ self.R.T + self.t
        z = cam[:, 2]
        uv = cam[:, :2] / np.where(np.abs(z) < 1e-9, 1e-9, z)[:, None]
        uv = uv * np.array([self.K[0, 0], self.K[1, 1]]) + np.array([self.K[0, 2], self.K[1, 2]])
        return uv, z

    def pixel_rays(self) -> np.ndarray:
        """World-frame direction per pixel (H, W, 3), scaled so camera z of each ray is 1."""
        v, u = np.mgrid[0:self.height, 0:self.width].astype(np.float64)
        x = (u - self.K[0, 2]) / self.K[0, 0]
        y = (v - self.K[1, 2]) / self.K[1, 1]
        cam = np.stack([x, y, np.ones_like(x)], axis=-1)
        return cam @ self.R  # (R^T @ d)^T = d^T @ R

    def world_points(self, depth_m: np.ndarray) -> np.ndarray:
        """Back-project a planar z-depth map to world points (H, W, 3); inf depth gives inf/nan."""
        return self.position[None, None, :] + depth_m[..., None].astype(np.float64) * self.pixel_rays()

    def height_map(self, depth_m: np.ndarray) -> np.ndarray:
        """World z of the surface seen at every pixel (float32, NaN where the depth is inf)."""
        with np.errstate(invalid="ignore"):
            z = self.position[2] + depth_m.astype(np.float64) * self.pixel_rays()[..., 2]
        z[~np.isfinite(depth_m)] = np.nan
        return z.astype(np.float32)

    def to_json(self) -> dict:
        return {"width": self.width, "height": self.height, "K": self.K.tolist(), "R": self.R.tolist(),
                "t": self.t.tolist(), "height_m": self.height_m, "pitch_deg": self.pitch_deg,
                "roll_deg": self.roll_deg, "fov_deg": self.fov_deg, "yaw_deg": self.yaw_deg,
                "position": self.position.tolist()}

    @classmethod
    def from_json(cls, d: dict) -> "SynthCamera":
        return cls(width=int(d["width"]), height=int(d["height"]), K=np.array(d["K"], np.float64),
                   R=np.array(d["R"], np.float64), t=np.array(d["t"], np.float64),
                   height_m=float(d["height_m"]), pitch_deg=float(d["pitch_deg"]),
                   roll_deg=float(d["roll_deg"]), fov_deg=float(d["fov_deg"]),
                   yaw_deg=float(d.get("yaw_deg", 0.0)))


def make_camera(position: np.ndarray, yaw_deg: float, pitch_deg: float, roll_deg: float,
                fov_deg: float, width: int, height: int) -> SynthCamera:
    """A camera at ``position`` looking along heading yaw, tilted pitch below the horizon."""
    yaw, pitch, roll = map(math.radians, (yaw_deg, pitch_deg, roll_deg))
    forward = np.array([math.cos(pitch) * math.cos(yaw), math.cos(pitch) * math.sin(yaw), -math.sin(pitch)])
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    # Roll turns the image clockwise for positive angles.
    c, s = math.cos(roll), math.sin(roll)
    right, down = c * right + s * down, -s * right + c * down
    R = np.stack([right, down, forward])
    t = -R @ np.asarray(position, np.float64)
    f = (width / 2) / math.tan(math.radians(fov_deg) / 2)
    K = np.array([[f, 0.0, (width - 1) / 2], [0.0, f, (height - 1) / 2], [0.0, 0.0, 1.0]])
    return SynthCamera(width=width, height=height, K=K, R=R, t=t, height_m=float(position[2]),
                       pitch_deg=float(pitch_deg), roll_deg=float(roll_deg), fov_deg=float(fov_deg),
                       yaw_deg=float(yaw_deg))


def mujoco_xyaxes(camera: SynthCamera) -> tuple[np.ndarray, np.ndarray]:
    """MuJoCo's camera x and y axes in world coordinates (it looks along -z, y up)."""
    return camera.R[0], -camera.R[1]


def ground_footprint_point(camera: SynthCamera, u: float, v: float) -> np.ndarray | None:
    """Where the ray through pixel (u, v) meets the ground plane, or None above the horizon."""
    d = camera.R.T @ np.array([(u - camera.K[0, 2]) / camera.K[0, 0], (v - camera.K[1, 2]) / camera.K[1, 1], 1.0])
    if d[2] >= -1e-6:
        return None
    lam = -camera.position[2] / d[2]
    return camera.position + lam * d
