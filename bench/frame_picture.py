"""A picture of one frame of a run: every confirmed track boxed in its class's colour, with its
class and height; what a reviewer looks at to see whether every vehicle (or person) was found.

Runs ``heightpipe run`` on the video up to the frame (``--max-frames``), as a user would, with
any ``--set`` overrides (another model, ``objects.source=network``), then draws that frame's rows
of ``PREFIX.tracks.csv`` (source pixels) on the video's own frame. Several ``--run LABEL:SETTINGS``
give pictures side by side, one per configuration, over the same frame.

    python -m bench.frame_picture ../shared/real/traffic_bridge/car_traffic_small.mp4 --frame 300 \\
        --out docs/traffic_frame300.jpg [--run "blobs:" --run "network:objects.source=network ..."]
"""

from __future__ import annotations

import argparse
import csv
import subprocess
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

from stages.sink_common import CLASS_COLORS_RGB

ROOT = Path(__file__).resolve().parents[1]


def run_to_frame(video: Path, frame: int, settings: list[str], out: Path) -> Path:
    """``heightpipe run`` over frames 0..frame; returns the tracks CSV."""
    command = [sys.executable, "-m", "pipeline.cli", "run", str(video), "--out", str(out), "--no-progress",
               "--rerun", "off", "--max-frames", str(frame + 1)]
    for setting in settings:
        command += ["--set", setting]
    result = subprocess.run(command, cwd=ROOT, capture_output=True, text=True)
    if result.returncode != 0:
        raise SystemExit(f"bench.frame_picture: the run failed: {result.stderr.strip().splitlines()[-1]}")
    return out.with_name(out.name + ".tracks.csv")


def read_frame(video: Path, frame: int) -> np.ndarray:
    capture = cv2.VideoCapture(str(video))
    image = None
    for _ in range(frame + 1):
        ok, image = capture.read()
        if not ok:
            raise SystemExit(f"bench.frame_picture: {video} has no frame {frame}")
    capture.release()
    return image


def frame_rows(tracks_csv: Path, frame: int) -> list[dict]:
    """The rows of ``tracks_csv`` (confirmed tracks) at ``frame``."""
    with open(tracks_csv, newline="") as f:
        return [row for row in csv.DictReader(f) if int(row["frame"]) == frame]


def draw_tracks(image: np.ndarray, rows: list[dict], frame: int, label: str) -> np.ndarray:
    """The frame with ``rows`` (its tracks.csv rows) boxed and labelled; ``label`` on top."""
    picture = image.copy()
    scale = max(1.0, picture.shape[1] / 640.0)
    for row in rows:
        x, y, w, h = (float(row[key]) for key in "xywh")
        r, g, b = CLASS_COLORS_RGB.get(row["class"], CLASS_COLORS_RGB["other"])
        cv2.rectangle(picture, (int(x), int(y)), (int(x + w), int(y + h)), (b, g, r), max(1, int(2 * scale)))
        height = float(row["height_m"])
        text = f"{row['class']} {height:.2f} m" if np.isfinite(height) else f"{row['class']} -"
        cv2.putText(picture, text, (int(x), max(int(y) - 4, 12)), cv2.FONT_HERSHEY_SIMPLEX, 0.4 * scale,
                    (b, g, r), max(1, int(scale)), cv2.LINE_AA)
    banner = f"{label}: {len(rows)} tracks at frame {frame}"
    cv2.rectangle(picture, (0, 0), (picture.shape[1], int(22 * scale)), (0, 0, 0), -1)
    cv2.putText(picture, banner, (6, int(16 * scale)), cv2.FONT_HERSHEY_SIMPLEX, 0.5 * scale, (255, 255, 255),
                max(1, int(scale)), cv2.LINE_AA)
    return picture


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("video", type=Path)
    parser.add_argument("--frame", type=int, default=300)
    parser.add_argument("--out", type=Path, required=True, help="picture (.jpg or .png)")
    parser.add_argument("--run", action="append", default=[], metavar="LABEL:SETTING[,SETTING...]",
                        help="one picture per run: a label and the --set overrides (default: one run, as configured)")
    args = parser.parse_args()
    if not args.video.is_file():
        raise SystemExit(f"bench.frame_picture: no such video: {args.video}")
    runs = []
    for spec in args.run or ["default:"]:
        label, _, settings = spec.partition(":")
        runs.append((label, [s for s in settings.split(",") if s]))
    image = read_frame(args.video, args.frame)
    panels = []
    with tempfile.TemporaryDirectory() as tmp:
        for index, (label, settings) in enumerate(runs):
            rows = frame_rows(run_to_frame(args.video, args.frame, settings, Path(tmp) / f"run{index}"), args.frame)
            panels.append(draw_tracks(image, rows, args.frame, label))
            print(f"{label}: {len(rows)} confirmed tracks at frame {args.frame}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.out), np.vstack(panels))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
