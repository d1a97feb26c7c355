"""CPU time per frame of `heightpipe run`, stage by stage: measurable on a busy machine.

    python -m bench.cpu_bench [--sizes 640x360,1920x1080] [--models fp32,int8] [--cores 2]
                              [--frames N] [--set SECTION.KEY=VALUE ...]

Wall-clock frames/s say little on a shared machine (another job takes the cores); the CPU time
a frame costs hardly depends on the load. So this runs the pipeline sequentially (the order and
the stages of ``pipeline.runner.run_pipeline``, all three outputs on: rerun .rrd, MCAP, CSV, into
a temporary folder) and reads the process's CPU clock (``time.process_time``: every thread of
the process, the network's thread pool and rerun's encoder included) around the capture, every
stage and every sink. It prints one table: CPU ms per frame of each part, the total, and the
frames/s ceiling the total allows on N cores (N x 1000 / total: every core busy, the threaded
run overlapping perfectly). Each configuration runs in a fresh process; model loading, the
background seed and the first frame (the network's warm-up) are excluded, the sinks' closing
(rerun's and MCAP's last flush) is included in the total.

Background threads run while a stage runs, so a stage's figure holds a little of their work
(rerun's encoder thread, the network's pool spinning down); the "other" row is what ran
between the parts (the loop itself). The 1920x1080 clip is the sample upscaled
(``bench.clips.upscaled_clip``).
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import tempfile
import time
from collections import defaultdict
from pathlib import Path

from bench.clips import add_clip_arguments, upscaled_clip

MODELS = {"fp32": "", "int8": "int8"}
"""Model names of the table's columns and their ``height.model`` values."""


def measure(clip: str, overrides: list[str], out_dir: str) -> dict:
    """CPU ms per frame of each part of one sequential run (its own process: ``measure_in_process``)."""
    from contextlib import closing

    from core.config import load_config
    from core.packets import FramePacket
    from pipeline.runner import build_camera, build_sinks, output_paths
    from pipeline.stage_chain import build_stage_chain, close_all
    from stages.capture import open_source

    config = load_config(None, ['output.rerun="save"', "output.mcap=true", "output.csv=true",
                                *overrides, "run.overlapped=false", "output.progress=false"])
    source = open_source(clip, config.capture)
    camera = build_camera(config, *source.size)
    chain = build_stage_chain(config, camera)
    chain.prime(source.background_sample(config.objects.background_prime_frames,
                                         config.objects.background_prime_s))
    prefix = Path(out_dir) / "bench"
    sinks = build_sinks(output_paths(prefix, config), config, prefix.name)
    cpu_ms: dict[str, float] = defaultdict(float)
    frames = 0
    clock = time.process_time
    with closing(source.frames()) as decoded:
        start = clock()
        while True:
            t0 = clock()
            frame = next(decoded, None)
            if frame is None:
                break
            t1 = clock()
            packet = FramePacket(frame=frame, camera=camera)
            parts = {"capture": t1 - t0}
            for name, stage in chain.stages:
                t0 = clock()
                packet = stage.process(packet)
                parts[name] = clock() - t0
            for name, sink in sinks:
                t0 = clock()
                sink.write(packet)
                parts[f"sink {name}"] = clock() - t0
            if frames == 0:      # the first frame warms the network up: start counting after it
                start = clock()
            else:
                for name, seconds in parts.items():
                    cpu_ms[name] += seconds * 1000.0
            frames += 1
    t0 = clock()
    close_all([sink for _, sink in sinks])
    cpu_ms["sinks' close (last flush)"] = (clock() - t0) * 1000.0
    total_ms = (clock() - start) * 1000.0
    close_all([stage for _, stage in chain.stages] + [source])
    counted = max(1, frames - 1)
    cpu_ms["other"] = total_ms - sum(cpu_ms.values())
    return {"frames": counted, "ms": {name: ms / counted for name, ms in cpu_ms.items()},
            "total": total_ms / counted}


def measure_in_process(clip: str, overrides: list[str]) -> dict:
    """``measure`` in a fresh process: no state (OpenCV's generator, caches) carried over."""
    context = multiprocessing.get_context("spawn")
    with tempfile.TemporaryDirectory() as tmp, context.Pool(1) as pool:
        return pool.apply(measure, (clip, overrides, tmp))


def table(columns: dict[str, dict], cores: int) -> str:
    """The markdown table: a row per part (first seen order), the total and the ceiling."""
    names: list[str] = []
    for result in columns.values():
        names += [n for n in result["ms"] if n not in names and n != "other"]
    names.append("other")
    lines = ["| CPU ms per frame | " + " | ".join(columns) + " |",
             "|---|" + "---|" * len(columns)]
    for name in names:
        cells = [f"{result['ms'][name]:.1f}" if name in result["ms"] else "" for result in columns.values()]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines.append("| **total** | " + " | ".join(f"**{r['total']:.1f}**" for r in columns.values()) + " |")
    lines.append(f"| frames/s ceiling on {cores} cores | "
                 + " | ".join(f"{cores * 1000.0 / r['total']:.0f}" for r in columns.values()) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_clip_arguments(parser)
    parser.add_argument("--models", default="fp32,int8", help=f"of {', '.join(MODELS)}")
    parser.add_argument("--cores", type=int, default=2, help="cores the frames/s ceiling assumes")
    args = parser.parse_args()

    args.tmp.mkdir(parents=True, exist_ok=True)
    columns: dict[str, dict] = {}
    for size in args.sizes.split(","):
        width, height = (int(v) for v in size.split("x"))
        clip = args.clip if (width, height) == (640, 360) else upscaled_clip(args.clip, width, height, args.tmp)
        for model in args.models.split(","):
            overrides = [f'height.model="{MODELS[model]}"', f"capture.max_frames={args.frames}", *args.overrides]
            columns[f"{size} {model}"] = measure_in_process(str(clip), overrides)
    frames = ", ".join(f"{name}: {result['frames']}" for name, result in columns.items())
    print(f"clip: {args.clip}; frames counted ({frames}); sequential run, all outputs on; "
          f"overrides: {' '.join(args.overrides) or 'none'}; load avg {os.getloadavg()[0]:.1f}")
    print()
    print(table(columns, args.cores))


if __name__ == "__main__":
    main()
