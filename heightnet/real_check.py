"""Sanity check on real video: are annotated people predicted higher than the ground around them?

Uses the Oxford Town Centre clip and its body boxes (``../shared/real/oxford_towncentre``).
For each annotated person with a whole box inside the frame: the median predicted height over
the torso (middle half of the box width, 15-60% of its height from the top) against the median
over a ring around the box (box grown by 40%, every person box removed). No height accuracy is
claimed here: the synthetic-to-real gap is large and the clip's annotations use one stature.

    python -m heightnet.real_check [--model stages/models/heightnet.onnx] [--every 25]
"""

from __future__ import annotations

import argparse
import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from heightnet.predict import HeightPredictor, iter_inputs
from stages.heightnet_model import SHIPPED_MODEL

OXFORD = Path(__file__).resolve().parents[2] / "shared" / "real" / "oxford_towncentre"
OXFORD_CAMERA_HEIGHT_M = 7.84


@dataclass
class PersonCheck:
    frame: int
    person: int
    torso_m: float
    around_m: float


def load_boxes(labels_csv: Path) -> dict[int, list[tuple[int, np.ndarray]]]:
    boxes: dict[int, list[tuple[int, np.ndarray]]] = {}
    with open(labels_csv, newline="") as f:
        for row in csv.DictReader(f):
            if row["body_valid"] != "1":
                continue
            box = np.array([float(row[k]) for k in ("body_x1", "body_y1", "body_x2", "body_y2")])
            boxes.setdefault(int(row["frame"]), []).append((int(row["person"]), box))
    return boxes


def check_people(predictor: HeightPredictor, video: Path, labels_csv: Path,
                 camera_height_m: float = OXFORD_CAMERA_HEIGHT_M, every: int = 25) -> list[PersonCheck]:
    boxes = load_boxes(labels_csv)
    results = []
    for stem, rgb in iter_inputs(video, every):
        frame = int(stem.rsplit("_", 1)[1])
        if frame not in boxes:
            continue
        height = predictor.predict(rgb, camera_height_m).height_m
        h, w = height.shape
        people = np.zeros((h, w), bool)
        for _, (x1, y1, x2, y2) in boxes[frame]:
            people[max(0, int(y1)):int(y2) + 1, max(0, int(x1)):int(x2) + 1] = True
        for person, (x1, y1, x2, y2) in boxes[frame]:
            if x1 < 0 or y1 < 0 or x2 >= w or y2 >= h:
                continue
            bw, bh = x2 - x1, y2 - y1
            torso = height[int(y1 + 0.15 * bh):int(y1 + 0.6 * bh), int(x1 + 0.25 * bw):int(x2 - 0.25 * bw)]
            gx1, gy1 = max(0, int(x1 - 0.4 * bw)), max(0, int(y1 - 0.4 * bh))
            gx2, gy2 = min(w, int(x2 + 0.4 * bw)), min(h, int(y2 + 0.4 * bh))
            ring = height[gy1:gy2, gx1:gx2][~people[gy1:gy2, gx1:gx2]]
            if torso.size and ring.size:
                results.append(PersonCheck(frame, person, float(np.median(torso)), float(np.median(ring))))
    return results


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="people vs surrounding ground on the Oxford clip")
    parser.add_argument("--model", default=str(SHIPPED_MODEL))
    parser.add_argument("--every", type=int, default=25)
    args = parser.parse_args(argv)
    checks = check_people(HeightPredictor(args.model), OXFORD / "oxford_snipped.mp4",
                          OXFORD / "gt_with_geometry.csv", every=args.every)
    higher = sum(c.torso_m > c.around_m for c in checks)
    print(f"{higher}/{len(checks)} people predicted higher than the ground around them; "
          f"median torso {np.median([c.torso_m for c in checks]):.2f} m, "
          f"median surroundings {np.median([c.around_m for c in checks]):.2f} m")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
