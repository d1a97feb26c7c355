"""`heightpipe train`: train HeightNet on a synth dataset ([train] config), resumable."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", default="", metavar="DIR[,DIR...]",
                        help="synth dataset(s), comma-separated (default: train.data)")
    parser.add_argument("--out", default="", metavar="DIR", help="run folder (default: train.out)")
    parser.add_argument("--resume", action="store_true", help="continue the run folder's checkpoint")
    parser.add_argument("--max-steps", type=int, default=0, metavar="N",
                        help="stop after N steps in this call (0 = run to train.steps)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def main(args: argparse.Namespace, config) -> int:
    import dataclasses

    from core.extras import require

    for module in ("torch", "matplotlib"):
        require(module, "train", "heightpipe train")
    from heightnet.data import build_cache, dataset_hash
    from heightnet.train import train
    from core.errors import ConfigError
    from synth.dataset import list_sequences

    train_config = dataclasses.replace(config.train, data=args.data or config.train.data,
                                       out=args.out or config.train.out)
    roots = [Path(part.strip()) for part in train_config.data.split(",") if part.strip()]
    if not roots:
        raise ConfigError("train.data names no dataset")
    cached = []
    for root in roots:
        if not (root / "manifest.json").is_file():
            raise ConfigError(f"no synth dataset at {root} (make one with `heightpipe synth`)")
        sequences = list_sequences(root, split="train")
        if not sequences:
            raise ConfigError(f"{root} has no training sequences")
        cached += build_cache(sequences, root / ".heightnet_cache", train_config.matcher,
                              progress=not args.no_progress)
    data_hash = dataset_hash(roots, {k: getattr(train_config, k) for k in
                                     ("architecture", "target", "input_width", "input_height",
                                      "consistency_weight", "seed")})
    result = train(train_config, cached, data_hash, resume=args.resume,
                   progress=not args.no_progress, max_steps=args.max_steps or None)
    print(f"step {result.steps}: checkpoint {result.checkpoint}; log {Path(train_config.out) / 'log.csv'}")
    return 0
