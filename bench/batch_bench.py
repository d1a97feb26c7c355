"""Throughput of `heightpipe batch` with 1 and 2 workers on this machine, and the scaling ratio.

    python -m bench.batch_bench [--clips N] [--frames N] [--engine local|ray] [--model PATH]

Cuts the real traffic clip (../shared/real, 640x360) into N separate videos (moving-box clips
if it is missing), then runs the whole batch (worker start-up, every stage, all three sinks,
the archive tables) into a fresh folder once with 1 worker and once with 2, and prints
frames/s, hours of video per hour of wall time, and 2-worker / 1-worker throughput: one
worker with 1 ONNX Runtime thread, one worker with 2 (the default on 2 cores), two workers
with 1 each (what the batch picks on 2 cores). On a shared machine other people's jobs take
cores away from the run that meets them: the last column says how many cores, on average,
went to processes other than this benchmark's (system busy time from /proc/stat minus this
process tree's CPU time).
"""

from __future__ import annotations

import argparse
import os
import resource
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

REPO_ROOT = Path(__file__).resolve().parent.parent
REAL_CLIP = REPO_ROOT.parent / "shared" / "real" / "traffic_bridge" / "car_traffic_small.mp4"


def make_clips(folder: Path, clips: int, frames: int) -> list[Path]:
    """N distinct videos: consecutive pieces of the real clip, or synthetic moving boxes."""
    folder.mkdir(parents=True, exist_ok=True)
    source = cv2.VideoCapture(str(REAL_CLIP)) if REAL_CLIP.exists() else None
    rng = np.random.default_rng(0)
    paths = []
    for i in range(clips):
        path = folder / f"clip{i:02d}.mp4"
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 30.0, (640, 360))
        for j in range(frames):
            ok, image = source.read() if source is not None else (False, None)
            if not ok:
                image = (rng.random((360, 640, 3)) * 40).astype(np.uint8)
                x = 20 + j * 560 // max(1, frames - 1)
                cv2.rectangle(image, (x, 120), (x + 40, 240), (255, 255, 255), -1)
            writer.write(image)
        writer.release()
        paths.append(path)
    if source is not None:
        source.release()
    return paths


def busy_cpu_s() -> tuple[float, float]:
    """(CPU seconds busy on the whole machine, CPU seconds used by this process and its children)."""
    fields = [int(v) for v in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    idle = fields[3] + fields[4]  # idle + iowait
    machine = (sum(fields[:8]) - idle) / os.sysconf("SC_CLK_TCK")
    mine = sum(getattr(resource.getrusage(who), name) for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)
               for name in ("ru_utime", "ru_stime"))
    return machine, mine


def run(folder: Path, out: Path, workers: int, threads: int, engine: str, model: str):
    from pipeline.batch import BatchOptions, run_batch
    from core.config import load_config

    config = load_config(None, [])
    config.height.model = model
    config.height.threads = threads  # the batch lowers it to cores // workers where that is less
    config.output.progress = False
    start = time.perf_counter()
    report = run_batch([str(folder)], config, BatchOptions(out_dir=out, engine=engine, workers=workers,
                                                           progress=False))
    wall = time.perf_counter() - start
    if report.failed or report.done == 0:
        raise SystemExit(f"batch failed: {report.failed}")
    return report, wall


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clips", type=int, default=6)
    parser.add_argument("--frames", type=int, default=90, help="frames per clip")
    parser.add_argument("--engine", default="local", choices=["local", "ray"])
    parser.add_argument("--model", default="", help="ONNX model (default: the shipped one)")
    args = parser.parse_args()

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        clips = make_clips(Path(tmp) / "clips", args.clips, args.frames)
        print(f"{len(clips)} clips x {args.frames} frames, 640x360 "
              f"({'pieces of ' + REAL_CLIP.name if REAL_CLIP.exists() else 'synthetic'}), "
              f"engine {args.engine}, {len(os.sched_getaffinity(0))} cores")
        for workers, threads in ((1, 1), (1, 2), (2, 2)):
            machine_before, mine_before = busy_cpu_s()
            report, wall = run(Path(tmp) / "clips", Path(tmp) / f"out{workers}-{threads}", workers, threads,
                               args.engine, args.model)
            machine_after, mine_after = busy_cpu_s()
            others = max(0.0, (machine_after - machine_before) - (mine_after - mine_before)) / wall
            rows.append((workers, report, wall, (mine_after - mine_before) / wall, others))

    print()
    print("| workers | ORT threads each | videos | frames | wall s | frames/s | h video / h wall "
          "| cores used by the batch | cores used by others |")
    print("|---|---|---|---|---|---|---|---|---|")
    for workers, report, wall, mine, others in rows:
        print(f"| {workers} | {report.threads} | {report.done} | {report.frames} | {wall:.1f} | "
              f"{report.frames / wall:.1f} | {report.video_s / wall:.2f} | {mine:.2f} | {others:.2f} |")
    one_thread, one, two = (r[1].frames / r[2] for r in rows)
    print()
    print(f"scaling ratio, 2 workers / 1 worker with 2 ORT threads: {two / one:.2f}")
    print(f"scaling ratio, 2 workers / 1 worker with 1 ORT thread:  {two / one_thread:.2f}")


if __name__ == "__main__":
    main()
