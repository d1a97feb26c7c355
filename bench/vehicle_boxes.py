"""Vehicle geometry on generator sequences: one outline's box height against the truth.

For every whole vehicle in a synthetic dataset (visible > 90 %, at least 20 px tall, clear of
the frame's edge) the box of ``stages.vehicle_geometry`` is fitted to

* its true mask (the generator's instance mask): what the geometry can do with a perfect outline;
* the outline of the detection the pipeline made of it (shipped network, background model; the
  detection that overlaps its box at IoU >= 0.5 and is whole): what it does in a run;

and, for that detection, the foot/top height is listed beside it (what vehicles read before).
Per class: readings, median error and median |error| (cm). ``--picture`` draws the fitted boxes
(footprint green, roof red, the roof at the truth's height cyan) on crops of the detections' frames.

    python -m bench.vehicle_boxes data/trk_val20 [--split all] [--every 2] [--picture docs/vehicle_boxes.png]
"""

from __future__ import annotations

import argparse
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from core.packets import BOX, GEOMETRY

WHOLE_VISIBILITY = 0.9
MIN_BOX_PX = 20
EDGE_PX = 2
PICTURE_TILES = 6


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", help="synthetic dataset folder (manifest.json)")
    parser.add_argument("--split", choices=("test", "train", "all"), default="test")
    parser.add_argument("--every", type=int, default=1, help="every Nth frame is measured (all run)")
    parser.add_argument("--picture", help="PNG of fitted boxes on detection crops")
    args = parser.parse_args(argv)

    from synth.dataset import list_sequences

    sequences = list_sequences(Path(args.data), split=None if args.split == "all" else args.split)
    if not sequences:
        print(f"no {args.split} sequences in {args.data}", file=sys.stderr)
        return 1
    readings: dict[str, list[tuple[float, float, float, float]]] = defaultdict(list)
    tiles: list[np.ndarray] = []
    for sequence in sequences:
        for cls, truth, true_mask, detection, frame, camera in _vehicles(sequence, args.every):
            readings[cls].append((truth, true_mask, detection.height(BOX) if detection else np.nan,
                                  detection.height(GEOMETRY) if detection else np.nan))
            if args.picture and detection is not None and BOX in detection.heights \
                    and len(tiles) < PICTURE_TILES and len(readings[cls]) % 7 == 1:
                tiles.append(_tile(frame, camera, detection, truth))
        print(f"  {sequence.name}: {sum(len(r) for r in readings.values())} vehicle outlines so far", file=sys.stderr)
    print(format_table(readings))
    if args.picture and tiles:
        _save_picture(tiles, Path(args.picture))
    return 0


def _vehicles(sequence, every: int):
    """(class, true height, box height on the true mask, matched detection or None, rgb, camera)."""
    from core.config import load_config
    from pipeline.eval_metrics import matched_at_iou
    from pipeline.eval_sequences import build_eval_chain, prime_sequence_background, sequence_packets
    from stages.vehicle_geometry import vehicle_box

    config = load_config(None)
    chain = build_eval_chain(sequence, config, "model", geometry=True).without("tracking")
    prime_sequence_background(sequence, chain, config)
    for truth_frame, packet in sequence_packets(sequence, chain):
        index = packet.frame.index
        if index % every:
            continue
        height, width = truth_frame.instance.shape
        whole = []
        for o in sequence.objects(index):
            if o.cls not in ("car", "van", "truck", "bus") or o.visible_fraction < WHOLE_VISIBILITY \
                    or o.box[3] < MIN_BOX_PX:
                continue
            rows, cols = np.nonzero(truth_frame.instance == o.id)
            if rows.size == 0 or cols.min() < EDGE_PX or rows.min() < EDGE_PX \
                    or cols.max() >= width - EDGE_PX or rows.max() >= height - EDGE_PX:
                continue
            whole.append((o, rows, cols))
        if not whole:
            continue
        detections = [d for d in packet.detections if not (d.touches_border or d.top_cut or d.foot_cut)]
        matched = dict(matched_at_iou([o.box for o, _, _ in whole], [d.box for d in detections])) if detections else {}
        for i, (o, rows, cols) in enumerate(whole):
            mask = (truth_frame.instance == o.id)[rows.min():rows.max() + 1, cols.min():cols.max() + 1]
            fitted = vehicle_box(packet.camera, mask, (float(cols.min()), float(rows.min())))
            detection = detections[matched[i]] if i in matched else None
            yield (o.cls, float(o.height_m), fitted.height_m if fitted else np.nan, detection,
                   truth_frame.rgb, packet.camera)


def format_table(readings: dict[str, list[tuple[float, float, float, float]]]) -> str:
    lines = ["| class | outlines | true mask: box median / median abs error (cm) | pipeline outline: box readings | "
             "box median / median abs (cm) | foot/top on the same detections: median / median abs (cm) |",
             "|---|---|---|---|---|---|"]
    groups = dict(readings)
    groups["all"] = [r for rows in readings.values() for r in rows]
    for cls in [c for c in ("car", "van", "truck", "bus") if c in groups] + ["all"]:
        data = np.array(groups[cls], dtype=float).reshape(-1, 4)
        truth = data[:, 0]
        cells = []
        for column in (1, 2, 3):
            error = data[:, column] - truth
            error = error[np.isfinite(error)]
            cells.append((len(error), f"{100 * np.median(error):+.1f} / {100 * np.median(np.abs(error)):.1f}"
                          if error.size else "-"))
        lines.append(f"| {cls} | {len(data)} | {cells[0][1]} | {cells[1][0]} | {cells[1][1]} | {cells[2][1]} |")
    return "\n".join(lines)


def _tile(rgb: np.ndarray, camera, detection, truth_m: float) -> np.ndarray:
    """A crop around the detection with its box's footprint and roof drawn, 4x."""
    import cv2

    from stages.calibration import project_points
    from stages.vehicle_geometry import CONSTANTS, vehicle_box

    fitted = vehicle_box(camera, detection.outline, (detection.box[0], detection.box[1]))
    image = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR).copy()
    along = np.array(fitted.axis_xy)
    across = np.array([-along[1], along[0]])
    centre = np.array(fitted.centre_xy_m)
    half = np.array([fitted.length_m, fitted.width_m]) / 2.0
    roof = half * np.asarray(CONSTANTS.car_roof_share) if fitted.length_m < CONSTANTS.car_max_length_m else half

    def outline(extent, z):
        corners = [centre + a * extent[0] * along + b * extent[1] * across
                   for a, b in ((1, 1), (1, -1), (-1, -1), (-1, 1))]
        return project_points(camera, np.column_stack([np.array(corners), np.full(4, z)]))

    # The footprint where its points were taken (body_clearance_m up), the roof at the box's height
    # and at the truth's.
    for extent, z, colour in ((half, CONSTANTS.body_clearance_m, (0, 200, 0)), (roof, truth_m, (255, 255, 0)),
                              (roof, fitted.height_m, (0, 0, 255))):
        cv2.polylines(image, [np.round(outline(extent, z) * 8).astype(np.int32)], True, colour, 1, shift=3)
    x, y, w, h = (int(v) for v in detection.box)
    crop = image[max(0, y - 12):y + h + 12, max(0, x - 12):x + w + 12]
    crop = cv2.resize(crop, None, fx=4, fy=4, interpolation=cv2.INTER_NEAREST)
    cv2.putText(crop, f"box {fitted.height_m:.2f} m, truth {truth_m:.2f} m", (4, 14), cv2.FONT_HERSHEY_SIMPLEX,
                0.45, (255, 255, 255), 1, cv2.LINE_AA)
    return crop


def _save_picture(tiles: list[np.ndarray], path: Path) -> None:
    import cv2

    height = max(t.shape[0] for t in tiles)
    width = max(t.shape[1] for t in tiles)
    padded = [np.pad(t, ((0, height - t.shape[0]), (0, width - t.shape[1]), (0, 0))) for t in tiles]
    while len(padded) % 3:
        padded.append(np.zeros_like(padded[0]))
    rows = [np.hstack(padded[i:i + 3]) for i in range(0, len(padded), 3)]
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), np.vstack(rows))
    print(f"picture: {path}", file=sys.stderr)


if __name__ == "__main__":
    sys.exit(main())
