"""Memory over a long run: `heightpipe run` on looped video, resident memory every few minutes.

    python -m bench.soak_bench [--minutes 30] [--every 5] [--clip CLIP]

The clip (default: the shipped sample) is repeated, by copying its packets into /tmp, until it
lasts ``--minutes`` of video; the whole pipeline runs over it with all three outputs on, and
the table prints the process's resident memory (VmRSS) at every ``--every`` minutes of video,
with the wall time, the frames/s so far and the output sizes then. The verdict compares the
last reading with the one at ``--every`` minutes (the first one after start-up): flat means
within 10 %.

The looped file stands for a camera that runs for hours, so the .rrd is written as a live
stream's is: without rerun's index (``output.rrd_index = "off"``), whose manifest grows by
~2 MB per minute of video until the file is closed. ``--set output.rrd_index=on`` measures a
file's run with the index instead; the header line says which was measured.
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

from bench.clips import SAMPLE, looped_clip

FLAT_SHARE = 0.10


def rss_mb() -> float:
    """This process's resident memory now (VmRSS), in MB."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


class RssReadings:
    """The process's RSS at every ``every_min`` minutes of video, once each (``on_frame`` of
    ``run_pipeline``): rows of (video min, wall s, frames/s so far, RSS MB, frames)."""

    def __init__(self, fps: float, every_min: float):
        self.frames_per_reading = max(1, round(every_min * 60.0 * fps))
        self.fps = fps
        self.rows: list[tuple[float, float, float, float, int]] = []

    def on_frame(self, frames: int, _total: int | None, elapsed_s: float) -> None:
        # ``frames`` counts frames written: it stands still (at 0 at the start, too) while the
        # tracker holds frames back to backfill a new track, so one count may come several times.
        if not frames or frames % self.frames_per_reading or (self.rows and frames <= self.rows[-1][4]):
            return
        self.rows.append((frames / self.fps / 60.0, elapsed_s, frames / elapsed_s, rss_mb(), frames))
        print(f"  {self.rows[-1][0]:.1f} min of video: RSS {self.rows[-1][3]:.0f} MB", flush=True)


def main() -> None:
    import cv2

    from core.config import load_config
    from pipeline.runner import run_pipeline

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clip", type=Path, default=SAMPLE)
    parser.add_argument("--minutes", type=float, default=30.0, help="minutes of (looped) video")
    parser.add_argument("--every", type=float, default=5.0, help="minutes of video between readings")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE")
    parser.add_argument("--tmp", type=Path, default=Path(tempfile.gettempdir()) / "heightpipe-bench")
    args = parser.parse_args()

    args.tmp.mkdir(parents=True, exist_ok=True)
    clip = looped_clip(args.clip, args.minutes, args.tmp)
    capture = cv2.VideoCapture(str(clip))
    fps = capture.get(cv2.CAP_PROP_FPS) or 15.0
    capture.release()
    config = load_config(None, args.overrides)
    if not any(o.startswith("output.rrd_index=") for o in args.overrides):
        config.output.rrd_index = "off"  # as for a live stream (see the docstring)
    config.output.progress = False
    config.output.rerun = "save"
    config.output.mcap = config.output.csv = True
    readings = RssReadings(fps, args.every)

    with tempfile.TemporaryDirectory() as out_dir:
        prefix = Path(out_dir) / "soak"

        print(f"clip: {clip} ({fps:g} frames/s), {args.minutes:g} min of video; .rrd index "
              f"{config.output.rrd_index}; load average {os.getloadavg()[0]:.1f} at the start", flush=True)
        summary = run_pipeline(str(clip), config, prefix, on_frame=readings.on_frame)
        sizes = {name: path.stat().st_size / 1e6 for name, path in
                 (("mcap", summary.outputs.mcap), ("rrd", summary.outputs.rrd))}

    print()
    print("| video min | wall s | frames/s so far | RSS MB |")
    print("|---|---|---|---|")
    for video_min, wall_s, so_far, rss, _ in readings.rows:
        print(f"| {video_min:.1f} | {wall_s:.0f} | {so_far:.1f} | {rss:.0f} |")
    video_h = summary.frames / fps / 3600.0
    print()
    print(f"frames: {summary.frames}; MCAP {sizes['mcap'] / 1e3 / video_h:.2f} GB/h, "
          f".rrd {sizes['rrd'] / 1e3 / video_h:.2f} GB/h of video; load average {os.getloadavg()[0]:.1f} at the end")
    rows = readings.rows
    if len(rows) >= 2:
        first, last = rows[0][3], rows[-1][3]
        change = (last - first) / first
        verdict = "flat" if abs(change) <= FLAT_SHARE else "NOT flat"
        print(f"RSS from {rows[0][0]:.0f} to {rows[-1][0]:.0f} min: {first:.0f} -> {last:.0f} MB "
              f"({change:+.1%}): {verdict} (within {FLAT_SHARE:.0%})")


if __name__ == "__main__":
    main()
