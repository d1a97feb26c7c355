"""Real-time headroom of `heightpipe run`: frames/s by resolution, cameras, threading and model.

    python -m bench.realtime_bench [--sizes 640x360,1920x1080] [--cameras 1,2]
                                   [--modes sequential,overlapped] [--int8 MODEL.onnx] [--frames N]

Every configuration runs the whole pipeline with all three outputs on (rerun .rrd, MCAP, CSV,
into a temporary folder), each camera in its own fresh process (as `heightpipe run SRC1 SRC2`
does), so peak RSS is that process's own. Two cameras are two copies of the clip run at once.
Prints one table: frames/s per camera (the slower camera), the per-stage milliseconds, peak
RSS, and MCAP / .rrd megabytes per minute of video. The 1920x1080 clip is the sample upscaled
into /tmp. The load average at the start of each row is printed with it: on a shared machine
it says how much the numbers are worth.
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import resource
import tempfile
from pathlib import Path

from bench.clips import add_clip_arguments, upscaled_clip

STAGE_ORDER = ("undistortion", "ground", "height", "keypoints", "matching", "objects", "geometry",
               "tracking", "rerun", "mcap", "csv")


def measure_camera(clip: str, overrides: list[str], out_dir: str, results) -> None:
    """One camera's run, in its own process; puts a dict of measurements on ``results``."""
    import cv2

    from core.config import load_config
    from pipeline.runner import run_pipeline

    config = load_config(None, overrides)
    config.output.progress = False
    prefix = Path(out_dir) / "bench"
    summary = run_pipeline(clip, config, prefix)
    capture = cv2.VideoCapture(clip)
    fps = capture.get(cv2.CAP_PROP_FPS) or 15.0
    capture.release()
    video_min = summary.frames / fps / 60.0
    outputs = summary.outputs
    results.put({
        "fps": summary.fps,
        "frames": summary.frames,
        "stage_ms": summary.ms_per_frame(),
        "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        "mcap_mb_min": outputs.mcap.stat().st_size / 1e6 / video_min,
        "rrd_mb_min": outputs.rrd.stat().st_size / 1e6 / video_min,
        "dropped": summary.dropped_frames,
    })


def measure(clip: Path, cameras: int, overrides: list[str]) -> list[dict]:
    """Runs ``cameras`` copies of the clip at once, one process each; their measurements."""
    context = multiprocessing.get_context("spawn")
    results = context.Queue()
    with tempfile.TemporaryDirectory() as tmp:
        processes = []
        for camera in range(cameras):
            out_dir = Path(tmp) / f"camera{camera}"
            out_dir.mkdir()
            processes.append(context.Process(target=measure_camera,
                                             args=(str(clip), overrides, str(out_dir), results)))
        for process in processes:
            process.start()
        measured = [results.get() for _ in processes]
        for process in processes:
            process.join()
    return measured


def _row(size: str, cameras: int, mode: str, model: str, load: float, runs: list[dict]) -> str:
    slowest = min(runs, key=lambda run: run["fps"])
    stages = " ".join(f"{name} {slowest['stage_ms'][name]:.1f}" for name in STAGE_ORDER
                      if name in slowest["stage_ms"])
    return (f"| {size} | {cameras} | {mode} | {model} | {slowest['fps']:.1f} | {stages} | "
            f"{max(run['rss_mb'] for run in runs):.0f} | {slowest['mcap_mb_min']:.1f} | "
            f"{slowest['rrd_mb_min']:.1f} | {load:.1f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_clip_arguments(parser)
    parser.add_argument("--cameras", default="1,2")
    parser.add_argument("--modes", default="sequential,overlapped")
    parser.add_argument("--int8", default="", metavar="MODEL", help="also measure this (INT8) ONNX model")
    args = parser.parse_args()

    args.tmp.mkdir(parents=True, exist_ok=True)
    models = [("fp32", "")] + ([("int8", args.int8)] if args.int8 else [])
    print(f"clip: {args.clip}; {os.cpu_count()} CPUs; all outputs on (rerun save, MCAP, CSV)")
    print()
    print("| size | cameras | mode | model | frames/s per camera | ms per frame (slowest camera) "
          "| peak RSS MB per camera | MCAP MB/min | .rrd MB/min | load avg |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for size in args.sizes.split(","):
        width, height = (int(v) for v in size.split("x"))
        clip = args.clip if (width, height) == (640, 360) else upscaled_clip(args.clip, width, height, args.tmp)
        for cameras in (int(c) for c in args.cameras.split(",")):
            for mode in args.modes.split(","):
                for model_name, model_path in models:
                    overrides = [f"run.overlapped={'true' if mode == 'overlapped' else 'false'}",
                                 f'height.model="{model_path}"', 'output.rerun="save"',
                                 "output.mcap=true", "output.csv=true",
                                 f"capture.max_frames={args.frames}", *args.overrides]
                    if cameras > 1:  # as `heightpipe run SRC1 SRC2` shares the network's threads out
                        overrides.append(f"height.threads={max(1, 2 // cameras)}")
                    load = os.getloadavg()[0]
                    runs = measure(clip, cameras, overrides)
                    print(_row(size, cameras, mode, model_name, load, runs), flush=True)
    print()
    print("frames/s counts from the first frame to the last, model loading and the background "
          "seed excluded; the network runs once per frame in 'ground'.")


if __name__ == "__main__":
    main()
