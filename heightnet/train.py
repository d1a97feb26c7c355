"""Training loop: config-driven, resumable, logged (CSV + PNG plot) and deterministic.

A run folder holds ``checkpoint.pt`` (latest, written atomically every ``checkpoint_every``
steps and at the end), ``log.csv`` (one row per logged step: losses, learning rate, mover RMSE
on the batch) and ``loss.png``. ``resume=True`` continues from the checkpoint to the configured
step count with the same data order: the order is a function of (seed, epoch) and the learning
rate a function of the step, so nothing but the checkpoint has to survive an interruption.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch

from heightnet.checkpoint import load_checkpoint, save_checkpoint
from heightnet.data import Augmentation, CachedSequence, PairDataset
from heightnet.encoding import TARGETS
from heightnet.losses import LossWeights, heightnet_loss
from heightnet.model import build_model
from heightnet.onnx_weights import (exported_architecture, freeze_batchnorm, load_onnx_weights,
                                   load_onnx_weights_shared, trained_steps)
from core.config import TrainConfig
from core.errors import ConfigError

LOG_FIELDS = ["step", "epoch", "lr", "total", "si", "si_above", "consistency", "ground",
              "mover_rmse_cm", "seconds"]
WARMUP_STEPS = 200


@dataclass
class TrainResult:
    checkpoint: Path
    steps: int
    last: dict[str, float]


def learning_rate(step: int, config: TrainConfig) -> float:
    """Linear warm-up, then cosine decay to 5% of the peak at ``config.steps``."""
    if step < WARMUP_STEPS:
        return config.lr * (step + 1) / WARMUP_STEPS
    progress = min(1.0, (step - WARMUP_STEPS) / max(1, config.steps - WARMUP_STEPS))
    return config.lr * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * progress)))


def check_config(config: TrainConfig) -> None:
    if config.target not in TARGETS:
        raise ConfigError(f"train.target must be one of {', '.join(TARGETS)}, got {config.target!r}")
    if config.input_width % 16 or config.input_height % 16:
        raise ConfigError(f"train.input_width/height must be multiples of 16, "
                          f"got {config.input_width}x{config.input_height}")
    if config.batch_size < 1 or config.steps < 1:
        raise ConfigError("train.batch_size and train.steps must be positive")


def epoch_order(seed: int, epoch: int, n: int) -> np.ndarray:
    return np.random.default_rng([seed, epoch, 7]).permutation(n)


def train(config: TrainConfig, sequences: Sequence[CachedSequence], data_hash: str = "",
          resume: bool = False, progress: bool = True, max_steps: int | None = None) -> TrainResult:
    """Train (or continue training) until ``config.steps``; ``max_steps`` stops earlier (this call)."""
    from tqdm import tqdm

    check_config(config)
    torch.set_num_threads(max(1, config.threads))
    run_dir = Path(config.out)
    run_dir.mkdir(parents=True, exist_ok=True)
    checkpoint_path = run_dir / "checkpoint.pt"

    torch.manual_seed(config.seed)
    net = build_model(config.architecture, config.target, config.backbone)
    optimiser = torch.optim.AdamW(net.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    step = 0
    init_steps = 0              # steps behind the weights a fine-tuning run started from
    frozen = bool(config.init_onnx)   # BatchNorms folded at export: identities with a bias now
    if checkpoint_path.is_file():
        if not resume:
            raise ConfigError(f"{checkpoint_path} exists: pass --resume to continue it or choose another "
                              f"train.out")
        state = load_checkpoint(checkpoint_path)
        _check_resumable(state, config)
        net.load_state_dict(state["model"])
        optimiser.load_state_dict(state["optimiser"])
        step = int(state["step"])
        init_steps = int(state.get("init_steps", 0))
        frozen = bool(state.get("frozen_batchnorm", False))
    elif config.init_onnx:
        if exported_architecture(Path(config.init_onnx)) in ("", config.architecture):
            load_onnx_weights(net, Path(config.init_onnx))
        else:  # a cut-down architecture starts from what it shares with the larger one
            fresh = load_onnx_weights_shared(net, Path(config.init_onnx))
            print(f"train: {config.architecture} from {config.init_onnx}; not in it: {', '.join(fresh)}")
        init_steps = trained_steps(Path(config.init_onnx))
    (run_dir / "config.json").write_text(json.dumps(dataclasses.asdict(config), indent=2))

    dataset = PairDataset(sequences, config.input_width, config.input_height, config.target,
                          Augmentation(), config.max_matches, config.seed)
    batches_per_epoch = max(1, len(dataset) // config.batch_size)
    weights = LossWeights(config.si_lambda, config.above_ground_weight, config.above_ground_lambda,
                          config.consistency_weight, config.ground_weight)
    end = config.steps if max_steps is None else min(config.steps, step + max_steps)
    log_file = (run_dir / "log.csv").open("a", newline="")
    log = csv.DictWriter(log_file, LOG_FIELDS)
    if log_file.tell() == 0:
        log.writeheader()
    net.train()
    if frozen:
        freeze_batchnorm(net)
    sums: dict[str, float] = {}
    last: dict[str, float] = {}
    counted = 0
    started = time.time()
    bar = tqdm(total=end, initial=step, desc="train", disable=not progress, dynamic_ncols=True)
    try:
        while step < end:
            epoch, position = divmod(step, batches_per_epoch)
            dataset.epoch = epoch
            order = epoch_order(config.seed, epoch, len(dataset))
            items = order[position * config.batch_size:(position + 1) * config.batch_size]
            batch = collate([dataset[int(i)] for i in items])
            for group in optimiser.param_groups:
                group["lr"] = learning_rate(step, config)
            encoded, ground_logit = net(batch["image"].flatten(0, 1))
            losses = heightnet_loss(encoded, ground_logit, batch, net.encoding, weights)
            optimiser.zero_grad(set_to_none=True)
            losses["total"].backward()
            torch.nn.utils.clip_grad_norm_(net.parameters(), 5.0)
            optimiser.step()
            step += 1

            values = {k: float(v.detach()) for k, v in losses.items()}
            values["mover_rmse_cm"] = _mover_rmse_cm(encoded.detach(), batch, net.encoding)
            for k, v in values.items():
                if math.isfinite(v):
                    sums[k] = sums.get(k, 0.0) + v
            counted += 1
            bar.update(1)
            bar.set_postfix(loss=f"{values['total']:.3f}", rmse_cm=f"{values['mover_rmse_cm']:.1f}")
            if step % 20 == 0 or step == end:
                last = {k: v / counted for k, v in sums.items()}
                log.writerow({"step": step, "epoch": epoch, "lr": f"{learning_rate(step - 1, config):.3g}",
                              **{k: f"{last.get(k, float('nan')):.5f}" for k in LOG_FIELDS[3:9]},
                              "seconds": f"{time.time() - started:.1f}"})
                log_file.flush()
                sums, counted = {}, 0
            if step % config.checkpoint_every == 0 or step == end:
                _save(checkpoint_path, net, optimiser, step, config, data_hash, init_steps, frozen)
                plot_log(run_dir / "log.csv", run_dir / "loss.png")
    finally:
        bar.close()
        log_file.close()
    return TrainResult(checkpoint_path, step, last)


def _check_resumable(state: dict[str, Any], config: TrainConfig) -> None:
    for key in ("architecture", "target", "input_width", "input_height"):
        if state.get(key) != getattr(config, key):
            raise ConfigError(f"cannot resume: checkpoint has {key}={state.get(key)!r}, "
                              f"config has {getattr(config, key)!r}")


def _save(path: Path, net: torch.nn.Module, optimiser: torch.optim.Optimizer, step: int,
          config: TrainConfig, data_hash: str, init_steps: int = 0, frozen: bool = False) -> None:
    save_checkpoint(path, {
        "model": net.state_dict(), "optimiser": optimiser.state_dict(), "step": step,
        "init_steps": init_steps, "frozen_batchnorm": frozen,
        "architecture": config.architecture, "backbone": config.backbone, "target": config.target,
        "input_width": config.input_width, "input_height": config.input_height,
        "data_hash": data_hash, "config": dataclasses.asdict(config)})


def collate(items: list[dict[str, Any]]) -> dict[str, torch.Tensor]:
    """Samples (dicts of NumPy arrays) stacked into one batch of tensors."""
    return {k: torch.from_numpy(np.stack([item[k] for item in items])) for k in items[0]}


def _mover_rmse_cm(encoded: torch.Tensor, batch: dict[str, torch.Tensor], encoding) -> float:
    """RMSE in cm on mover pixels of this batch (training-set progress, not an evaluation)."""
    camera = batch["camera_height_m"].repeat_interleave(2)[:, None, None, None]
    pred = encoding.metres_from_output(torch.relu(torch.exp(encoded) - encoding.offset), camera)
    truth = encoding.metres_from_output(batch["target"].flatten(0, 1), camera)
    mask = batch["mover"].flatten(0, 1) & torch.isfinite(truth) & (truth > 0.1)
    if not mask.any():
        return float("nan")
    return float(((pred - truth)[mask] ** 2).mean().sqrt() * 100)


def plot_log(log_path: Path, png_path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with open(log_path, newline="") as f:
        rows = list(csv.DictReader(f))
    if not rows:
        return
    steps = [int(r["step"]) for r in rows]
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4))
    for key in ("total", "si", "si_above", "ground", "consistency"):
        left.plot(steps, [float(r[key]) for r in rows], label=key)
    left.set_yscale("log")
    left.set_xlabel("step")
    left.set_title("training losses")
    left.legend()
    right.plot(steps, [float(r["mover_rmse_cm"]) for r in rows], color="tab:red")
    right.set_xlabel("step")
    right.set_ylabel("cm")
    right.set_title("mover-pixel RMSE on training batches")
    fig.tight_layout()
    fig.savefig(png_path, dpi=90)
    plt.close(fig)
