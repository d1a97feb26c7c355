"""`heightpipe export`: a training checkpoint -> ONNX (contract metadata, checked against PyTorch)."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--checkpoint", default="", metavar="FILE",
                        help="checkpoint (default: <train.out>/checkpoint.pt)")
    parser.add_argument("--out", default="stages/models/heightnet.onnx", metavar="FILE",
                        help="ONNX file to write (default: the shipped model's path)")


def main(args: argparse.Namespace, config) -> int:
    from core.extras import require

    for module in ("torch", "onnx"):
        require(module, "train", "heightpipe export")
    from heightnet.export import export_checkpoint

    checkpoint = Path(args.checkpoint or Path(config.train.out) / "checkpoint.pt")
    report = export_checkpoint(checkpoint, Path(args.out))
    meta = report.metadata
    print(f"wrote {report.path} ({report.size_bytes / 1e6:.2f} MB): {meta['heightpipe.architecture']}, "
          f"{meta['heightpipe.input_width']}x{meta['heightpipe.input_height']}, "
          f"{meta['heightpipe.output_units']}, {meta['heightpipe.trained_steps']} steps")
    print(f"ONNX Runtime vs PyTorch: max difference height {report.max_abs_diff_height:.2e}, "
          f"ground logit {report.max_abs_diff_ground:.2e}")
    return 0
