"""The height network alone on real people: its height map inside Oxford's labelled body boxes.

``bench.real_heights`` scores what a run reports, where the tracker fuses the network's heights
with the calibrated geometry of the boxes' ends; a good geometry there hides how far the network
itself is from real footage. This reads the network's height map (v1: network height x camera
height; v2: heights from its ground-contact offsets and the camera) inside each labelled person's
body box, in the calibration file's undistorted frames, with no detection or tracking in between,
so the boxes are the labels' and only the network is measured:

* ``box max``: the highest pixel in the box (what a perfect box would read as its top);
* ``box p99``: the 99th percentile (a few stray pixels aside);
* ``centre p95``: the 95th percentile of the box's middle third of columns (the head is there).

Per model: person-frames (labelled people whose head and feet are both in the frame), the median
signed and absolute error of each reading against the labelled height, and the median ratio of
the box max to it. The clip's labels put everyone near 1.80 m (its README): this measures the
network's scale on real walkers, not individual statures. Nothing here is tuned on these labels.

    python -m bench.network_on_people [--models v1,v2] [--set SECTION.KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass

import numpy as np

from bench.real_heights import CALIBRATION, VIDEO, LabelledPerson, load_labels

LABEL_WIDTH_PX = 1920
"""Oxford's labels are in the source's pixels; the run may work on a downscaled frame."""


@dataclass
class BoxReading:
    """The network's height map inside one labelled person's box in one frame."""

    true_m: float
    max_m: float
    p99_m: float
    centre_p95_m: float


READINGS = (("box max", "max_m"), ("box p99", "p99_m"), ("centre p95", "centre_p95_m"))


def read_box(height_map: np.ndarray, person: LabelledPerson, scale: float) -> BoxReading | None:
    """The height map's readings inside ``person``'s box (source pixels x ``scale`` = map pixels);
    None when the box holds fewer than 4 x 4 map pixels."""
    rows, cols = height_map.shape
    x, y, w, h = np.asarray(person.box, float) * scale
    x0, y0 = max(int(np.floor(x)), 0), max(int(np.floor(y)), 0)
    x1, y1 = min(int(np.ceil(x + w)), cols), min(int(np.ceil(y + h)), rows)
    if x1 - x0 < 4 or y1 - y0 < 4:
        return None
    box = np.nan_to_num(height_map[y0:y1, x0:x1], nan=0.0)
    third = (x1 - x0) // 3
    centre = box[:, third:(x1 - x0) - third]
    return BoxReading(person.height_m, float(box.max()), float(np.percentile(box, 99)),
                      float(np.percentile(centre, 95)))


def summarise(readings: list[BoxReading]) -> dict[str, float]:
    """Median signed and absolute errors (m) of each reading, and the median max / true ratio."""
    true = np.array([r.true_m for r in readings])
    summary: dict[str, float] = {"person_frames": float(len(readings))}
    for label, field in READINGS:
        error = np.array([getattr(r, field) for r in readings]) - true
        summary[f"{label} signed"] = float(np.median(error)) if len(error) else float("nan")
        summary[f"{label} abs"] = float(np.median(np.abs(error))) if len(error) else float("nan")
    summary["max / true"] = float(np.median([r.max_m / r.true_m for r in readings])) if readings else float("nan")
    return summary


def measure(model: str, overrides: list[str]) -> dict[str, float]:
    """One model over the clip: the readings of every labelled person whose head and feet are in view."""
    from core.config import load_config
    from pipeline.overlapped import split_chain
    from pipeline.runner import build_camera
    from pipeline.stage_chain import build_stage_chain, load_height_model
    from stages.capture import open_source

    config = load_config(None, [f"camera.calibration={CALIBRATION}", f"height.model={model}", *overrides])
    source = open_source(str(VIDEO), config.capture)
    camera = build_camera(config, *source.size)
    # Undistortion and the network only: what the network thread of a run does.
    network, _ = split_chain(build_stage_chain(config, camera, model=load_height_model(config)))
    labels = load_labels(undistort=True)
    scale = source.size[0] / LABEL_WIDTH_PX
    readings: list[BoxReading] = []
    try:
        for packet in network.run(source.frames(), camera):
            for person in labels.get(packet.frame.index, []):
                if not person.foot_inside or person.head[1] < 0:
                    continue
                reading = read_box(packet.height_map, person, scale)
                if reading is not None:
                    readings.append(reading)
    finally:
        source.close()
    return summarise(readings)


def format_table(results: dict[str, dict[str, float]]) -> str:
    header = ["model", "person-frames"] + [f"{label} {kind} (cm)" for label, _ in READINGS
                                           for kind in ("signed", "abs")] + ["max / true"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for model, s in results.items():
        cells = [model, f"{s['person_frames']:.0f}"]
        cells += [f"{100 * s[f'{label} {kind}']:.1f}" for label, _ in READINGS for kind in ("signed", "abs")]
        cells.append(f"{s['max / true']:.2f}")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", default="v1,v2", help="comma-separated height.model values")
    parser.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                        help="configuration override for every model's run")
    args = parser.parse_args()
    if not VIDEO.exists():
        print(f"error: {VIDEO} not found (the shared real clips)", file=sys.stderr)
        return 2
    from core.errors import HeightpipeError

    results = {}
    for model in [m.strip() for m in args.models.split(",") if m.strip()]:
        try:
            results[model] = measure(model, args.set)
        except HeightpipeError as error:
            print(f"error: {model}: {error}", file=sys.stderr)
            return 2
    print(f"clip: {VIDEO.name} (calibration file, undistorted); overrides: {' '.join(args.set) or 'none'}\n")
    print(format_table(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
