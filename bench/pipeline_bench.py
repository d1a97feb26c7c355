"""End-to-end speed of `heightpipe run` against OpenCV's decode-only speed of the same clip.

    python -m bench.pipeline_bench [CLIP] [--frames N] [--model PATH] [--set SECTION.KEY=VALUE ...]

Runs the whole pipeline in-process (capture, every stage, rerun + MCAP + CSV sinks all on,
writing to a temporary folder) over a 640x360 clip and prints one table: decode-only
frames/s, pipeline frames/s, their ratio, the CPU a frame costs over all threads (and the
frames/s that caps on this machine's cores), and the milliseconds each stage takes per frame.
The default clip is the shipped sample if it is 640x360, else the real traffic clip.
Model loading and start-up are excluded: they happen once per run, not per frame.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import cv2

REPO_ROOT = Path(__file__).resolve().parent.parent
CANDIDATE_CLIPS = [REPO_ROOT / "recordings" / "sample.mp4",
                   REPO_ROOT.parent / "shared" / "real" / "traffic_bridge" / "car_traffic_small.mp4"]
TARGET_FPS = 15.0


def default_clip() -> Path:
    for clip in CANDIDATE_CLIPS:
        capture = cv2.VideoCapture(str(clip))
        size = (int(capture.get(cv2.CAP_PROP_FRAME_WIDTH)), int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT)))
        capture.release()
        if size == (640, 360):
            return clip
    raise SystemExit("no 640x360 clip found: pass one")


@dataclass
class CpuClock:
    """The process's CPU time (every thread's) over the frames processed after the first.

    Stage times are wall times on their own threads, which overlap; CPU per frame says what a
    frame costs the machine, and the cores divided by it the most frames/s they can give: when
    the run comes close to that ceiling it is the CPU, not one thread, that holds it back.
    Pass ``on_frame`` to ``run_pipeline`` (called once per processed frame); start-up (loading,
    priming) comes before the first call and is left out.
    """

    clock: Callable[[], float] = time.process_time
    first: float | None = None
    last: float | None = None
    calls: int = 0

    def on_frame(self, *_) -> None:
        now = self.clock()
        self.first = now if self.first is None else self.first
        self.last, self.calls = now, self.calls + 1

    def ms_per_frame(self) -> float:
        if self.calls < 2:
            return float("nan")
        return (self.last - self.first) * 1000.0 / (self.calls - 1)


def decode_fps(clip: Path, frames: int) -> float | None:
    """OpenCV's FFmpeg decode rate over the clip's first ``frames``; None where it reads none
    (an image folder, a source only the pipeline's own capture opens)."""
    capture = cv2.VideoCapture(str(clip), cv2.CAP_FFMPEG)
    count, start = 0, time.perf_counter()
    while count < frames and capture.read()[0]:
        count += 1
    capture.release()
    return count / (time.perf_counter() - start) if count else None


def main(argv: list[str] | None = None) -> None:
    from core.config import load_config
    from core.errors import HeightpipeError
    from pipeline.runner import run_pipeline
    from stages.heightnet_model import cores

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("clip", nargs="?", type=Path)
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--model", default="", help="ONNX model (default: config.toml's height.model)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                        help="config override (repeatable), e.g. camera.height_m=6.4 for a v2 model")
    args = parser.parse_args(argv)
    clip = args.clip or default_clip()

    try:
        config = load_config(None, args.overrides)
    except HeightpipeError as exc:
        raise SystemExit(f"pipeline_bench: {exc}") from None
    config.capture.max_frames = args.frames
    config.output.progress = False
    config.output.rerun = "save"
    config.output.mcap = config.output.csv = True
    if args.model:
        config.height.model = args.model
    decode = decode_fps(clip, args.frames)
    cpu = CpuClock()
    with tempfile.TemporaryDirectory() as tmp:
        try:
            summary = run_pipeline(str(clip), config, Path(tmp) / "bench", on_frame=cpu.on_frame)
        except HeightpipeError as exc:
            raise SystemExit(f"pipeline_bench: {exc}") from None
    if summary.frames == 0 or summary.fps <= 0:
        raise SystemExit(f"pipeline_bench: no frame of {clip} was processed")
    cpu_ms = cpu.ms_per_frame()

    print(f"clip: {clip} ({summary.frames} frames)")
    print()
    print("| measure | value |")
    print("|---|---|")
    decoded = "not measured (OpenCV reads no frame of it as one video)" if decode is None else f"{decode:.1f} frames/s"
    print(f"| OpenCV decode only | {decoded} |")
    print(f"| heightpipe run, all sinks on | {summary.fps:.1f} frames/s |")
    print(f"| ratio run / decode | {'-' if decode is None else f'{summary.fps / decode:.3f}'} |")
    print(f"| CPU per frame, all threads | {cpu_ms:.1f} ms |")
    print(f"| ceiling on {cores()} cores (cores / CPU per frame) | {1000.0 * cores() / cpu_ms:.1f} frames/s |")
    print(f"| target | >= {TARGET_FPS:.0f} frames/s: {'met' if summary.fps >= TARGET_FPS else 'NOT met'} |")
    print()
    total = summary.total_ms_per_frame()
    print("| stage | ms per frame | share |")
    print("|---|---|---|")
    for name, per_frame in summary.ms_per_frame().items():
        print(f"| {name} | {per_frame:.1f} | {per_frame / total:.0%} |")
    wall = 1000.0 / summary.fps
    print(f"| all stages | {total:.1f} | |")
    print(f"| wall time per frame | {wall:.1f} | |")
    if config.run.overlapped:
        # The network's thread and the caller's run side by side: their sum is not a frame's wall time.
        print(f"| stages run side by side (overlapped): their sum minus the wall time | {total - wall:.1f} | |")
    else:
        print(f"| capture (decode) and loop overhead | {wall - total:.1f} | |")
    print()
    print("The height network (both heads) runs once per frame inside the 'ground' stage; "
          "'height' only rescales its cached output.")


if __name__ == "__main__":
    main()
