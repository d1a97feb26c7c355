"""The camera a run told only its height ends with: the heads alone, and sharpened by the scene's lines.

    python -m bench.camera_edges DATA [DATA ...] [--model v2] [--frames 0 | --as-run] [--per-sequence] [--mirror]

For each generator sequence (every frame, as ``heightpipe run --camera-height H`` sees it), the
v2 network's camera heads are averaged as a run averages them (``stages/contact_heights.py``),
once alone and once with the scene's straight lines (``stages/vertical_edges.py``: vertical
edges and parallel ground lines; what ``heightpipe calibrate --camera-height`` reads), and both
final cameras are compared with the true one: pitch and roll error (degrees), focal length
error (%), horizon error (% of the image height), and the error of a 1.70 m pole stood on 81
ground points across the image, foot and top projected with the true camera and measured back
with the estimated one (cm; what a person standing there would be off by before any error of
the network's offsets or boxes). Also: the share of sequences the lines were used on, and how
often the truth lies within the reported ±1 std (68 % if honest). One table of medians per
dataset; ``--per-sequence`` prints each sequence too. ``--as-run`` reads the frames a file run
told only the height reads before its first frame (``[camera] read_scene_frames`` spread over
``read_scene_s``: all 60 frames of a generator sequence at 10 frames/s) instead of the first ``--frames``.
``--mirror`` reads each frame with its mirror image, as a run with ``height.mirror`` does.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

POLE_M = 1.70


@dataclass
class CameraError:
    pitch_deg: float
    roll_deg: float
    focal_pct: float
    horizon_pct: float
    pole_cm: float
    within_std: tuple[bool, bool, bool]
    edges: int


def pole_error_cm(true_camera, estimate, width: int, height: int) -> float:
    """Median error (cm) of 1.70 m poles on a 9 x 9 grid of ground points over the image, seen by
    ``true_camera`` and measured by ``estimate`` (both ``CameraInfo``); a pole the estimate cannot
    measure (its foot above the estimate's horizon) counts as wholly wrong."""
    from stages.calibration import heights_from_foot_top, pixel_to_ground, project_points

    us, vs = np.meshgrid(np.linspace(0.1 * width, 0.9 * width, 9), np.linspace(0.35 * height, 0.95 * height, 9))
    foot = np.column_stack([us.ravel(), vs.ravel()])
    ground = pixel_to_ground(true_camera, foot)
    ok = np.all(np.isfinite(ground), axis=1)
    top = project_points(true_camera, np.column_stack([ground[ok], np.full(ok.sum(), POLE_M)]))
    inside = np.all(np.isfinite(top), axis=1) & (top[:, 1] >= 0)
    if not inside.any():
        return float("nan")
    measured, _ = heights_from_foot_top(estimate, foot[ok][inside], top[inside])
    error = np.abs(measured - POLE_M)
    error[~np.isfinite(error)] = POLE_M
    return float(np.median(error) * 100)


def camera_error(true_camera, used, width: int, height: int) -> CameraError:
    """``used`` (the run's ``HeightCamera``) against the sequence's true ``CameraInfo``."""
    from core.packets import CameraInfo
    from stages.calibration import angles_from_rotation, camera_from_pose

    pitch, roll, yaw = angles_from_rotation(true_camera.R)
    focal = float(true_camera.K[1, 1])
    estimate_K = np.array([[used.focal_px, 0, (width - 1) / 2], [0, used.focal_px, (height - 1) / 2], [0, 0, 1]])
    estimate: CameraInfo = camera_from_pose(width, height, estimate_K, used.height_m, used.pitch_deg,
                                            used.roll_deg, yaw)
    horizon = lambda p, f: f * math.tan(math.radians(p))  # noqa: E731 - distance above the centre
    log_focal_std = math.log1p(used.focal_std_pct / 100)
    return CameraError(
        pitch_deg=abs(used.pitch_deg - pitch), roll_deg=abs(used.roll_deg - roll),
        focal_pct=abs(used.focal_px / focal - 1) * 100,
        horizon_pct=abs(horizon(used.pitch_deg, used.focal_px) - horizon(pitch, focal)) / height * 100,
        pole_cm=pole_error_cm(true_camera, estimate, width, height),
        within_std=(abs(used.pitch_deg - pitch) <= used.pitch_std_deg,
                    abs(used.roll_deg - roll) <= used.roll_std_deg,
                    abs(math.log(used.focal_px / focal)) <= log_focal_std),
        edges=used.edges)


def sequence_cameras(sequence, model, correlation, spread, max_frames: int = 0, as_run: bool = False):
    """The final ``HeightCamera`` of a heads-only and of an edge-sharpened run over ``sequence``
    (its first ``max_frames``, or with ``as_run`` the frames a run told only the height reads)."""
    import cv2

    from core.config import load_config
    from pipeline.eval_sequences import camera_info
    from stages.capture import background_indices
    from stages.contact_heights import ContactHeights

    told = camera_info(sequence, known="height")
    alone = ContactHeights(spread_scale=spread, error_correlation=correlation, vertical_edges=False)
    sharpened = ContactHeights(spread_scale=spread, error_correlation=correlation, vertical_edges=True)
    count = len(sequence) if max_frames <= 0 else min(max_frames, len(sequence))
    indices = range(count)
    if as_run:
        reading = load_config(None).camera    # config.toml's, as the run reads it
        indices = background_indices(len(sequence), sequence.meta.fps, reading.read_scene_frames,
                                     reading.read_scene_s)
    for index in indices:
        image = cv2.cvtColor(sequence.frame(index).rgb, cv2.COLOR_RGB2BGR)
        output = model.run(image)
        heads = alone.heads_camera(output, told, image)
        edges = sharpened.heads_camera(output, told, image)
    return heads, edges


def summary_row(name: str, errors: list[CameraError]) -> str:
    def median(key):
        return float(np.nanmedian([getattr(e, key) for e in errors]))

    within = np.mean([e.within_std for e in errors], axis=0) * 100
    used = np.mean([e.edges > 0 for e in errors]) * 100
    return (f"| {name} | {len(errors)} | {used:.0f} | {median('pitch_deg'):.2f} | {median('roll_deg'):.2f} | "
            f"{median('focal_pct'):.1f} | {median('horizon_pct'):.2f} | {median('pole_cm'):.1f} | "
            f"{within[0]:.0f} / {within[1]:.0f} / {within[2]:.0f} |")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.camera_edges", description=__doc__.split("\n\n")[0])
    parser.add_argument("data", nargs="+", help="generator datasets (heightpipe synth)")
    parser.add_argument("--model", default="v2", help="v2 model (a name or an ONNX file)")
    parser.add_argument("--frames", type=int, default=0, help="frames per sequence (0 = all)")
    parser.add_argument("--as-run", action="store_true",
                        help="the frames a run told only the height reads its camera from (not the first --frames)")
    parser.add_argument("--per-sequence", action="store_true")
    parser.add_argument("--mirror", action="store_true",
                        help="each frame read with its mirror image, averaged (a run's height.mirror)")
    args = parser.parse_args(argv)

    from core.errors import HeightpipeError
    from pipeline.eval_sequences import camera_info
    from stages.heightnet_model import HeightNetModel
    from synth.dataset import list_sequences

    try:
        model = HeightNetModel(args.model, mirror=args.mirror)
    except HeightpipeError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if not model.info.contact:
        print(f"error: {args.model} is not a HeightNet v2 (ground-contact) model", file=sys.stderr)
        return 2
    for folder in args.data:
        if not (Path(folder) / "manifest.json").is_file():
            print(f"error: {folder} is not a generator dataset (no manifest.json)", file=sys.stderr)
            return 2
    correlation = np.array(model.info.camera_error_correlation)
    rows = []
    for folder in args.data:
        results = {"heads": [], "heads + lines": []}
        for sequence in list_sequences(folder):
            true_camera = camera_info(sequence)
            heads, edges = sequence_cameras(sequence, model, correlation, model.info.camera_spread_scale, args.frames,
                                            args.as_run)
            for label, used in (("heads", heads), ("heads + lines", edges)):
                results[label].append(camera_error(true_camera, used, true_camera.width, true_camera.height))
            if args.per_sequence:
                a, b = results["heads"][-1], results["heads + lines"][-1]
                print(f"{sequence.name}: {b.edges} lines; pitch {a.pitch_deg:.2f} -> {b.pitch_deg:.2f} deg, "
                      f"roll {a.roll_deg:.2f} -> {b.roll_deg:.2f}, focal {a.focal_pct:.1f} -> {b.focal_pct:.1f} %, "
                      f"pole {a.pole_cm:.1f} -> {b.pole_cm:.1f} cm", flush=True)
        rows += [summary_row(f"{Path(folder).name}, {label}", errors) for label, errors in results.items()]
    print("| data, camera | sequences | lines used (%) | pitch (deg) | roll (deg) | focal (%) | horizon (%) | "
          "1.70 m pole (cm) | truth within ±1 std: pitch / roll / focal (%) |")
    print("|---|---|---|---|---|---|---|---|---|")
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
