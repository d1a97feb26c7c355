"""`heightpipe train`: train HeightNet on synth data, resumable.

``train.formulation = "contact"`` (default) trains HeightNet v2 ([train_v2], ``heightnet/contact_train.py``),
whose run folder is committed so that ``heightpipe train --resume`` continues on a fresh clone:
missing synth data is rendered first with the configured commands. ``"log_height"`` trains the
v1 network of the shipped model ([train]).
"""

from __future__ import annotations

import argparse
import errno
import shlex
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", default="", metavar="DIR[,DIR...]",
                        help="synth dataset(s), comma-separated (default: train.data)")
    parser.add_argument("--out", default="", metavar="DIR", help="run folder (default: train.out)")
    parser.add_argument("--resume", action="store_true", help="continue the run folder's checkpoint")
    parser.add_argument("--max-steps", type=int, default=0, metavar="N",
                        help="stop after N steps in this call (0 = run to train.steps)")
    parser.add_argument("--max-minutes", type=float, default=0, metavar="M",
                        help="stop after M minutes in this call, state written (0 = no limit; v2 only)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def main(args: argparse.Namespace, config) -> int:
    import dataclasses

    from core.extras import require

    for module in ("torch", "matplotlib"):
        require(module, "train", "heightpipe train")
    if config.train.formulation == "contact":
        return train_v2(args, config)
    if config.train.formulation != "log_height":
        from core.errors import ConfigError

        raise ConfigError(f"train.formulation must be 'contact' or 'log_height', got {config.train.formulation!r}")
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


def train_v2(args: argparse.Namespace, config) -> int:
    """HeightNet v2: render missing data, cache it, train or resume, print where things are."""
    import dataclasses

    from core.errors import ConfigError
    from heightnet.contact_data import build_contact_cache
    from heightnet.contact_train import train_contact
    from synth.dataset import list_sequences

    v2 = dataclasses.replace(config.train_v2, data=args.data or config.train_v2.data,
                             out=args.out or config.train_v2.out)
    progress = not args.no_progress

    def cached(key: str, roots: str, command: str, split: str, count: int):
        """The contact caches of the ``split`` sequences in the comma-separated folders ``roots``
        (the key ``train_v2.<key>``, named in errors), the first ``count`` by name over all of them
        (0 = all). A missing folder is rendered with ``command`` if that is where the command
        writes (a fresh clone's configured data), else an error: a mistyped folder rendered the
        configured data into another folder."""
        chosen = []
        for root in [part.strip() for part in roots.split(",") if part.strip()]:
            folder = Path(root)
            if not (folder / "manifest.json").is_file():
                if not command or _writes_to(command) != folder:
                    raise ConfigError(f"no synth dataset at {folder} (make one with `heightpipe synth`)")
                render(folder, command)
            sequences = sorted(list_sequences(folder, split=split), key=lambda s: s.name)
            if not sequences:
                raise ConfigError(f"{folder} has no {split}-split sequences")
            chosen += [(folder, sequence) for sequence in sequences]
        if not chosen:
            raise ConfigError(f"train_v2.{key} names no dataset")
        chosen = chosen[:count or None]
        caches = []
        for folder in dict.fromkeys(folder for folder, _ in chosen):
            try:
                caches += build_contact_cache([s for f, s in chosen if f == folder], folder / ".contact_cache",
                                              progress=progress, workers=v2.loader_workers)
            except OSError as exc:
                if exc.errno != errno.EMFILE:
                    raise
                # One memory map a sequence (heightnet.contact_data), each holding its file open.
                raise ConfigError(f"{len(chosen)} sequences open more files than this machine allows "
                                  f"(ulimit -n): name fewer (train_v2.sequences, fewer --data folders)") from None
        return caches

    def render(folder: Path, command: str) -> None:
        words = shlex.split(command)
        if words[:2] != ["heightpipe", "synth"]:
            raise ConfigError(f"a data command must be a 'heightpipe synth ...' command, got {command!r}")
        print(f"{folder} is missing: rendering it first ({command})")
        from synth import cli as synth_cli

        parser = argparse.ArgumentParser(prog="heightpipe synth")
        synth_cli.add_arguments(parser)
        status = synth_cli.main(parser.parse_args(words[2:] + ([] if progress else ["--no-progress"])), config)
        if status:
            raise ConfigError(f"rendering {folder} failed (exit {status})")

    train_set = cached("data", v2.data, v2.data_command, "train", v2.sequences)
    held_out = cached("test_data", v2.test_data, v2.test_command, "test", v2.test_sequences) if v2.test_data else []
    try:
        result = train_contact(v2, train_set, held_out, resume=args.resume, progress=progress,
                               max_steps=args.max_steps or None,
                               max_seconds=args.max_minutes * 60 if args.max_minutes > 0 else None)
    except (FileExistsError, ValueError) as exc:
        raise ConfigError(str(exc)) from None
    out = Path(v2.out)
    print(f"step {result['step']} ({result['images']} images): state {out / 'checkpoint.pt'}; "
          f"losses {out / 'log.csv'}; held-out curve {out / 'curve.csv'}")
    return 0


def _writes_to(command: str) -> Path | None:
    """The folder a ``heightpipe synth`` command writes (its ``--out``), None if it names none."""
    words = shlex.split(command)
    return Path(words[words.index("--out") + 1]) if "--out" in words[:-1] else None
