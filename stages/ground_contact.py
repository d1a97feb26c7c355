"""Ground-contact offsets: the target HeightNet v2 learns, and metres from it in closed form.

For every pixel p the network predicts the image offset (du, dv) from p to the image of its
*ground-contact point*: the ground point vertically below the 3-D point p sees (zero on the
ground). This is the "flow" of Christie et al., *Learning Geocentric Object Pose in Oblique
Monocular Images* (CVPR 2020). It is local — the soles of a person are a few pixels below the
knee, whatever the camera — so a small network can learn it, while metric height needs the
camera, which single-view metrology then applies exactly:

    r_p, r_f   world rays of p and of its contact pixel f = p + (du, dv)
    G = C + (-C_z / r_f,z) r_f                      the contact point on the ground z = 0
    s = <G_xy - C_xy, r_p,xy> / |r_p,xy|^2         how far along r_p the vertical through G is
    H = C_z + s r_p,z                               the height above the ground

exact for any pitch and roll on flat ground. The same formulas build exact targets from the
generator's depth: back-project, drop to z = 0, project.

A camera here is (K, R, C): intrinsics of the image the offsets live in, world-to-camera
rotation, camera centre (its z is the mounting height). Yaw and the horizontal position do not
change any height, so a camera known only as (height, pitch, roll, focal length) is enough.
Both NumPy (targets, run time) and torch (training, differentiable) versions live here, side by
side, because they must agree to the last digit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# A contact ray must point below the horizon; rays closer to it than this (0.006 deg: ground
# 10,000 camera heights away) are clamped, which caps the height a wild offset can decode to
# instead of dividing by ~0.
MIN_DESCENT = 1e-4


@dataclass(frozen=True)
class PinholeCamera:
    """What single-view metrology needs: K of the image, world-to-camera R, centre C (metres)."""

    K: np.ndarray
    R: np.ndarray
    C: np.ndarray

    @property
    def height_m(self) -> float:
        return float(self.C[2])

    def window(self, x0: float, y0: float, w: float, h: float, out_w: int, out_h: int,
               flip: bool = False) -> "PinholeCamera":
        """The camera of a crop (x0, y0, w, h) resized to out_w x out_h (pixel centres kept),
        optionally mirrored left-right (a negative fx, which every formula here accepts)."""
        sx, sy = out_w / w, out_h / h
        K = self.K.astype(np.float64).copy()
        K[0, 0] *= sx
        K[1, 1] *= sy
        K[0, 1] *= sx
        K[0, 2] = (K[0, 2] + 0.5 - x0) * sx - 0.5
        K[1, 2] = (K[1, 2] + 0.5 - y0) * sy - 0.5
        if flip:
            K[0, 0], K[0, 1], K[0, 2] = -K[0, 0], -K[0, 1], out_w - 1 - K[0, 2]
        return PinholeCamera(K, self.R, self.C)


def camera_from_angles(width: int, height: int, height_m: float, pitch_rad: float, roll_rad: float,
                       focal_y_px: float, aspect: float = 1.0) -> PinholeCamera:
    """A camera at (0, 0, height_m) looking along +y, pitched down and rolled (the conventions of
    ``stages/calibration.py``: positive roll raises the horizon's right end), principal point at
    the image centre, ``aspect`` = fx / fy (1 for square pixels; a squashed frame has another)."""
    cp, sp, cr, sr = math.cos(pitch_rad), math.sin(pitch_rad), math.cos(roll_rad), math.sin(roll_rad)
    forward = np.array([0.0, cp, -sp])
    right = np.array([1.0, 0.0, 0.0])
    down = np.cross(forward, right)
    right, down = cr * right + sr * down, -sr * right + cr * down
    R = np.stack([right, down, forward])
    K = np.array([[focal_y_px * aspect, 0.0, (width - 1) / 2], [0.0, focal_y_px, (height - 1) / 2],
                  [0.0, 0.0, 1.0]])
    return PinholeCamera(K, R, np.array([0.0, 0.0, float(height_m)]))


def angles_of(camera: PinholeCamera) -> tuple[float, float]:
    """Pitch (down positive) and roll of a camera, radians, whatever its yaw."""
    forward, right = camera.R[2], camera.R[0]
    pitch = math.asin(float(np.clip(-forward[2], -1, 1)))
    # Roll: how far the camera's x axis leaves the horizontal plane, positive = right end up.
    roll = math.asin(float(np.clip(-right[2], -1, 1)) / max(math.cos(pitch), 1e-9))
    return pitch, roll


# --------------------------------------------------------------------------- NumPy

def pixel_grid(width: int, height: int) -> np.ndarray:
    """H x W x 2 pixel centres (u, v)."""
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    return np.stack([u, v], axis=-1)


def ray_matrix(camera: PinholeCamera) -> np.ndarray:
    """3 x 3 M with world ray = [u, v, 1] @ M (R^T K^-1 as rows): rays are affine in (u, v)."""
    return np.linalg.inv(camera.K).T @ camera.R


def world_rays(camera: PinholeCamera, uv: np.ndarray) -> np.ndarray:
    """World direction of the ray through each pixel (..., 2) -> (..., 3), camera z = 1."""
    M = ray_matrix(camera)
    return np.asarray(uv, np.float64) @ M[:2] + M[2]


def contact_offsets(camera: PinholeCamera, height_m: np.ndarray, ground: np.ndarray) -> np.ndarray:
    """Exact target offsets H x W x 2 (pixels) from a height map; NaN where height is undefined.

    Only the height is needed, not the depth: the seen point is where the pixel's ray reaches
    that height, and its contact point the same point at z = 0.
    """
    h, w = height_m.shape
    uv = pixel_grid(w, h)
    rays = world_rays(camera, uv)
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = (height_m.astype(np.float64) - camera.C[2]) / rays[..., 2]
        point = camera.C + lam[..., None] * rays
        point[..., 2] = 0.0
        cam = (point - camera.C) @ camera.R.T
        proj = cam @ camera.K.T
        contact = proj[..., :2] / proj[..., 2:3]
    offsets = contact - uv
    offsets[ground.astype(bool)] = 0.0
    offsets[~np.isfinite(height_m)] = np.nan
    return offsets.astype(np.float32)


def heights_from_offsets(camera: PinholeCamera, offsets: np.ndarray) -> np.ndarray:
    """Height in metres above the ground (H x W) seen at each pixel, from its contact offset."""
    h, w = offsets.shape[:2]
    # float32 throughout, like the offsets and the map it returns: within 2e-6 m of float64 and a
    # third of its time (320x240: 3.1 -> 1.0 ms), once a frame in a live run.
    M = ray_matrix(camera).astype(np.float32)
    u, v = np.arange(w, dtype=np.float32)[None, :], np.arange(h, dtype=np.float32)[:, None]
    du, dv = offsets[..., 0].astype(np.float32), offsets[..., 1].astype(np.float32)
    # Rays are affine in the pixel, so the contact point's ray is the pixel's plus the offset's
    # share (the same numbers as world_rays(uv + offsets) to rounding). Built one component at a
    # time from a row and a column: no H x W x 2 grid or matrix product (1.8 -> 0.5 ms at 320x180).
    r_p = [u * M[0, k] + v * M[1, k] + M[2, k] for k in range(3)]
    r_f = [r_p[k] + du * M[0, k] + dv * M[1, k] for k in range(3)]
    return _height(r_p, r_f, np.float32(camera.C[2]), np).astype(np.float32, copy=False)


def _height(r_p, r_f, c_z, xp):
    """The closed form shared by NumPy and torch (``xp`` is the array module); the rays through
    the pixel (``r_p``) and its contact point (``r_f``) as their x, y, z components."""
    norm_f = xp.sqrt(r_f[0] * r_f[0] + r_f[1] * r_f[1] + r_f[2] * r_f[2])
    descent = xp.minimum(r_f[2], -MIN_DESCENT * norm_f)
    dot = r_f[0] * r_p[0] + r_f[1] * r_p[1]
    horizontal = r_p[0] ** 2 + r_p[1] ** 2 + 1e-12
    # G_xy - C_xy = (-C_z / r_f,z) r_f,xy; H = C_z + s r_p,z
    s = (-c_z / descent) * dot / horizontal
    return c_z + s * r_p[2]


# --------------------------------------------------------------------------- torch

def torch_heights_from_offsets(offsets, K, R, C):
    """Differentiable ``heights_from_offsets`` for a batch: offsets B x 2 x H x W (pixels),
    K, R B x 3 x 3, C B x 3 (float tensors) -> B x 1 x H x W metres."""
    import torch

    b, _, h, w = offsets.shape
    v, u = torch.meshgrid(torch.arange(h, dtype=offsets.dtype, device=offsets.device),
                          torch.arange(w, dtype=offsets.dtype, device=offsets.device), indexing="ij")
    uv = torch.stack([u, v], 0)[None].expand(b, 2, h, w)
    Kinv = torch.linalg.inv(K.double()).to(offsets.dtype)
    M = (R.transpose(1, 2) @ Kinv)  # world ray = M @ [u, v, 1]

    def rays(points):
        flat = points.flatten(2)  # B x 2 x N
        homog = torch.cat([flat, torch.ones_like(flat[:, :1])], 1)
        return (M @ homog).transpose(1, 2)  # B x N x 3

    r_p = rays(uv)
    r_f = rays(uv + offsets)
    height = _height(r_p.unbind(-1), r_f.unbind(-1), C[:, 2:3], torch)
    return height.view(b, 1, h, w)
