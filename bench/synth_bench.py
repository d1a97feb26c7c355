"""Throughput of the synthetic generator (`heightpipe synth`) on this machine.

    python -m bench.synth_bench [--sequences N] [--frames N] [--quick]

Each row renders and writes a fresh dataset end to end (scene build, RGB pass with the
sun's shadow map, label and background passes, visibility passes, post effects, PNG/JPEG/NPZ
encoding) into a temporary folder and reports frames per second of wall time. Scenes are
forced to clear daytime so every frame really has shadows. A per-pass CPU breakdown of one
frame follows. The load average is printed: on a shared machine other jobs take cores away.

Target (issue 3): >= 5 frames/s at 320x240 with shadows on 2 cores.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

CONFIGS = [
    # label, size, workers, shadows
    ("320x240 shadows", (320, 240), 2, True),
    ("320x240 shadows", (320, 240), 1, True),
    ("320x240 no shadows", (320, 240), 2, False),
    ("640x360 shadows", (640, 360), 2, True),
]


def run_config(size, workers, shadows, sequences, frames) -> tuple[float, float]:
    from synth.sequence import SequenceOptions
    from synth.writer import generate_dataset

    options = SequenceOptions(frames=frames, sizes=(size,), shadows=shadows, time_of_day="day", weather="clear")
    with tempfile.TemporaryDirectory(prefix="synth_bench_") as tmp:
        start = time.perf_counter()
        generate_dataset(Path(tmp), 1234, sequences, options, workers=workers, progress=False)
        wall = time.perf_counter() - start
    return wall, sequences * frames / wall


def pass_breakdown(frames: int = 10) -> dict[str, float]:
    """CPU milliseconds per frame of each stage, one process (LP_NUM_THREADS as set)."""
    from synth.generate import SequenceRenderer
    from synth.render import amodal_groups
    from synth.sequence import SequenceOptions, plan_sequence

    plan = plan_sequence(1234, 0, SequenceOptions(frames=frames, sizes=((320, 240),), time_of_day="day",
                                                  weather="clear"))
    totals: dict[str, float] = {}
    with SequenceRenderer(plan) as seq:
        r = seq.renderer
        seq.frame(0)
        for i in range(frames):
            marks = [time.process_time()]
            tops = r.set_movers(plan.movers, i / plan.options.fps)
            marks.append(time.process_time())
            r.render_rgb()
            marks.append(time.process_time())
            r.render_labels()
            marks.append(time.process_time())
            r.render_amodal(amodal_groups(r.projected_boxes(plan.camera, list(tops)), 320, 240))
            marks.append(time.process_time())
            for name, a, b in zip(("pose movers", "RGB + shadows", "labels + depth", "visibility passes"),
                                  marks, marks[1:]):
                totals[name] = totals.get(name, 0.0) + (b - a) * 1000 / frames
        start = time.process_time()
        for i in range(frames):
            seq.frame(i)
        totals["whole frame (no disk)"] = (time.process_time() - start) * 1000 / frames
    return totals


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sequences", type=int, default=4)
    parser.add_argument("--frames", type=int, default=25)
    parser.add_argument("--quick", action="store_true", help="only the 2-worker 320x240 shadows row")
    args = parser.parse_args(argv)
    print(f"load average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}  cores: {os.cpu_count()}")
    print(f"{'config':<22}{'workers':>8}{'frames':>8}{'wall s':>9}{'frames/s':>10}")
    configs = CONFIGS[:1] if args.quick else CONFIGS
    for label, size, workers, shadows in configs:
        wall, fps = run_config(size, workers, shadows, args.sequences, args.frames)
        print(f"{label:<22}{workers:>8}{args.sequences * args.frames:>8}{wall:>9.1f}{fps:>10.2f}", flush=True)
    print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    if not args.quick:
        print("\nCPU ms per frame, one process, 320x240 day with shadows:")
        for name, ms in pass_breakdown().items():
            print(f"  {name:<24}{ms:>7.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
