"""`heightpipe eval DATA`: the paper's Table 1 on a synth dataset's held-out scenes."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("data", metavar="DATA", help="synth dataset folder")
    parser.add_argument("--model", default="", help="ONNX model (default: height.model or the shipped one)")
    parser.add_argument("--label", default="HeightNet", help="name of the model in the table")
    parser.add_argument("--ablation", default="", metavar="ONNX",
                        help="a second model shown side by side (e.g. trained without consistency loss)")
    parser.add_argument("--ablation-label", default="no consistency loss", metavar="NAME",
                        help="name of the --ablation model in the table (default: no consistency loss)")
    parser.add_argument("--split", default="test", choices=["test", "train", "all"],
                        help="which scenes of DATA: the held-out test split (default), train, or all")
    parser.add_argument("--every", type=int, default=1, metavar="N", help="every Nth frame")
    parser.add_argument("--out", default="runs/eval", metavar="DIR",
                        help="where table.md, table.csv and figure4.png go")


def main(args: argparse.Namespace, config) -> int:
    from core.extras import require

    require("matplotlib", "train", "heightpipe eval")
    from heightnet.evaluate import run_evaluation
    from heightnet.predict import model_path_from_config
    from core.errors import ConfigError
    from synth.dataset import list_sequences

    root = Path(args.data)
    if not (root / "manifest.json").is_file():
        raise ConfigError(f"no synth dataset at {root}")
    sequences = list_sequences(root, split=None if args.split == "all" else args.split)
    if not sequences:
        raise ConfigError(f"{root} has no {args.split} sequences")
    models = [(args.label, model_path_from_config(args.model or config.height.model))]
    if args.ablation:
        models.append((args.ablation_label, model_path_from_config(args.ablation)))
    table = run_evaluation(sequences, models, Path(args.out), max(1, args.every),
                           config.height.threads, progress=config.output.progress)
    print(table)
    print(f"written to {args.out}/table.md, table.csv, figure4.png")
    return 0
