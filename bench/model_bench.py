"""ONNX Runtime speed of the height network configurations on this CPU.

    python -m bench.model_bench [--threads 2] [--width 320 --height 192] [--shipped] [--model FILE ...]

Prints one row per configuration (config, input size, parameters, ms/frame, frames/s, speed
relative to the paper configuration). Untrained networks are exported to a temporary folder:
speed does not depend on the weights. ``--shipped`` adds the shipped stages/models/heightnet.onnx
and HeightNet v2 (stages/models/heightnet_v2.onnx) where it is exported; ``--model`` any ONNX file.
Timing is the best of several rounds, so other processes on a shared machine inflate it less.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO_ROOT = Path(__file__).resolve().parent.parent
SHIPPED = REPO_ROOT / "stages" / "models" / "heightnet.onnx"
SHIPPED_V2 = REPO_ROOT / "stages" / "models" / "heightnet_v2.onnx"


def time_onnx(path: Path, threads: int, rounds: int, runs: int) -> tuple[float, int, int]:
    """Best mean seconds per frame over ``rounds`` of ``runs`` frames; also the input size. A free
    input size (a v2 export) runs at the size its metadata names, fixed as the run time fixes it;
    every input (a motion-reading v2 head also takes the frame before) gets the same image."""
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    _, _, height, width = session.get_inputs()[0].shape
    if not isinstance(width, int) or not isinstance(height, int):
        metadata = session.get_modelmeta().custom_metadata_map
        free = {height: int(metadata["heightpipe.input_height"]), width: int(metadata["heightpipe.input_width"])}
        for name, size in free.items():
            options.add_free_dimension_override_by_name(name, size)
        session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        height, width = free[height], free[width]
    image = np.random.default_rng(0).standard_normal((1, 3, height, width)).astype(np.float32)
    feed = {given.name: image for given in session.get_inputs()}
    for _ in range(2):
        session.run(None, feed)
    best = float("inf")
    for _ in range(rounds):
        start = time.perf_counter()
        for _ in range(runs):
            session.run(None, feed)
        best = min(best, (time.perf_counter() - start) / runs)
    return best, width, height


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--width", type=int, default=320)
    parser.add_argument("--height", type=int, default=192)
    parser.add_argument("--configs", default="light,paper")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--shipped", action="store_true", help="also time the shipped models")
    parser.add_argument("--model", action="append", default=[], type=Path, metavar="FILE",
                        help="also time this ONNX file (repeatable)")
    parser.add_argument("--no-configs", action="store_true", help="time only --shipped / --model files")
    args = parser.parse_args(argv)

    import torch

    from heightnet.export import export_model
    from heightnet.model import build_model, count_parameters

    torch.manual_seed(0)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in ([] if args.no_configs else args.configs.split(",")):
            net = build_model(name, "relative").eval()
            path = Path(tmp) / f"{name}.onnx"
            export_model(net, path, args.width, args.height)
            runs = args.runs if name == "light" else max(2, args.runs // 5)
            seconds, w, h = time_onnx(path, args.threads, args.rounds, runs)
            rows.append((name, f"{w}x{h}", count_parameters(net), seconds))
    files = [("shipped", SHIPPED), ("shipped v2", SHIPPED_V2)] if args.shipped else []
    files += [(str(path), path) for path in args.model]
    for name, path in files:
        import onnx

        if not path.is_file():
            if name == "shipped v2":
                continue   # not exported yet
            sys.exit(f"error: no ONNX file at {path}")
        model = onnx.load(str(path))
        params = sum(int(np.prod(t.dims)) for t in model.graph.initializer)
        seconds, w, h = time_onnx(path, args.threads, args.rounds, args.runs)
        rows.append((name, f"{w}x{h}", params, seconds))

    paper = next((r[3] for r in rows if r[0] == "paper"), None)
    print(f"ONNX Runtime {args.threads} threads, best of {args.rounds} rounds")
    print("| config | input | params | ms/frame | frames/s | speed vs paper |")
    print("|---|---|---|---|---|---|")
    for name, size, params, seconds in rows:
        ratio = f"{paper / seconds:.1f}x" if paper else "-"
        print(f"| {name} | {size} | {params / 1e6:.2f} M | {seconds * 1000:.1f} | "
              f"{1 / seconds:.1f} | {ratio} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
