"""HeightNet v2 training data: generator frames -> a decoded cache -> pairs with exact targets.

The cache (``<data>/.contact_cache/<sequence>/``) holds, per sequence, the frames at their
rendered resolution: RGB, the exact ground-contact offsets (``stages/ground_contact.py``, from the
generator's depth and camera), the height map, the semantic classes, the mover instances, the
movers' whole boxes (hidden parts included, as evaluation boxes them), the feature matches between
consecutive frames (for the height-consistency loss) and the camera.
The arrays lie in one file a sequence (``arrays.bin``, their layout in ``meta.json``), memory-mapped
once: a map holds its file open, and a file an array ran a machine out of open files at ~3,300
sequences (``ulimit -n`` 20,000).

A sample is a pair (t-1, t) of one camera's frames with the same window, flip and colour
jitter. The window is either the whole frame squashed to the input size (what the run-time
stage feeds the network) or, with probability ``crop_probability``, a native-resolution window
around a random mover: at 320x240 a person far from a 9 m camera is 10-20 px tall, and native
crops of a 640x480 render show the network people at twice that size; with probability
``zoom_probability`` a window smaller than the input, enlarged to it, shows near objects as big as
a 3.5 m camera sees them. Every target is
transformed with the window — offsets scaled per axis and mirrored, the camera's K moved — so
the closed-form decode stays exact on the crop. Camera-head targets are given on whole frames
only: a crop's camera has an off-centre principal point the heads are not asked to know.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import cv2
import numpy as np

from stages.ground_contact import PinholeCamera, angles_of, contact_offsets, world_rays
from heightnet.appearance import apply_appearance, draw_appearance, pair_texture
from heightnet.data import Augmentation, apply_colour, colour_jitter, match_features, window_matches
from heightnet.contact_model import DETECTION_STRIDE
from heightnet.detection_targets import big_object_targets, detection_targets, ignored_cells, window_boxes
from synth.dataset import PARKED_VEHICLE_ID

CACHE_VERSION = 3
"""1: one .npy file an array; 2: one file a sequence; 3: with each frame's whole-object boxes."""
ARRAYS_FILE = "arrays.bin"
ARRAY_ALIGN = 64
"""Each array starts at a multiple of this many bytes of ``ARRAYS_FILE`` (aligned reads)."""
# Classes scored apart in the evaluation: trucks and buses hide their contact points.
CLASS_GROUPS = {"pedestrian": "person", "cyclist": "cyclist", "car": "car/van", "van": "car/van",
                "truck": "truck/bus", "bus": "truck/bus"}


@dataclass
class ContactSequence:
    """One sequence's cached arrays (memory-mapped) and camera."""

    name: str
    camera: PinholeCamera
    rgb: np.ndarray          # T x H x W x 3 uint8
    offsets: np.ndarray      # T x H x W x 2 float16, pixels; NaN = undefined (sky)
    height_m: np.ndarray     # T x H x W float16, NaN = sky
    semantic: np.ndarray     # T x H x W uint8 (synth CLASS_NAMES)
    ground: np.ndarray       # T x H x W uint8 (0/1)
    instance: np.ndarray     # T x H x W uint16, 0 = no mover
    match_offsets: np.ndarray
    match_points: np.ndarray
    boxes: np.ndarray        # M x 7 float32: frame, mover id, x, y, w, h, visible share (``object_boxes``)

    def __len__(self) -> int:
        return len(self.rgb)

    def whole_boxes(self, t: int) -> dict[int, tuple[float, float, float, float, float]]:
        """Frame ``t``'s movers by id: their whole box (x0, y0, x1, y1, pixels of the frame,
        hidden parts included) and the share of it in view."""
        rows = self.boxes[self.boxes[:, 0] == t]
        return {int(r[1]): (float(r[2]), float(r[3]), float(r[2] + r[4]), float(r[3] + r[5]), float(r[6]))
                for r in rows}

    def matches(self, t: int) -> np.ndarray:
        return self.match_points[self.match_offsets[t]:self.match_offsets[t + 1]]


def build_contact_cache(sequences: Sequence[Any], cache_dir: Path, progress: bool = False,
                        workers: int = 0) -> list[ContactSequence]:
    """Decode every frame once (reused when present) and load the cache memory-mapped;
    ``workers`` > 1 decodes sequences in that many processes (a many-core GPU machine)."""
    from tqdm import tqdm

    cache_dir = Path(cache_dir)
    missing = [seq for seq in sequences if not _cached(seq, cache_dir / seq.name)]
    bar = tqdm(total=len(missing), desc="cache", disable=not progress or not missing, dynamic_ncols=True)
    if workers > 1 and len(missing) > 1:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(workers) as pool:
            for _ in pool.map(_cache_sequence, missing, [cache_dir] * len(missing), chunksize=4):
                bar.update(1)
    else:
        for seq in missing:
            _cache_sequence(seq, cache_dir)
            bar.update(1)
    bar.close()
    return [load_contact_sequence(cache_dir / seq.name) for seq in sequences]


def _stamp(seq: Any) -> dict[str, int]:
    return {"version": CACHE_VERSION, "frames": len(seq)}


def _cached(seq: Any, folder: Path) -> bool:
    done = folder / "done.json"
    return done.is_file() and json.loads(done.read_text()) == _stamp(seq)


def _cache_sequence(seq: Any, cache_dir: Path) -> None:
    folder = Path(cache_dir) / seq.name
    _write_sequence(seq, folder)
    (folder / "done.json").write_text(json.dumps(_stamp(seq)))


def synth_pinhole(camera: Any) -> PinholeCamera:
    return PinholeCamera(np.asarray(camera.K, np.float64), np.asarray(camera.R, np.float64),
                         np.asarray(camera.position, np.float64))


def _write_sequence(seq: Any, folder: Path) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for stale in folder.glob("*.npy"):  # a version-1 cache of this sequence
        stale.unlink()
    camera = synth_pinhole(seq.meta.camera)
    frames = [seq.frame(i) for i in range(len(seq))]
    offsets, points = [0, 0], []
    for t in range(1, len(frames)):
        m = match_features(frames[t - 1].rgb, frames[t].rgb, frames[t - 1].instance, frames[t].instance)
        points.append(m)
        offsets.append(offsets[-1] + len(m))
    layout = write_arrays(folder / ARRAYS_FILE, {
        "rgb": np.stack([f.rgb for f in frames]),
        "offsets": np.stack([contact_offsets(camera, f.height_m, f.ground) for f in frames]).astype(np.float16),
        "height_m": np.stack([f.height_m for f in frames]).astype(np.float16),
        "semantic": np.stack([f.semantic for f in frames]).astype(np.uint8),
        "ground": np.stack([f.ground for f in frames]).astype(np.uint8),
        "instance": np.stack([f.instance for f in frames]).astype(np.uint16),
        "match_offsets": np.asarray(offsets[:len(frames) + 1], np.int64),
        "match_points": np.concatenate(points) if points else np.zeros((0, 4), np.float32),
        "boxes": object_boxes(seq),
    })
    (folder / "meta.json").write_text(json.dumps({
        "name": seq.name, "K": camera.K.tolist(), "R": camera.R.tolist(), "C": camera.C.tolist(),
        "arrays": layout}))


def object_boxes(seq: Any) -> np.ndarray:
    """M x 7 float32: every frame's movers as the generator boxed them (frame, id, x, y, w, h of
    the whole object, hidden parts included, and its visible share)."""
    rows = [(i, o.id, *o.box, o.visible_fraction) for i in range(len(seq)) for o in seq.objects(i)]
    return np.asarray(rows, np.float32).reshape(-1, 7)


def write_arrays(path: Path, arrays: dict[str, np.ndarray]) -> dict[str, dict]:
    """Write ``arrays`` one after another into ``path``; return each one's dtype, shape and offset."""
    layout = {}
    with open(path, "wb") as f:
        for name, array in arrays.items():
            array = np.ascontiguousarray(array)
            f.write(bytes(-f.tell() % ARRAY_ALIGN))
            layout[name] = {"dtype": array.dtype.str, "shape": list(array.shape), "offset": f.tell()}
            f.write(array.data)
    return layout


def map_arrays(path: Path, layout: dict[str, dict]) -> dict[str, np.ndarray]:
    """Read-only views of the arrays ``write_arrays`` wrote, all on one memory map of ``path``."""
    whole = np.memmap(path, dtype=np.uint8, mode="r")
    return {name: np.ndarray(tuple(entry["shape"]), np.dtype(entry["dtype"]), buffer=whole, offset=entry["offset"])
            for name, entry in layout.items()}


def load_contact_sequence(folder: Path) -> ContactSequence:
    meta = json.loads((folder / "meta.json").read_text())
    arrays = map_arrays(folder / ARRAYS_FILE, meta["arrays"])
    camera = PinholeCamera(np.array(meta["K"]), np.array(meta["R"]), np.array(meta["C"]))
    return ContactSequence(meta["name"], camera, arrays["rgb"], arrays["offsets"], arrays["height_m"],
                           arrays["semantic"], arrays["ground"], arrays["instance"],
                           np.array(arrays["match_offsets"]), np.array(arrays["match_points"]),
                           np.array(arrays["boxes"]))


# ----------------------------------------------------------------------------- camera channels

def camera_channels(camera: PinholeCamera, width: int, height: int) -> np.ndarray:
    """CAM-Conv style input channels (2 x H x W): the tangent of each ray's depression below the
    horizon, and its horizontal direction relative to the optical axis (tangent)."""
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    rays = world_rays(camera, np.stack([u, v], -1))
    horizontal = np.sqrt(rays[..., 0] ** 2 + rays[..., 1] ** 2) + 1e-9
    depression = -rays[..., 2] / horizontal
    lateral = (u - camera.K[0, 2]) / camera.K[0, 0]
    return np.stack([depression, lateral]).astype(np.float32)


def camera_targets(camera: PinholeCamera, image_height: int) -> np.ndarray:
    """Pitch, roll (radians) and log of the vertical focal length in image heights."""
    pitch, roll = angles_of(camera)
    return np.array([pitch, roll, math.log(abs(camera.K[1, 1]) / image_height)], np.float32)


def position_window(x0: int, y0: int, w: int, h: int, frame_width: int, frame_height: int,
                    flip: bool) -> np.ndarray:
    """The window's place in its source frame for ``contact_model.position_channels``: x start,
    x span, y start, y span, with the frame running from -1 to 1 each way. A flipped sample is a
    whole mirrored scene, so its x runs across the mirrored frame (the window's right edge first)."""
    span_x, span_y = 2 * w / frame_width, 2 * h / frame_height
    start_x = 2 * x0 / frame_width - 1
    if flip:
        start_x = -(start_x + span_x)
    return np.array([start_x, span_x, 2 * y0 / frame_height - 1, span_y], np.float32)


# ----------------------------------------------------------------------------- samples

@dataclass
class ContactSampling:
    """How training windows are drawn (``crop_probability`` 0 = whole frames only)."""

    crop_probability: float = 0.0
    crop_jitter: float = 0.25          # window centre moves by up to this share of its size
    flip: bool = True
    colour: bool = True
    camera_channels: bool = False
    detection: bool = False            # centre heatmap and box targets (heightnet/detection_targets.py)
    detection_stride: int = DETECTION_STRIDE  # input pixels per cell of those targets (the head's outputs)
    appearance: float = 0.0            # share of pairs whose look is randomised (heightnet/appearance.py)
    still_pairs: float = 0.0           # share of pairs shown as one frame twice: no motion anywhere
    whole_boxes: bool = False          # box targets span the whole object, hidden parts too (``window_boxes``)
    zoom_probability: float = 0.0      # share of windows smaller than the input around a mover, enlarged
    zoom_range: tuple[float, float] = (1.5, 3.0)  # how many times such a window is enlarged
    centre_core: float = 0.0           # big objects are centres where their Gaussian reaches this
    big_objects: bool = False          # targets of the big-object head too (``big_object_targets``)


class ContactPairDataset:
    """Pairs (t-1, t); a map dataset of NumPy arrays (see ``__getitem__`` for the keys)."""

    def __init__(self, sequences: Sequence[ContactSequence], input_width: int, input_height: int,
                 sampling: ContactSampling, max_matches: int = 64, seed: int = 0,
                 augment: bool = True):
        self.sequences = list(sequences)
        self.index = [(s, t) for s, seq in enumerate(self.sequences) for t in range(1, len(seq))]
        if not self.index:
            raise ValueError("training data has no sequence with two or more frames")
        self.size = (input_width, input_height)
        self.sampling = sampling
        self.max_matches = max_matches
        self.seed = seed
        self.augment = augment

    def __len__(self) -> int:
        return len(self.index)

    def window(self, rng: np.random.Generator, seq: ContactSequence, t: int) -> tuple[int, int, int, int, bool]:
        """x0, y0, w, h of the window and whether it is a crop (native resolution, or zoomed).

        Zoomed windows (``zoom_probability``, drawn only where asked for, so that runs without
        them draw the windows they drew before) are smaller than the input and enlarged to it:
        a car passing a 3.5 m camera is 80-160 px tall in a 320x240 frame, and whole frames and
        native crops of the 640x480 renders show objects that big rarely, and the head found 8 %
        of them (none taller). Forty minutes of the head alone at 0.3 did not change that
        (docs/results.md, 2026-12-06, thirty-third session)."""
        _, height, width, _ = seq.rgb.shape
        W, H = self.size
        zoom = bool(self.augment and self.sampling.zoom_probability > 0
                    and rng.random() < self.sampling.zoom_probability)
        if zoom or (self.augment and rng.random() < self.sampling.crop_probability and width >= W and height >= H):
            ids = np.unique(np.asarray(seq.instance[t]))
            ids = ids[ids > 0]
            if len(ids):
                w, h = W, H
                if zoom:
                    factor = rng.uniform(*self.sampling.zoom_range)
                    w, h = min(width, max(8, round(W / factor))), min(height, max(8, round(H / factor)))
                ys, xs = np.nonzero(np.asarray(seq.instance[t]) == rng.choice(ids))
                jitter = self.sampling.crop_jitter
                cx = xs.mean() + rng.uniform(-jitter, jitter) * w
                cy = ys.mean() + rng.uniform(-jitter, jitter) * h
                x0 = int(np.clip(round(cx - w / 2), 0, width - w))
                y0 = int(np.clip(round(cy - h / 2), 0, height - h))
                return x0, y0, w, h, True
        return 0, 0, width, height, False

    def __getitem__(self, item: int) -> dict[str, Any]:
        """Pair ``item`` as drawn in the first epoch (``sample`` draws it in any)."""
        return self.sample(item, 0)

    def sample(self, item: int, epoch: int) -> dict[str, Any]:
        """Pair ``item`` as drawn in ``epoch`` (window, flip and colours follow from seed, epoch
        and item alone, so any process draws the same): image 2x3xHxW uint8 RGB (colours jittered,
        not yet normalised), offsets 2x2xHxW float16 (NaN = no label), height 2x1xHxW metres
        float16 (NaN = no label), ground 2x1xHxW uint8, instance 2x1xHxW int32, K/R (3x3) and C
        (3) of the window's camera, camera_target (3) with camera_valid, matches Kx4 with
        match_valid, and camera_channels 2x2xHxW when enabled, window 2x4 (``position_window``),
        and with detection det_centre 2x3xhxw, det_box 2x4xhxw, det_box_mask 2x1xhxw, det_ignore
        2x1xhxw at 1/4 of the input (the head's stride), and with big objects the same four
        prefixed ``det_big_`` at 1/16. Images and labels keep compact types (0.4 of the bytes in
        float32: what loader processes copy) until ``contact_train.training_batch`` widens a
        batch where the network runs."""
        s, t = self.index[item]
        seq = self.sequences[s]
        rng = np.random.default_rng([self.seed, epoch, item])
        x0, y0, w, h, cropped = self.window(rng, seq, t)
        flip = bool(self.augment and self.sampling.flip and rng.random() < 0.5)
        colour = colour_jitter(rng, Augmentation()) if self.augment and self.sampling.colour else None
        W, H = self.size
        look = draw_appearance(rng, self.sampling.appearance if self.augment else 0.0)
        texture = pair_texture(rng, look, W, H)
        # Drawn only where asked for: a run without still pairs draws the pairs it drew before.
        still = bool(self.augment and self.sampling.still_pairs > 0 and rng.random() < self.sampling.still_pairs)
        sx, sy = W / w, H / h
        camera = seq.camera.window(x0, y0, w, h, W, H, flip)
        images, offsets, heights, grounds, instances = [], [], [], [], []
        detection: dict[str, list[np.ndarray]] = {"centre": [], "box": [], "box_mask": [], "ignore": []}
        if self.sampling.big_objects:
            detection.update({f"big_{key}": [] for key in ("centre", "box", "box_mask", "ignore")})
        for frame in (t, t) if still else (t - 1, t):
            win = (slice(y0, y0 + h), slice(x0, x0 + w))
            if self.sampling.detection:
                semantic = np.asarray(seq.semantic[frame][win])
                whole = seq.whole_boxes(frame) if self.sampling.whole_boxes else None
                boxes = window_boxes(np.asarray(seq.instance[frame][win]), semantic, sx, sy, flip, W,
                                     whole, (x0, y0))
                parked = _nearest((semantic == PARKED_VEHICLE_ID).astype(np.uint8), W, H) > 0
                stride = self.sampling.detection_stride
                parked = parked[:, ::-1] if flip else parked
                ignore = ignored_cells(parked, stride)
                for key, value in detection_targets(boxes, W, H, ignore, stride, self.sampling.centre_core).items():
                    detection[key].append(value)
                if self.sampling.big_objects:
                    for key, value in big_object_targets(boxes, W, H, parked).items():
                        detection[f"big_{key}"].append(value)
            rgb = cv2.resize(np.asarray(seq.rgb[frame][win]), (W, H), interpolation=cv2.INTER_AREA)
            off = _nearest(np.asarray(seq.offsets[frame][win], np.float32), W, H) * np.float32([sx, sy])
            hgt = _nearest(np.asarray(seq.height_m[frame][win], np.float32), W, H)
            gnd = _nearest(np.asarray(seq.ground[frame][win]), W, H)
            ins = _nearest(np.asarray(seq.instance[frame][win]), W, H)
            if flip:
                rgb, off, hgt, gnd, ins = (a[:, ::-1] for a in (rgb, off, hgt, gnd, ins))
                off = off * np.float32([-1, 1])
            if colour is not None:
                rgb = apply_colour(rgb, colour)
            rgb = apply_appearance(rgb, look, rng, texture)
            images.append(np.ascontiguousarray(rgb.transpose(2, 0, 1)))
            offsets.append(np.ascontiguousarray(off.transpose(2, 0, 1)).astype(np.float16))
            heights.append(hgt[None].astype(np.float16))
            grounds.append(gnd[None].astype(np.uint8))
            instances.append(ins[None].astype(np.int32))
        padded, valid = window_matches(seq.matches(t), (x0, y0, w, h), self.size, flip, rng, self.max_matches)
        if still:
            valid[:] = False    # the points matched from t-1 to t: no pair of this one
        sample = {"image": np.stack(images), "offsets": np.stack(offsets), "height": np.stack(heights),
                  "ground": np.stack(grounds), "instance": np.stack(instances),
                  "K": camera.K.astype(np.float32), "R": camera.R.astype(np.float32),
                  "C": camera.C.astype(np.float32), "camera_target": camera_targets(camera, H),
                  "camera_valid": np.bool_(not cropped), "matches": padded, "match_valid": valid,
                  "window": np.stack([position_window(x0, y0, w, h, seq.rgb.shape[2], seq.rgb.shape[1], flip)] * 2)}
        if self.sampling.detection:
            sample.update({f"det_{key}": np.stack(value) for key, value in detection.items()})
        if self.sampling.camera_channels:
            sample["camera_channels"] = np.stack([camera_channels(camera, W, H)] * 2)
        return sample


def _nearest(array: np.ndarray, width: int, height: int) -> np.ndarray:
    if array.shape[1] == width and array.shape[0] == height:
        return array
    return cv2.resize(array, (width, height), interpolation=cv2.INTER_NEAREST_EXACT)
