"""The HeightNet v2 recipe experiment: arms trained on one fixed data set, same steps, same seed.

    python -m heightnet.recipe cache --train DIR --test DIR [--sequences N]
    python -m heightnet.recipe run ARM --train DIR --test DIR [--sequences N] [--steps S] [--out DIR]
    python -m heightnet.recipe table [--out DIR]
    python -m heightnet.recipe speed [--threads 2]    # training images/s of each arm's network

Arms differ from ``base`` (plain 3x3 trunk, whole frames, RGB only) in one thing each:
``depthwise`` (MobileNetV2 inverted residuals, parameter count within 0.1 %), ``crops``
(half the samples native-resolution windows around a mover), ``camconv`` (two CAM-Conv camera
channels at the input). Each arm's ``curve.csv`` holds the held-out scores at every
``eval_every`` steps; ``table`` prints them side by side with each arm's training images/s.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

# Every arm is a fresh run of the network as it was then: the whole network trains, and the
# detection head (where an arm has one) has no residual blocks.
FRESH_RUN = {"head_only": False, "detection_blocks": 0, "detection_fine": False}
# The recipe's arms were measured on the first network (no context blocks, no detection head).
FIRST_NETWORK = {"context": [], "detection": False, "refine": 0, "gate": False, "position": False,
                 "crop_probability": 0.0}
ARMS = {
    "base": FIRST_NETWORK,
    "depthwise": {**FIRST_NETWORK, "trunk": "depthwise"},
    "crops": {**FIRST_NETWORK, "crop_probability": 0.5},
    "camconv": {**FIRST_NETWORK, "camera_channels": True},
    "grown": {"context": [2, 4, 8], "detection": True, "refine": 0, "gate": False, "position": False,
              "crop_probability": 0.5},
    "refined": {"context": [2, 4, 8], "detection": True, "refine": 8, "gate": False, "position": False,
                "crop_probability": 0.5},
    "gated": {"context": [2, 4, 8], "detection": True, "refine": 8, "gate": True, "position": False,
              "crop_probability": 0.5},
    "positioned": {"context": [2, 4, 8], "detection": True, "refine": 8, "gate": True, "position": True,
                   "crop_probability": 0.5},
}
COLUMNS = [("top_person_cm", "people"), ("top_cyclist_cm", "cyclists"), ("top_car_van_cm", "cars/vans"),
           ("top_truck_bus_cm", "trucks/buses"), ("rmse_cm", "mover RMSE w/o trucks"),
           ("rmse_worst_row_cm", "worst row"), ("top_heads_person_cm", "people, heads"),
           ("pitch_error_deg", "pitch err deg"), ("focal_error_pct", "focal err %")]


def load(root: str, sequences: int | None, split: str):
    from synth.dataset import list_sequences

    from heightnet.contact_data import build_contact_cache

    seqs = list_sequences(root, split=split)
    if not seqs:
        sys.exit(f"error: no {split}-split sequences in {root}")
    seqs = sorted(seqs, key=lambda s: s.name)[:sequences]
    return build_contact_cache(seqs, Path(root) / ".contact_cache", progress=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m heightnet.recipe", description=__doc__.split("\n")[0])
    parser.add_argument("command", choices=["cache", "run", "table", "speed"])
    parser.add_argument("arm", nargs="?", choices=list(ARMS))
    parser.add_argument("--train", default="data/v2_train")
    parser.add_argument("--test", default="data/v2_test")
    parser.add_argument("--sequences", type=int, default=600, help="train sequences used (first N by name)")
    parser.add_argument("--test-sequences", type=int, default=50, help="held-out sequences (first N by name)")
    parser.add_argument("--steps", type=int, default=1500)
    parser.add_argument("--eval-every", type=int, default=250)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--out", default="runs/recipe")
    args = parser.parse_args(argv)
    if args.command == "table":
        print_table(Path(args.out))
        return 0
    if args.command == "speed":
        print_speed(args.threads)
        return 0
    train = load(args.train, args.sequences, "train")
    test = load(args.test, args.test_sequences, "test")
    if args.command == "cache":
        print(f"{len(train)} train, {len(test)} test sequences cached")
        return 0
    if args.arm is None:
        parser.error("run needs an ARM")
    from core.config import TrainV2Config
    from heightnet.contact_train import train_contact

    config = TrainV2Config(out=str(Path(args.out) / args.arm), steps=args.steps, threads=args.threads,
                           eval_every=args.eval_every, checkpoint_every=args.eval_every,
                           **{**FRESH_RUN, **ARMS[args.arm]})
    train_contact(config, train, test, resume=True, progress=False)
    return 0


def print_speed(threads: int, steps: int = 6, batch_pairs: int = 4) -> None:
    """Images/s of one training step (forward, loss-free backward, AdamW) per arm's network at
    320x240, random inputs: the networks' own cost, without data loading."""
    import time

    import torch

    from core.config import TrainV2Config
    from heightnet.contact_model import ContactNet, count_parameters
    from heightnet.contact_train import architecture_of

    torch.set_num_threads(threads)
    print(f"| arm | parameters | training images/s ({threads} threads) |\n|---|---|---|")
    for arm, changes in ARMS.items():
        if arm == "crops":
            continue   # same network as base
        torch.manual_seed(0)
        net = ContactNet(architecture_of(TrainV2Config(**{**FRESH_RUN, **changes})))
        optimiser = torch.optim.AdamW(net.parameters())
        images = torch.randn(2 * batch_pairs, 3, 240, 320)
        channels = torch.randn(2 * batch_pairs, 2, 240, 320) if net.arch.camera_channels else None
        best = float("inf")
        for step in range(steps):
            start = time.perf_counter()
            outputs = net(images, channels)
            sum(t.square().mean() for t in outputs).backward()
            optimiser.step()
            optimiser.zero_grad()
            if step:   # the first step pays for allocation
                best = min(best, time.perf_counter() - start)
        print(f"| {arm} | {count_parameters(net):,} | {2 * batch_pairs / best:.1f} |")


def print_table(out: Path) -> None:
    print("| arm | step | images | " + " | ".join(name for _, name in COLUMNS) + " | train images/s |")
    print("|---" * (len(COLUMNS) + 4) + "|")
    for arm in ARMS:
        curve, log = out / arm / "curve.csv", out / arm / "log.csv"
        if not curve.is_file():
            continue
        with log.open() as f:
            rates = [float(r["images_per_s"]) for r in csv.DictReader(f)]
        rate = sorted(rates)[len(rates) // 2] if rates else float("nan")
        with curve.open() as f:
            for row in csv.DictReader(f):
                cells = " | ".join(f"{float(row[key]):.1f}" for key, _ in COLUMNS)
                print(f"| {arm} | {row['step']} | {row['images']} | {cells} | {rate:.1f} |")


if __name__ == "__main__":
    sys.exit(main())
