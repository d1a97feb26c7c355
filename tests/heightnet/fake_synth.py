"""A tiny stand-in for a rendered synth sequence, built on synth.dataset's own records.

A pinhole camera at height C looks down a flat ground plane; movers are upright billboards
facing the camera (id-coloured, textured) walking sideways. Heights, ground mask, depth and
instance ids come from exact ray casts, so the labels are geometrically right.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


from synth.camera import SynthCamera
from synth.dataset import CLASS_NAMES, ObjectTruth, SequenceMeta, SynthFrame


@dataclass
class Mover:
    id: int
    x: float
    y: float
    speed: float
    width: float
    height: float
    colour: np.ndarray


@dataclass
class FakeSequence:
    name: str
    meta: SequenceMeta
    frames: int
    movers: list[Mover] = field(default_factory=list)

    def __len__(self) -> int:
        return self.frames

    def _rays(self) -> np.ndarray:
        cam = self.meta.camera
        u, v = np.meshgrid(np.arange(cam.width) + 0.5, np.arange(cam.height) + 0.5)
        pix = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(cam.K).T
        return pix @ cam.R  # camera -> world directions (R is world -> camera)

    def _render(self, i: int):
        cam = self.meta.camera
        d = self._rays()
        centre = np.array([0.0, 0.0, cam.height_m])
        with np.errstate(divide="ignore", invalid="ignore"):
            s_ground = np.where(d[..., 2] < 0, -cam.height_m / d[..., 2], np.inf)
        dist = s_ground.copy()
        height = np.where(np.isfinite(s_ground), 0.0, np.nan)
        instance = np.zeros(d.shape[:2], np.uint16)
        gx = centre[0] + s_ground * d[..., 0]
        gy = centre[1] + s_ground * d[..., 1]
        checker = ((np.floor(gx) + np.floor(gy)) % 2 == 0)
        rgb = np.where(checker[..., None], 110, 90) * np.ones(3)
        rgb = np.where(np.isfinite(s_ground)[..., None], rgb, np.array([150.0, 180.0, 220.0]))
        t = i / self.meta.fps
        objects = []
        for m in sorted(self.movers, key=lambda m: -m.y):
            x = m.x + m.speed * t
            with np.errstate(divide="ignore", invalid="ignore"):
                s = m.y / d[..., 1]
            hx = s * d[..., 0]
            hz = cam.height_m + s * d[..., 2]
            hit = (s > 0) & (np.abs(hx - x) < m.width / 2) & (hz >= 0) & (hz <= m.height) & (s < dist)
            dist = np.where(hit, s, dist)
            height = np.where(hit, hz, height)
            instance[hit] = m.id
            stripes = 0.75 + 0.25 * np.sin(hz * 12.0 + (hx - x) * 9.0)
            rgb = np.where(hit[..., None], m.colour * stripes[..., None], rgb)
            ys, xs = np.nonzero(instance == m.id)
            if len(xs):
                objects.append(ObjectTruth(m.id, "pedestrian", (float(xs.min()), float(ys.min()),
                                           float(np.ptp(xs) + 1), float(np.ptp(ys) + 1)), 1.0,
                                           m.height, (x, m.y)))
        depth = dist * (d @ cam.R.T)[..., 2]
        ground = instance == 0
        ground &= np.isfinite(s_ground)
        return rgb.clip(0, 255).astype(np.uint8), height.astype(np.float32), ground, depth, \
            instance, objects

    def frame(self, i: int) -> SynthFrame:
        rgb, height, ground, depth, instance, _ = self._render(i)
        # Movers are pedestrians (as their ObjectTruth says), the rest road where there is ground.
        semantic = np.where(instance > 0, CLASS_NAMES.index("pedestrian"),
                            np.where(np.isfinite(height), CLASS_NAMES.index("road"), 0)).astype(np.uint8)
        return SynthFrame(rgb, height, ground, depth.astype(np.float32), depth.astype(np.float32),
                          instance, semantic, i / self.meta.fps)

    def objects(self, i: int) -> list[ObjectTruth]:
        return self._render(i)[5]


def fake_camera(width: int, height: int, camera_height_m: float, pitch_deg: float) -> SynthCamera:
    f = width / (2 * np.tan(np.radians(30)))
    K = np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1.0]])
    p = np.radians(pitch_deg)
    # World: x right, y forward, z up. Camera looks along +y pitched down by p.
    forward = np.array([0, np.cos(p), -np.sin(p)])
    right = np.array([1.0, 0, 0])
    down = np.cross(forward, right)
    R = np.stack([right, down, forward])
    t = -R @ np.array([0, 0, camera_height_m])
    return SynthCamera(width, height, K, R, t, camera_height_m, pitch_deg, roll_deg=0.0, fov_deg=60.0)


def fake_sequences(count: int = 2, frames: int = 4, width: int = 96, height: int = 64,
                   seed: int = 0, camera_heights=(3.5, 9.2)) -> list[FakeSequence]:
    rng = np.random.default_rng(seed)
    sequences = []
    for k in range(count):
        cam_h = float(camera_heights[k % len(camera_heights)])
        camera = fake_camera(width, height, cam_h, 25.0)
        movers = [Mover(j + 1, float(rng.uniform(-4, 4)), float(rng.uniform(8, 16)),
                        float(rng.uniform(-1.5, 1.5)), float(rng.uniform(0.6, 2.0)),
                        float(rng.uniform(1.5, 2.0)), rng.uniform(40, 240, 3)) for j in range(3)]
        meta = SequenceMeta("fake", k, "train" if k % 5 else "test", 10.0, "clear", "day", camera)
        sequences.append(FakeSequence(f"fake_{k:03d}", meta, frames, movers))
    return sequences
