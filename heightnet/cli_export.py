"""`heightpipe export`: a training checkpoint -> ONNX (contract metadata, checked against PyTorch).

Which network is the config's ``train.formulation``: HeightNet v2 ("contact", the default: the
state in ``[train_v2] out``) or v1 ("log_height": ``[train] out``)."""

from __future__ import annotations

import argparse
from pathlib import Path

V1_MODEL = "stages/models/heightnet.onnx"
V2_MODEL = "stages/models/heightnet_v2.onnx"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--checkpoint", default="", metavar="FILE",
                        help="checkpoint (default: <train_v2.out>/checkpoint.pt, v1: <train.out>/checkpoint.pt)")
    parser.add_argument("--out", default="", metavar="FILE",
                        help=f"ONNX file to write (default: {V2_MODEL} for v2, {V1_MODEL} for v1)")


def main(args: argparse.Namespace, config) -> int:
    from core.extras import require

    for module in ("torch", "onnx"):
        require(module, "train", "heightpipe export")
    if config.train.formulation == "contact":
        return export_v2(args, config)
    from heightnet.export import export_checkpoint

    checkpoint = Path(args.checkpoint or Path(config.train.out) / "checkpoint.pt")
    report = export_checkpoint(checkpoint, Path(args.out or V1_MODEL))
    meta = report.metadata
    print(f"wrote {report.path} ({report.size_bytes / 1e6:.2f} MB): {meta['heightpipe.architecture']}, "
          f"{meta['heightpipe.input_width']}x{meta['heightpipe.input_height']}, "
          f"{meta['heightpipe.output_units']}, {meta['heightpipe.trained_steps']} steps")
    print(f"ONNX Runtime vs PyTorch: max difference height {report.max_abs_diff_height:.2e}, "
          f"ground logit {report.max_abs_diff_ground:.2e}")
    return 0


def export_v2(args: argparse.Namespace, config) -> int:
    from core.errors import ConfigError
    from heightnet.contact_export import export_contact

    checkpoint = Path(args.checkpoint or Path(config.train_v2.out) / "checkpoint.pt")
    if not checkpoint.is_file():
        raise ConfigError(f"no HeightNet v2 state at {checkpoint} (train one with `heightpipe train`)")
    out = Path(args.out or V2_MODEL)
    try:
        report = export_contact(checkpoint, out)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    diffs = ", ".join(f"{name} {value:.1e}" for name, value in report.items() if name != "size_bytes")
    print(f"wrote {out} ({report['size_bytes'] / 1e6:.2f} MB, HeightNet v2 from {checkpoint}); "
          f"ONNX Runtime vs PyTorch max difference: {diffs}")
    return 0
