"""Reading (and the types of) the synthetic dataset written by ``heightpipe synth``.

This is the contract with heightnet/ and the tracker evaluation
(notes_for_helpers/SYNTH_FORMAT.md); the on-disk layout is documented in synth/README.md.
Heights are not stored: they are world z of the surface seen, recomputed here from the
exact float32 depth, the intrinsics and the pose, so they cannot disagree with the depth.
Only NumPy and OpenCV are needed (no MuJoCo).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from synth.camera import SynthCamera
from synth.scene import CLASS_ID, CLASS_NAMES, GROUND_CLASSES

FORMAT = "heightpipe-synth/1"
MOVER_CLASSES = ("pedestrian", "cyclist", "car", "van", "truck", "bus")
COARSE_CLASS = {"pedestrian": "person", "cyclist": "cyclist", "car": "vehicle", "van": "vehicle",
                "truck": "vehicle", "bus": "vehicle"}
GROUND_CLASS_IDS = np.array([CLASS_ID[c] for c in GROUND_CLASSES], np.uint8)
# Drawn, but given no instance (no box): training ignores them, evaluation does not count them.
PARKED_VEHICLE_ID = CLASS_ID["parked_vehicle"]

__all__ = ["CLASS_NAMES", "MOVER_CLASSES", "COARSE_CLASS", "PARKED_VEHICLE_ID", "SynthCamera", "SequenceMeta",
           "SynthFrame", "ObjectTruth", "SynthSequence", "list_sequences", "ground_mask"]


@dataclass
class SequenceMeta:
    layout: str
    layout_seed: int
    split: str
    fps: float
    weather: str
    time_of_day: str
    camera: SynthCamera
    name: str = ""
    scenario: str = ""
    raw: dict | None = None
    """The whole meta.json (environment, movers, render settings, notes)."""


@dataclass
class SynthFrame:
    rgb: np.ndarray  # uint8 HxWx3 RGB
    height_m: np.ndarray  # float32 HxW, 0 on ground, NaN for sky
    ground: np.ndarray  # bool HxW
    depth_m: np.ndarray  # float32 HxW planar z-depth, inf for sky
    bg_depth_m: np.ndarray  # float32 HxW, movers removed
    instance: np.ndarray  # uint16 HxW, 0 = no mover
    semantic: np.ndarray  # uint8 HxW, index into CLASS_NAMES
    time_s: float


@dataclass
class ObjectTruth:
    id: int
    cls: str
    box: tuple[float, float, float, float]  # x, y, w, h in pixels (full extent, even if occluded)
    visible_fraction: float
    height_m: float  # true top of the object this frame
    ground_xy_m: tuple[float, float]


def ground_mask(semantic: np.ndarray) -> np.ndarray:
    return np.isin(semantic, GROUND_CLASS_IDS)


def heights_from_depth(camera: SynthCamera, depth_m: np.ndarray, semantic: np.ndarray) -> np.ndarray:
    """World z per pixel; painted ground layers (<= 0.6 mm) count as exactly 0."""
    height = camera.height_map(depth_m)
    height[ground_mask(semantic)] = 0.0
    np.maximum(height, 0.0, out=height, where=np.isfinite(height))
    return height


class SynthSequence:
    """One rendered sequence on disk; frames are read lazily."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        meta_path = self.path / "meta.json"
        if not meta_path.is_file():
            raise FileNotFoundError(f"{self.path} is not a synth sequence (no meta.json)")
        raw = json.loads(meta_path.read_text())
        self.name = raw.get("name", self.path.name)
        self.meta = SequenceMeta(layout=raw["layout"], layout_seed=int(raw["layout_seed"]), split=raw["split"],
                                 fps=float(raw["fps"]), weather=raw["weather"], time_of_day=raw["time_of_day"],
                                 camera=SynthCamera.from_json(raw["camera"]), name=self.name,
                                 scenario=raw.get("scenario", ""), raw=raw)
        self._frames = int(raw["frames_written"])
        self._rgb_ext = raw.get("rgb_format", "jpg")
        self._bg: np.ndarray | None = None
        self._objects: dict[int, list[ObjectTruth]] | None = None
        self._mover_class = {int(m["id"]): m["class"] for m in raw.get("movers", [])}

    def __len__(self) -> int:
        return self._frames

    def __repr__(self) -> str:
        return f"SynthSequence({self.path}, {len(self)} frames, {self.meta.layout})"

    @property
    def bg_depth_m(self) -> np.ndarray:
        if self._bg is None:
            with np.load(self.path / "bg_depth.npz") as z:
                self._bg = z["depth"].astype(np.float32)
        return self._bg

    def image_bgr(self, i: int) -> np.ndarray:
        """Frame ``i``'s picture alone (BGR, as OpenCV reads it), without its label maps: what a
        camera would have given."""
        import cv2

        if not 0 <= i < len(self):
            raise IndexError(f"frame {i} out of range 0..{len(self) - 1}")
        path = self.path / "rgb" / f"{i:06d}.{self._rgb_ext}"
        bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if bgr is None:
            raise FileNotFoundError(path)
        return bgr

    def frame(self, i: int) -> SynthFrame:
        import cv2

        stem = f"{i:06d}"
        bgr = self.image_bgr(i)
        instance = cv2.imread(str(self.path / "instance" / f"{stem}.png"), cv2.IMREAD_UNCHANGED).astype(np.uint16)
        semantic = cv2.imread(str(self.path / "semantic" / f"{stem}.png"), cv2.IMREAD_UNCHANGED).astype(np.uint8)
        bg = self.bg_depth_m
        depth = bg.copy()
        with np.load(self.path / "depth" / f"{stem}.npz") as z:
            depth.reshape(-1)[z["index"]] = z["depth"]
        height = heights_from_depth(self.meta.camera, depth, semantic)
        return SynthFrame(rgb=np.ascontiguousarray(bgr[..., ::-1]), height_m=height, ground=ground_mask(semantic),
                          depth_m=depth, bg_depth_m=bg.copy(), instance=instance, semantic=semantic,
                          time_s=i / self.meta.fps)

    def __iter__(self):
        for i in range(len(self)):
            yield self.frame(i)

    def _load_objects(self) -> dict[int, list[ObjectTruth]]:
        objects: dict[int, list[ObjectTruth]] = {i: [] for i in range(len(self))}
        ground: dict[tuple[int, int], tuple[float, float]] = {}
        world_path = self.path / "gt" / "world.txt"
        if world_path.is_file():
            for line in world_path.read_text().splitlines():
                if line.strip():
                    f, oid, x, y = line.split(",")[:4]
                    ground[(int(f), int(oid))] = (float(x), float(y))
        for line in (self.path / "gt" / "gt.txt").read_text().splitlines():
            if not line.strip():
                continue
            f, oid, x, y, w, h, _conf, cls_id, vis, height = line.split(",")[:10]
            frame, oid = int(f), int(oid)
            objects.setdefault(frame - 1, []).append(ObjectTruth(
                id=oid, cls=self._mover_class.get(oid, CLASS_NAMES[int(cls_id)]),
                box=(float(x), float(y), float(w), float(h)), visible_fraction=float(vis),
                height_m=float(height), ground_xy_m=ground.get((frame, oid), (float("nan"), float("nan")))))
        return objects

    def objects(self, i: int) -> list[ObjectTruth]:
        if self._objects is None:
            self._objects = self._load_objects()
        return list(self._objects.get(i, []))


def list_sequences(root: str | Path, split: str | None = None) -> list[SynthSequence]:
    """All sequences under ``root`` (sorted by name), optionally only one split."""
    if split not in (None, "train", "test"):
        raise ValueError(f"split must be 'train', 'test' or None, got {split!r}")
    root = Path(root)
    manifest = root / "manifest.json"
    if manifest.is_file():
        names = json.loads(manifest.read_text()).get("sequences", [])
        paths = [root / n for n in names if (root / n / "meta.json").is_file()]
    else:
        paths = sorted(p.parent for p in root.glob("*/meta.json"))
    sequences = [SynthSequence(p) for p in sorted(paths)]
    return [s for s in sequences if split is None or s.meta.split == split]
