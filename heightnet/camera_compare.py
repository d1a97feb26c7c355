"""Camera height only: the camera heads against the nadir of the offsets, and what heights need.

    python -m heightnet.camera_compare CACHE_DIR [--sequences 50] [--frames 2] [--checkpoint PATH]

The question. Each above-ground offset of HeightNet v2 runs from its pixel to the image of the
ground point vertically below: the image of a vertical line. All such lines meet at the vertical
vanishing point (the nadir), which with the principal point at the image centre fixes the roll
and f cot(pitch) (f in image heights):

    nadir - centre = f cot(pitch) (sin roll, cos roll)

so the offsets could replace two of the camera heads' three guesses. ``fit_nadir`` fits it
robustly (below) and pools a fixed camera's frames; the third number comes from the heads.

For each sequence of a contact cache (``heightnet/contact_data.py``) the network's offsets and
heads on its first ``--frames`` whole frames give these cameras, all with the true mounting
height, each decoding the same offsets; object-top error as ``heightnet/contact_eval.py``
(per mover, 98th percentile of decoded heights against its highest true height; median |error|
per class group):

* ``true``: the true camera (the floor: the offsets' own error);
* ``heads``: pitch, roll, focal length from the heads' mean over the frames (``contact_eval``'s
  camera-height-only number);
* ``nadir+focal`` / ``nadir+pitch`` / ``nadir+blend``: roll and f cot(pitch) from the nadir,
  the third from the heads' focal length, their pitch, or log f weighted by inverse variance;
* diagnostics: ``nadir+true f`` (the fitted nadir's own worth); ``heads|true X`` (the heads'
  camera with one thing made true: the horizon f tan(pitch) at the heads' focal length, the
  pitch, the focal length, the nadir at the heads' focal length); ``*|snapped`` (the offsets'
  horizontal component replaced so each points at that camera's nadir).

Then the camera errors (median |pitch|, |roll| in degrees, |focal| and |horizon distance| in %),
and two checks of the offsets' geometry: the nadir fitted to the *exact* offsets (the fit is
right) and to the network's (the network is what it is), and the slope of the network's offset
direction against the true one (angles from the image vertical).

The robust fit: only offsets at least ``MIN_OFFSET_PX`` long vote; a line's residual is the
distance of its contact point from the line joining its pixel to the nadir (input pixels: about
the same noise whatever the length, so long offsets count for more), with a Cauchy loss
(iteratively reweighted least squares) started from a RANSAC crossing of two lines; the nadir is
homogeneous (smallest eigenvector), so a level camera's, at infinity, is no special case.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections import defaultdict
from pathlib import Path

import cv2
import numpy as np

from stages.camera_heads import camera_from_heads
from stages.ground_contact import PinholeCamera, angles_of, camera_from_angles, heights_from_offsets

GROUPS = ("person", "cyclist", "car/van", "truck/bus")
MIN_OFFSET_PX = 4.0        # shorter offsets do not vote: their direction is mostly noise
RESIDUAL_PX = 1.0          # Cauchy scale: the contact point's typical error across the line
ITERATIONS = 12            # reweighting rounds
HYPOTHESES = 256           # RANSAC: crossings of random pairs of lines ...
SCORED_LINES = 1000        # ... each scored on this many lines
LINES_PER_FRAME = 3000     # a fixed-seed sample of each frame's voting lines
DIRECTION_MIN_PX = 8.0     # offsets (predicted and exact) this long enter the direction slope


# ----------------------------------------------------------------------------- the nadir fit

def frame_lines(offsets: np.ndarray, aspect: float = 1.0) -> np.ndarray:
    """N x 4 (x, y, dx, dy) of a frame's voting offsets (H x W x 2, input pixels), in square
    image-height units about the image centre (``aspect`` = fx / fy of the input)."""
    h, w = offsets.shape[:2]
    offsets = np.asarray(offsets, np.float64)
    length = np.hypot(offsets[..., 0], offsets[..., 1])
    v, u = np.nonzero(np.isfinite(length) & (length >= MIN_OFFSET_PX))
    if len(v) > LINES_PER_FRAME:  # a sample, not the longest: those would favour wild outliers
        pick = np.random.default_rng(0).choice(len(v), LINES_PER_FRAME, replace=False)
        v, u = v[pick], u[pick]
    o = offsets[v, u]
    return np.stack([(u - (w - 1) / 2) / (aspect * h), (v - (h - 1) / 2) / h,
                     o[:, 0] / (aspect * h), o[:, 1] / h], axis=1)


def fit_nadir(lines: np.ndarray, image_height: int) -> np.ndarray | None:
    """Homogeneous nadir (X, Y, W) of lines N x 4, oriented so the offsets point at it (W > 0: a
    camera looking down); None with fewer than 2 lines."""
    if len(lines) < 2:
        return None
    p, o = lines[:, :2], lines[:, 2:]
    # l = (p, 1) x (p + o, 1), so l . V = cross(o, V_xy - V_w p).
    hom = np.stack([-o[:, 1], o[:, 0], p[:, 0] * o[:, 1] - p[:, 1] * o[:, 0]], axis=1)
    scale = RESIDUAL_PX / image_height
    V = _ransac(hom, p, o, scale)
    for _ in range(ITERATIONS):
        V = _orient(V, p, o)
        q = V[:2][None] - V[2] * p
        qn = np.hypot(q[:, 0], q[:, 1]) + 1e-12
        weight = ((o * q).sum(1) > 0) / (1.0 + ((hom @ V) / qn / scale) ** 2) / qn ** 2
        if weight.sum() <= 0:
            break
        V = np.linalg.eigh((hom * weight[:, None]).T @ hom)[1][:, 0]
    return _orient(V, p, o)


def _support(V: np.ndarray, p: np.ndarray, o: np.ndarray, hom: np.ndarray, scale: float) -> np.ndarray:
    """Sum of the Cauchy weights of the lines pointing towards each candidate (K x 3)."""
    q = V[:, None, :2] - V[:, None, 2:] * p[None]
    qn = np.hypot(q[..., 0], q[..., 1]) + 1e-12
    towards = (o[None] * q).sum(-1) > 0
    return (towards / (1.0 + ((V @ hom.T) / qn / scale) ** 2)).sum(1)


def _ransac(hom: np.ndarray, p: np.ndarray, o: np.ndarray, scale: float) -> np.ndarray:
    rng = np.random.default_rng(0)
    pairs = rng.integers(0, len(hom), size=(HYPOTHESES, 2))
    V = np.cross(hom[pairs[:, 0]], hom[pairs[:, 1]])
    norm = np.linalg.norm(V, axis=1)
    V = V[norm > 0] / norm[norm > 0, None]
    if not len(V):
        return np.array([0.0, 1.0, 0.0])
    V = np.concatenate([V, -V])  # the same image point, offsets pointing towards or away
    sample = rng.choice(len(hom), min(len(hom), SCORED_LINES), replace=False)
    return V[int(_support(V, p[sample], o[sample], hom[sample], scale).argmax())]


def _orient(V: np.ndarray, p: np.ndarray, o: np.ndarray) -> np.ndarray:
    q = V[:2][None] - V[2] * p
    return V if (np.sign((o * q).sum(1)) * np.hypot(o[:, 0], o[:, 1])).sum() >= 0 else -V


def nadir_roll(V: np.ndarray) -> float:
    return math.atan2(V[0], V[1])


def nadir_distance(V: np.ndarray) -> float:
    """f cot(pitch), image heights (inf for a nadir at or beyond infinity)."""
    return math.hypot(V[0], V[1]) / V[2] if V[2] > 0 else math.inf


def nadir_pitch(V: np.ndarray, focal: float) -> float:
    return math.atan2(V[2] * focal, math.hypot(V[0], V[1]))


def true_nadir(camera: PinholeCamera, image_height: int) -> np.ndarray:
    """The camera's nadir in the same homogeneous units (square pixels: aspect 1 assumed)."""
    f = abs(camera.K[1, 1]) / image_height
    d = camera.R @ np.array([0.0, 0.0, -1.0])  # camera coordinates of straight down
    return np.array([d[0], d[1], d[2] / f])


def nadir_camera(V: np.ndarray, heads: np.ndarray, width: int, height: int, aspect: float,
                 height_m: float, mode: str) -> PinholeCamera:
    """Roll and f cot(pitch) from the nadir; the focal length from the heads' (``focal``), from
    their pitch (``pitch``), or log f weighted by inverse variance between the two (``blend``)."""
    pitch_h, log_f = float(heads[0]), float(heads[2])
    focal = math.exp(log_f)
    if mode != "focal" and V[2] > 0 and 0 < pitch_h < math.pi / 2:
        from_pitch = nadir_distance(V) * math.tan(pitch_h)
        if mode == "pitch":
            focal = from_pitch
        else:
            var_pitch, var_log_f = np.exp(np.clip([heads[3], heads[5]], -20, 20))
            var_from_pitch = var_pitch / (math.sin(pitch_h) * math.cos(pitch_h)) ** 2
            w = var_from_pitch / (var_from_pitch + var_log_f)
            focal = math.exp(w * log_f + (1 - w) * math.log(from_pitch))
    return camera_from_angles(width, height, height_m, nadir_pitch(V, focal), nadir_roll(V), focal * height, aspect)


def snapped(camera: PinholeCamera, offsets: np.ndarray) -> np.ndarray:
    """Offsets with their vertical component kept and the horizontal one set so that each points
    at the camera's nadir (``*|snapped``)."""
    h, w = offsets.shape[:2]
    nd = camera.K @ camera.R @ np.array([0.0, 0.0, -1.0])
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        dx, dy = nd[0] - u * nd[2], nd[1] - v * nd[2]
        out = np.asarray(offsets, np.float64).copy()
        out[..., 0] = np.where(np.abs(dy) > 1e-9, offsets[..., 1] * dx / dy, offsets[..., 0])
    return out.astype(np.float32)


# ----------------------------------------------------------------------------- the comparison

def variant_cameras(true_camera: PinholeCamera, heads: np.ndarray, V: np.ndarray | None,
                    width: int, height: int, source_size: tuple[int, int]) -> dict[str, PinholeCamera]:
    """Every variant's camera at the input size for one sequence (``heads``: the frames' mean)."""
    height_m = true_camera.height_m
    aspect = (width / source_size[0]) / (height / source_size[1])
    head_cam = camera_from_heads(heads, width, height, source_size, height_m)
    cameras = {"true": true_camera, "heads": head_cam}
    true_f = abs(true_camera.K[1, 1]) / height
    for mode in ("focal", "pitch", "blend"):
        cameras[f"nadir+{mode}"] = (head_cam if V is None else
                                    nadir_camera(V, heads, width, height, aspect, height_m, mode))
    cameras["nadir+true f"] = head_cam if V is None else camera_from_angles(
        width, height, height_m, nadir_pitch(V, true_f), nadir_roll(V), true_f * height, aspect)
    hp, hr = angles_of(head_cam)
    hf = abs(head_cam.K[1, 1]) / height
    tp, tr = angles_of(true_camera)

    def heads_with(pitch: float, roll: float, focal: float) -> PinholeCamera:
        return camera_from_angles(width, height, height_m, pitch, roll, focal * height, aspect)

    cameras["heads|true horizon"] = heads_with(math.atan(true_f * math.tan(tp) / hf), hr, hf)
    cameras["heads|true pitch"] = heads_with(tp, hr, hf)
    cameras["heads|true focal"] = heads_with(hp, hr, true_f)
    cameras["heads|true nadir"] = heads_with(math.atan(hf * math.tan(tp) / true_f), tr, hf)
    cameras["true|snapped"] = true_camera
    cameras["heads|snapped"] = head_cam
    return cameras


def camera_errors(camera: PinholeCamera, truth: PinholeCamera) -> dict[str, float]:
    """|pitch|, |roll| errors (degrees), |focal| and |horizon distance| errors (%)."""
    pitch, roll = angles_of(camera)
    true_pitch, true_roll = angles_of(truth)
    focal, true_focal = abs(camera.K[1, 1]), abs(truth.K[1, 1])
    horizon, true_horizon = focal * math.tan(pitch), true_focal * math.tan(true_pitch)
    return {"pitch_deg": abs(math.degrees(pitch - true_pitch)), "roll_deg": abs(math.degrees(roll - true_roll)),
            "focal_pct": abs(focal / true_focal - 1) * 100, "horizon_pct": abs(horizon / true_horizon - 1) * 100}


def _nadir_errors(V: np.ndarray | None, truth: np.ndarray) -> tuple[float, float]:
    """|roll| error (degrees) and |f cot(pitch)| error (% of the true one) of a fitted nadir."""
    if V is None:
        return float("nan"), float("nan")
    roll = abs(math.degrees(math.remainder(nadir_roll(V) - nadir_roll(truth), 2 * math.pi)))
    return roll, abs(nadir_distance(V) / nadir_distance(truth) - 1) * 100


def compare(net, sequences, width: int, height: int, frames: int = 2, min_pixels: int = 20) -> dict:
    """Per variant: median object-top |error| (cm) per group and median camera errors; the nadir
    fits' errors and the offset-direction slope."""
    from heightnet.contact_eval import MAX_HEIGHT_M, frame_labels, labelled_objects, predict, top_error

    tops: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    errors: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    nadir_errors: dict[str, list[tuple[float, float]]] = defaultdict(list)
    angles_pred, angles_true = [], []
    for seq in sequences:
        _, src_h, src_w, _ = seq.rgb.shape
        true_camera = seq.camera.window(0, 0, src_w, src_h, width, height)
        aspect = (width / src_w) / (height / src_h)
        used = range(min(frames, len(seq)))
        outputs = [predict(net, np.asarray(seq.rgb[t]), width, height, true_camera) for t in used]
        heads = np.mean([cam for _, cam, _ in outputs], axis=0)
        exact = [cv2.resize(np.asarray(seq.offsets[t], np.float32), (width, height),
                            interpolation=cv2.INTER_NEAREST_EXACT) * np.float32([width / src_w, height / src_h])
                 for t in used]
        V = fit_nadir(np.concatenate([frame_lines(o, aspect) for o, _, _ in outputs]), height)
        V_exact = fit_nadir(np.concatenate([frame_lines(np.nan_to_num(e), aspect) for e in exact]), height)
        truth_nadir = true_nadir(true_camera, height)
        nadir_errors["network offsets"].append(_nadir_errors(V, truth_nadir))
        nadir_errors["exact offsets"].append(_nadir_errors(V_exact, truth_nadir))
        cameras = variant_cameras(true_camera, heads, V, width, height, (src_w, src_h))
        for name, camera in cameras.items():
            for key, value in camera_errors(camera, true_camera).items():
                errors[name][key].append(value)
        for t, (offsets, _, _), exact_t in zip(used, outputs, exact):
            length = np.hypot(offsets[..., 0], offsets[..., 1])
            exact_length = np.hypot(exact_t[..., 0], exact_t[..., 1])
            both = (length >= DIRECTION_MIN_PX) & np.isfinite(exact_length) & (exact_length >= DIRECTION_MIN_PX)
            angles_pred.append(np.degrees(np.arctan2(offsets[..., 0], offsets[..., 1]))[both])
            angles_true.append(np.degrees(np.arctan2(exact_t[..., 0], exact_t[..., 1]))[both])
            truth, instance, semantic = frame_labels(seq, t, width, height)
            preds = {name: np.clip(heights_from_offsets(camera, snapped(camera, offsets) if "snapped" in name
                                                        else offsets), 0, MAX_HEIGHT_M)
                     for name, camera in cameras.items()}
            for group, pixels in labelled_objects(truth, instance, semantic):
                if pixels.sum() < min_pixels:
                    continue
                for name, pred in preds.items():
                    tops[name][group].append(top_error(pred, truth, pixels))
    table = {}
    for name in errors:
        row = {f"top_{g}_cm": float(np.median(tops[name][g]) * 100) if tops[name][g] else float("nan")
               for g in GROUPS}
        row.update({k: float(np.median(v)) for k, v in errors[name].items()})
        table[name] = row
    pred_angles, true_angles = np.concatenate(angles_pred), np.concatenate(angles_true)
    return {"table": table, "objects": {g: len(tops["true"][g]) for g in GROUPS},
            "nadir": {k: np.nanmedian(np.array(v), axis=0).tolist() for k, v in nadir_errors.items()},
            "direction_slope": float(np.polyfit(true_angles, pred_angles, 1)[0]),
            "direction_true_deg": float(np.median(np.abs(true_angles))),
            "direction_pred_deg": float(np.median(np.abs(pred_angles))),
            "sequences": len(sequences)}


def format_report(result: dict) -> str:
    table = result["table"]
    cols = [f"top_{g}_cm" for g in GROUPS] + ["pitch_deg", "roll_deg", "focal_pct", "horizon_pct"]
    heads = ["people", "cyclists", "cars/vans", "trucks/bus", "pitch deg", "roll deg", "focal %", "horizon %"]
    lines = ["object-top median |error| (cm) and median camera errors, camera height only:",
             f"{'camera':<20}" + "".join(f"{h:>11}" for h in heads)]
    for name, row in table.items():
        lines.append(f"{name:<20}" + "".join(f"{row[c]:>11.2f}" for c in cols))
    lines += ["", "ratio of object-top error to the true camera's:"]
    for name, row in table.items():
        lines.append(f"{name:<20}" + "".join(f"{row[c] / table['true'][c]:>11.2f}" for c in cols[:4]))
    lines.append("objects: " + ", ".join(f"{g} {n}" for g, n in result["objects"].items()))
    lines += ["", "nadir fit, median |roll error| (deg) and |f cot(pitch) error| (%):"]
    for name, (roll, distance) in result["nadir"].items():
        lines.append(f"  from the {name:<16} roll {roll:8.2f}   f cot(pitch) {distance:10.1f}")
    lines.append(f"offset directions (both >= {DIRECTION_MIN_PX:.0f} px), angle from the image vertical: "
                 f"true median {result['direction_true_deg']:.1f} deg, predicted {result['direction_pred_deg']:.1f} "
                 f"deg, slope predicted/true {result['direction_slope']:.3f}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m heightnet.camera_compare", description=__doc__.split("\n")[0])
    parser.add_argument("cache", type=Path, help="a contact cache folder (one sub-folder per sequence)")
    parser.add_argument("--sequences", type=int, default=50, help="the first N sequences by name")
    parser.add_argument("--frames", type=int, default=2)
    parser.add_argument("--checkpoint", type=Path, default=Path(__file__).parent / "state/v2/checkpoint.pt")
    parser.add_argument("--size", default="320x240", help="network input WIDTHxHEIGHT")
    args = parser.parse_args(argv)
    import torch

    from heightnet.contact_data import load_contact_sequence
    from heightnet.contact_train import load_network

    torch.set_num_threads(1)
    width, height = (int(v) for v in args.size.split("x"))
    folders = sorted(p for p in args.cache.iterdir() if (p / "done.json").is_file())[:args.sequences]
    if not folders:
        print(f"error: no cached sequence in {args.cache}", file=sys.stderr)
        return 2
    net = load_network(args.checkpoint)
    result = compare(net, [load_contact_sequence(f) for f in folders], width, height, args.frames)
    print(f"{result['sequences']} sequences of {args.cache}, {args.frames} frames each, {args.checkpoint}")
    print(format_report(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
