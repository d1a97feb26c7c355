"""Training data: synth sequences -> a decoded cache -> pairs of consecutive frames with matches.

Decoding JPEG/PNG and matching features cost more than a training step's data handling, so
``build_cache`` does both once per dataset and stores plain arrays (memory-mapped at training
time, one folder per sequence under ``<data>/.heightnet_cache``). A training sample is a pair
(t-1, t) of one sequence's frames — the same fixed camera — with the same random crop, flip and
colour jitter applied to both, plus the feature matches between them for the height consistency
loss.

Matches (the paper's "feature correspondences"): corners on mover pixels of frame t-1 tracked
into frame t with pyramidal Lucas-Kanade (``lk``, default) or ORB descriptors matched with a
cross-check (``orb``). A forward-backward check removes bad tracks, and the generator's instance
ids reject any match whose two ends lie on different movers (or on background): real video has
no such check, synthetic training data can afford it.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import cv2
import numpy as np

from heightnet.normalisation import normalise
from core.errors import ConfigError

CACHE_VERSION = 1
MATCHERS = ("lk", "orb")


@dataclass
class CachedSequence:
    """One sequence's decoded arrays (memory-mapped) and its pair matches."""

    name: str
    camera_height_m: float
    rgb: np.ndarray          # T x H x W x 3 uint8
    height_m: np.ndarray     # T x H x W float16, NaN where undefined (sky)
    ground: np.ndarray       # T x H x W uint8 (0/1)
    instance: np.ndarray     # T x H x W uint16
    match_offsets: np.ndarray  # T+1 int64: matches of pair (t-1, t) are points[off[t]:off[t+1]]
    match_points: np.ndarray   # M x 4 float32: x0, y0 (frame t-1), x1, y1 (frame t), pixels

    def __len__(self) -> int:
        return len(self.rgb)

    def matches(self, t: int) -> np.ndarray:
        return self.match_points[self.match_offsets[t]:self.match_offsets[t + 1]]


# ----------------------------------------------------------------------------- matching

def match_features(rgb0: np.ndarray, rgb1: np.ndarray, instance0: np.ndarray,
                   instance1: np.ndarray, method: str = "lk", max_points: int = 200) -> np.ndarray:
    """Correspondences on movers between two frames of one fixed camera: M x 4 (x0, y0, x1, y1)."""
    if method not in MATCHERS:
        raise ConfigError(f"unknown matcher {method!r} (known: {', '.join(MATCHERS)})")
    mask0 = (instance0 > 0).astype(np.uint8) * 255
    if not mask0.any():
        return np.zeros((0, 4), np.float32)
    gray0 = cv2.cvtColor(rgb0, cv2.COLOR_RGB2GRAY)
    gray1 = cv2.cvtColor(rgb1, cv2.COLOR_RGB2GRAY)
    if method == "lk":
        corners = cv2.goodFeaturesToTrack(gray0, max_points, 0.01, 3, mask=mask0)
        if corners is None:
            return np.zeros((0, 4), np.float32)
        p0 = corners.reshape(-1, 1, 2).astype(np.float32)
        lk = dict(winSize=(15, 15), maxLevel=2,
                  criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 0.03))
        p1, ok, _ = cv2.calcOpticalFlowPyrLK(gray0, gray1, p0, None, **lk)
        back, ok_back, _ = cv2.calcOpticalFlowPyrLK(gray1, gray0, p1, None, **lk)
        good = (ok[:, 0] == 1) & (ok_back[:, 0] == 1) & \
            (np.linalg.norm((back - p0)[:, 0], axis=1) < 1.0)
        pts = np.concatenate([p0[:, 0], p1[:, 0]], axis=1)[good]
    else:
        orb = cv2.ORB_create(nfeatures=max_points, edgeThreshold=8, patchSize=15)
        mask1 = (instance1 > 0).astype(np.uint8) * 255
        k0, d0 = orb.detectAndCompute(gray0, mask0)
        k1, d1 = orb.detectAndCompute(gray1, mask1)
        if d0 is None or d1 is None:
            return np.zeros((0, 4), np.float32)
        pairs = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(d0, d1)
        pts = np.array([[*k0[m.queryIdx].pt, *k1[m.trainIdx].pt] for m in pairs if m.distance < 64],
                       np.float32).reshape(-1, 4)
    return _same_instance(pts, instance0, instance1)


def _same_instance(pts: np.ndarray, instance0: np.ndarray, instance1: np.ndarray) -> np.ndarray:
    h, w = instance0.shape
    inside = (pts[:, 2] >= 0) & (pts[:, 2] <= w - 1) & (pts[:, 3] >= 0) & (pts[:, 3] <= h - 1)
    pts = pts[inside]
    i0 = instance0[np.round(pts[:, 1]).astype(int), np.round(pts[:, 0]).astype(int)]
    i1 = instance1[np.round(pts[:, 3]).astype(int), np.round(pts[:, 2]).astype(int)]
    return pts[(i0 > 0) & (i0 == i1)].astype(np.float32)


# ----------------------------------------------------------------------------- cache

def dataset_hash(roots: Path | Sequence[Path], extra: dict[str, Any] | None = None) -> str:
    """Hex digest of the dataset manifest(s) (+ training settings): which data made a model."""
    roots = [roots] if isinstance(roots, (str, Path)) else list(roots)
    digest = hashlib.sha256()
    for root in roots:
        manifest = Path(root) / "manifest.json"
        digest.update(manifest.read_bytes() if manifest.is_file() else str(root).encode())
    digest.update(json.dumps(extra or {}, sort_keys=True).encode())
    return digest.hexdigest()[:16]


def build_cache(sequences: Sequence[Any], cache_dir: Path, matcher: str = "lk",
                progress: bool = False) -> list[CachedSequence]:
    """Decode every frame once into ``cache_dir/<seq>/*.npy`` (reused when present) and load them."""
    from tqdm import tqdm

    cache_dir = Path(cache_dir)
    cached = []
    for seq in tqdm(sequences, desc="cache", disable=not progress):
        folder = cache_dir / seq.name
        done = folder / "done.json"
        stamp = {"version": CACHE_VERSION, "matcher": matcher, "frames": len(seq)}
        if not (done.is_file() and json.loads(done.read_text()) == stamp):
            _write_sequence(seq, folder, matcher)
            done.write_text(json.dumps(stamp))
        cached.append(load_cached_sequence(folder))
    return cached


def _write_sequence(seq: Any, folder: Path, matcher: str) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    frames = [seq.frame(i) for i in range(len(seq))]
    np.save(folder / "rgb.npy", np.stack([f.rgb for f in frames]))
    np.save(folder / "height_m.npy", np.stack([f.height_m for f in frames]).astype(np.float16))
    np.save(folder / "ground.npy", np.stack([f.ground for f in frames]).astype(np.uint8))
    np.save(folder / "instance.npy", np.stack([f.instance for f in frames]).astype(np.uint16))
    offsets, points = [0, 0], []
    for t in range(1, len(frames)):
        m = match_features(frames[t - 1].rgb, frames[t].rgb, frames[t - 1].instance,
                           frames[t].instance, matcher)
        points.append(m)
        offsets.append(offsets[-1] + len(m))
    np.save(folder / "match_offsets.npy", np.asarray(offsets[:len(frames) + 1], np.int64))
    np.save(folder / "match_points.npy",
            np.concatenate(points) if points else np.zeros((0, 4), np.float32))
    (folder / "meta.json").write_text(json.dumps({"name": seq.name,
                                                  "camera_height_m": float(seq.meta.camera.height_m)}))


def load_cached_sequence(folder: Path) -> CachedSequence:
    meta = json.loads((folder / "meta.json").read_text())

    def load(name: str) -> np.ndarray:
        return np.load(folder / f"{name}.npy", mmap_mode="r")

    return CachedSequence(meta["name"], meta["camera_height_m"], load("rgb"), load("height_m"),
                          load("ground"), load("instance"), np.load(folder / "match_offsets.npy"),
                          np.load(folder / "match_points.npy"))


# ----------------------------------------------------------------------------- samples

@dataclass
class Augmentation:
    """Random crop with aspect jitter (4:3 to 16:9 windows, like synth renders and real video),
    horizontal flip and colour jitter. The run-time stage squashes any aspect to the input size,
    so training sees squashed crops too."""

    min_area: float = 0.6
    aspect_range: tuple[float, float] = (4 / 3, 16 / 9)
    flip: bool = True
    brightness: float = 0.25
    contrast: float = 0.25
    saturation: float = 0.3


def sample_crop(rng: np.random.Generator, width: int, height: int,
                aug: Augmentation | None) -> tuple[int, int, int, int]:
    """x0, y0, w, h of a crop window (the whole frame without augmentation)."""
    if aug is None:
        return 0, 0, width, height
    for _ in range(10):
        aspect = rng.uniform(*aug.aspect_range)
        area = rng.uniform(aug.min_area, 1.0) * width * height
        w = int(round(np.sqrt(area * aspect)))
        h = int(round(np.sqrt(area / aspect)))
        if w <= width and h <= height:
            return int(rng.integers(0, width - w + 1)), int(rng.integers(0, height - h + 1)), w, h
    return 0, 0, width, height


def colour_jitter(rng: np.random.Generator, aug: Augmentation) -> list[float]:
    """Brightness, contrast and saturation factors, shared by both frames of a pair."""
    return [rng.uniform(1 - aug.brightness, 1 + aug.brightness),
            rng.uniform(1 - aug.contrast, 1 + aug.contrast),
            rng.uniform(1 - aug.saturation, 1 + aug.saturation)]


def apply_colour(rgb: np.ndarray, params: list[float]) -> np.ndarray:
    """Brightness b, then contrast c about the image's mean m, then saturation s about each
    pixel's grey g, clipped to uint8. All three are linear in the pixel, so they are one 3x4
    colour matrix, out = s c b rgb + (1 - s) c b g + (1 - c) b m, applied by OpenCV in one pass
    (35x faster than the three steps in NumPy floats; within one grey level of them, the 0.5
    below making OpenCV's rounding a truncation as NumPy's cast was)."""
    brightness, contrast, saturation = params
    mean = brightness * float(np.mean(cv2.mean(rgb)[:3]))
    matrix = np.full((3, 4), (1 - saturation) * contrast * brightness / 3.0)
    matrix[np.arange(3), np.arange(3)] += saturation * contrast * brightness
    matrix[:, 3] = (1 - contrast) * mean - 0.5
    return cv2.transform(rgb, matrix)


class PairDataset:
    """Pairs (t-1, t) of consecutive frames; a torch-style map dataset returning NumPy arrays.

    Item: image 2x3xHxW float32 (normalised), target 2x1xHxW float32 (height in the training
    target's units; NaN = no label), ground 2x1xHxW float32, mover 2x1xHxW bool, matches Kx4
    float32 in input pixels, match_valid K bool, camera_height_m float.
    """

    def __init__(self, sequences: Sequence[CachedSequence], input_width: int, input_height: int,
                 target: str, augmentation: Augmentation | None, max_matches: int = 64,
                 seed: int = 0):
        self.sequences = list(sequences)
        self.index = [(s, t) for s, seq in enumerate(self.sequences) for t in range(1, len(seq))]
        if not self.index:
            raise ConfigError("training data has no sequence with two or more frames")
        self.size = (input_width, input_height)
        self.target = target
        self.augmentation = augmentation
        self.max_matches = max_matches
        self.seed = seed
        self.epoch = 0

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, item: int) -> dict[str, Any]:
        s, t = self.index[item]
        seq = self.sequences[s]
        rng = np.random.default_rng([self.seed, self.epoch, item])
        _, height, width, _ = seq.rgb.shape
        x0, y0, w, h = sample_crop(rng, width, height, self.augmentation)
        flip = bool(self.augmentation and self.augmentation.flip and rng.random() < 0.5)
        colour = colour_jitter(rng, self.augmentation) if self.augmentation else None
        W, H = self.size
        images, targets, grounds, movers = [], [], [], []
        for frame in (t - 1, t):
            window = (slice(y0, y0 + h), slice(x0, x0 + w))
            rgb = cv2.resize(np.asarray(seq.rgb[frame][window]), (W, H), interpolation=cv2.INTER_AREA)
            hgt = _resize_nearest(np.asarray(seq.height_m[frame][window], np.float32), W, H)
            gnd = _resize_nearest(np.asarray(seq.ground[frame][window]), W, H)
            mov = _resize_nearest(np.asarray(seq.instance[frame][window]), W, H) > 0
            if flip:
                rgb, hgt, gnd, mov = (a[:, ::-1] for a in (rgb, hgt, gnd, mov))
            if colour is not None:
                rgb = apply_colour(rgb, colour)
            if self.target == "relative":
                hgt = hgt / seq.camera_height_m
            images.append(normalise(rgb))
            targets.append(hgt[None].astype(np.float32))
            grounds.append(gnd[None].astype(np.float32))
            movers.append(mov[None].copy())
        padded, valid = window_matches(seq.matches(t), (x0, y0, w, h), self.size, flip, rng, self.max_matches)
        return {"image": np.stack(images), "target": np.stack(targets), "ground": np.stack(grounds),
                "mover": np.stack(movers), "matches": padded, "match_valid": valid,
                "camera_height_m": np.float32(seq.camera_height_m)}


def window_matches(matches: np.ndarray, window: tuple[int, int, int, int], size: tuple[int, int],
                   flip: bool, rng: np.random.Generator, max_matches: int) -> tuple[np.ndarray, np.ndarray]:
    """Matches (x0, y0, x1, y1 in frame pixels) moved into a crop window resized to ``size`` (and
    mirrored), those inside kept, at most ``max_matches`` drawn; padded to max_matches x 4 with
    a validity mask."""
    x0, y0, w, h = window
    W, H = size
    m = matches.copy()
    m[:, [0, 2]] = (m[:, [0, 2]] + 0.5 - x0) * (W / w) - 0.5
    m[:, [1, 3]] = (m[:, [1, 3]] + 0.5 - y0) * (H / h) - 0.5
    if flip:
        m[:, [0, 2]] = W - 1 - m[:, [0, 2]]
    inside = ((m[:, [0, 2]] >= 0) & (m[:, [0, 2]] <= W - 1)).all(1) & \
             ((m[:, [1, 3]] >= 0) & (m[:, [1, 3]] <= H - 1)).all(1)
    m = m[inside]
    if len(m) > max_matches:
        m = m[rng.choice(len(m), max_matches, replace=False)]
    padded = np.zeros((max_matches, 4), np.float32)
    padded[:len(m)] = m
    valid = np.zeros(max_matches, bool)
    valid[:len(m)] = True
    return padded, valid


def _resize_nearest(array: np.ndarray, width: int, height: int) -> np.ndarray:
    # INTER_NEAREST_EXACT samples pixel centres; labels must not be blended across edges.
    return cv2.resize(array, (width, height), interpolation=cv2.INTER_NEAREST_EXACT)
