"""HeightNet v2 training: resumable from a small committed state, logged, evaluated as it goes.

A 2-core CPU supplies training volume only if training accumulates over working days, and the
machine is not kept between them. So the run folder is meant to live in git:

* ``checkpoint.pt`` — the weights and their moving average (float32) and AdamW's moments
  (stored as float16, restored to float32): a few MB for a 0.5 M-parameter network; the step
  and images seen (the data order follows from them);
* ``log.csv`` — training losses every ``log_every`` steps;
* ``curve.csv`` — held-out scores (``heightnet/contact_eval.py``) every ``eval_every`` steps,
  against images seen: the learning curve.

``resume=True`` continues from ``checkpoint.pt`` with the same data order (a function of seed
and epoch) and learning rate (a function of the step), so nothing else must survive.
"""

from __future__ import annotations

import copy
import csv
import dataclasses
import json
import math
import time
from pathlib import Path
from typing import Any, Sequence

import torch

from core.config import TrainV2Config
from heightnet.contact_data import ContactPairDataset, ContactSampling, ContactSequence
from heightnet.contact_eval import evaluate, scores_row
from heightnet.contact_losses import ContactLossWeights, contact_loss
from heightnet.contact_model import ContactArchitecture, ContactNet
from heightnet.train import collate, epoch_order

LOSS_FIELDS = ["total", "offset", "offset_all", "height", "si", "consistency", "ground", "camera",
               "mover_rmse_cm"]
WARMUP_STEPS = 200


def architecture_of(config: TrainV2Config) -> ContactArchitecture:
    return ContactArchitecture(config.trunk, tuple(config.widths), 2 if config.camera_channels else 0)


def loss_weights_of(config: TrainV2Config) -> ContactLossWeights:
    return ContactLossWeights(config.offset_all_weight, config.height_weight, config.si_weight,
                              config.consistency_weight, config.ground_weight, config.camera_weight)


def learning_rate(step: int, config: TrainV2Config) -> float:
    """Linear warm-up, then constant: an open-ended run that accumulates over days has no end
    to decay towards (lower ``lr`` in the config when the curve flattens)."""
    return config.lr * min(1.0, (step + 1) / WARMUP_STEPS)


def train_contact(config: TrainV2Config, sequences: Sequence[ContactSequence],
                  held_out: Sequence[ContactSequence] = (), resume: bool = False,
                  progress: bool = True, max_steps: int | None = None) -> dict[str, Any]:
    """Train until ``config.steps`` (``max_steps``: at most this many in this call)."""
    from tqdm import tqdm

    torch.set_num_threads(max(1, config.threads))
    run_dir = Path(config.out)
    run_dir.mkdir(parents=True, exist_ok=True)
    checkpoint_path = run_dir / "checkpoint.pt"
    torch.manual_seed(config.seed)
    net = ContactNet(architecture_of(config))
    optimiser = torch.optim.AdamW(net.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    ema = copy.deepcopy(net)
    step, images = 0, 0
    if checkpoint_path.is_file():
        if not resume:
            raise FileExistsError(f"{checkpoint_path} exists: resume it or choose another output folder")
        step, images = load_state(checkpoint_path, net, optimiser, config, ema)
    (run_dir / "config.json").write_text(json.dumps(dataclasses.asdict(config), indent=2))

    sampling = ContactSampling(crop_probability=config.crop_probability,
                               camera_channels=config.camera_channels)
    dataset = ContactPairDataset(sequences, config.input_width, config.input_height, sampling,
                                 config.max_matches, config.seed)
    per_epoch = max(1, len(dataset) // config.batch_size)
    loss_weights = loss_weights_of(config)
    end = config.steps if max_steps is None else min(config.steps, step + max_steps)
    log = _CsvLog(run_dir / "log.csv", ["step", "images", "lr", *LOSS_FIELDS, "images_per_s"])
    curve = _CsvLog(run_dir / "curve.csv", None)
    net.train()
    sums: dict[str, float] = {}
    counted, tick, tick_images = 0, time.time(), 0
    bar = tqdm(total=end, initial=step, desc="train v2", disable=not progress, dynamic_ncols=True)
    try:
        while step < end:
            epoch, position = divmod(step, per_epoch)
            dataset.epoch = epoch
            order = epoch_order(config.seed, epoch, len(dataset))
            items = order[position * config.batch_size:(position + 1) * config.batch_size]
            batch = collate([dataset[int(i)] for i in items])
            for group in optimiser.param_groups:
                group["lr"] = learning_rate(step, config)
            channels = batch["camera_channels"].flatten(0, 1) if "camera_channels" in batch else None
            offsets, ground, camera = net(batch["image"].flatten(0, 1), channels)
            losses = contact_loss(offsets, ground, camera, batch, loss_weights)
            optimiser.zero_grad(set_to_none=True)
            losses["total"].backward()
            torch.nn.utils.clip_grad_norm_(net.parameters(), 5.0)
            optimiser.step()
            update_average(ema, net, config.ema_decay)
            step += 1
            images += 2 * len(items)
            tick_images += 2 * len(items)
            values = {k: float(losses[k].detach()) for k in LOSS_FIELDS[:-1]}
            values["mover_rmse_cm"] = _mover_rmse_cm(losses, batch)
            for k, v in values.items():
                if math.isfinite(v):
                    sums[k] = sums.get(k, 0.0) + v
            counted += 1
            bar.update(1)
            bar.set_postfix(loss=f"{values['total']:.2f}", rmse_cm=f"{values['mover_rmse_cm']:.0f}")
            if step % config.log_every == 0 or step == end:
                rate = tick_images / max(1e-9, time.time() - tick)
                log.write({"step": step, "images": images, "lr": f"{learning_rate(step - 1, config):.3g}",
                           **{k: f"{sums.get(k, float('nan')) / max(1, counted):.5f}" for k in LOSS_FIELDS},
                           "images_per_s": f"{rate:.2f}"})
                sums, counted, tick, tick_images = {}, 0, time.time(), 0
            if held_out and (step % config.eval_every == 0 or step == end):
                scores = evaluate(ema, held_out, config.input_width, config.input_height)
                curve.write({"step": step, "images": images,
                             **{k: f"{v:.2f}" for k, v in scores_row(scores).items()}})
                tick = time.time()   # evaluation time is not training throughput
            if step % config.checkpoint_every == 0 or step == end:
                save_state(checkpoint_path, net, optimiser, step, images, config, ema)
    finally:
        bar.close()
        log.close()
        curve.close()
    return {"step": step, "images": images, "net": net, "ema": ema}


def update_average(ema: torch.nn.Module, net: torch.nn.Module, decay: float) -> None:
    """Exponential moving average of the weights (and BatchNorm statistics): at a constant
    learning rate the last iterate wanders, and its held-out scores with it; the average is
    what is evaluated and exported."""
    with torch.no_grad():
        for averaged, current in zip(ema.state_dict().values(), net.state_dict().values()):
            if averaged.dtype.is_floating_point:
                averaged.mul_(decay).add_(current, alpha=1 - decay)
            else:
                averaged.copy_(current)


def save_state(path: Path, net: torch.nn.Module, optimiser: torch.optim.Optimizer, step: int,
               images: int, config: TrainV2Config, ema: torch.nn.Module | None = None) -> None:
    """Atomically write the compact state: weights and their average in float32, Adam moments in
    float16."""
    opt = optimiser.state_dict()
    # state_dict() hands out the live per-parameter dicts: build new ones, never edit those.
    opt["state"] = {index: {key: _compact(key, value) for key, value in state.items()}
                    for index, state in opt["state"].items()}
    tmp = path.with_suffix(".tmp")
    torch.save({"model": net.state_dict(), "ema": (ema or net).state_dict(), "optimiser": opt,
                "step": step, "images": images,
                "architecture": net.arch.to_dict(), "input_size": [config.input_width, config.input_height],
                "config": dataclasses.asdict(config)}, tmp)
    tmp.replace(path)


def _compact(key: str, value: Any) -> Any:
    if key == "exp_avg":
        return value.to(torch.float16)
    if key == "exp_avg_sq":   # stored as its square root: tiny second moments stay representable
        return value.sqrt().to(torch.float16)
    return value


def load_state(path: Path, net: torch.nn.Module, optimiser: torch.optim.Optimizer | None,
               config: TrainV2Config | None = None, ema: torch.nn.Module | None = None) -> tuple[int, int]:
    """Restore a state into ``net`` (and ``optimiser``, ``ema``); a state written before the
    average existed starts the average from its weights."""
    state = torch.load(path, map_location="cpu", weights_only=False)
    if config is not None:
        if state["architecture"] != architecture_of(config).to_dict() or \
                state["input_size"] != [config.input_width, config.input_height]:
            raise ValueError(f"cannot resume {path}: it holds {state['architecture']} at "
                             f"{state['input_size']}, the config asks for {architecture_of(config).to_dict()} "
                             f"at {[config.input_width, config.input_height]}")
    net.load_state_dict(state["model"])
    if ema is not None:
        ema.load_state_dict(state.get("ema", state["model"]))
    if optimiser is not None:
        opt = state["optimiser"]
        for s in opt["state"].values():
            if "exp_avg" in s:
                s["exp_avg"] = s["exp_avg"].float()
            if "exp_avg_sq" in s:
                s["exp_avg_sq"] = s["exp_avg_sq"].float() ** 2
        optimiser.load_state_dict(opt)
    return int(state["step"]), int(state["images"])


def load_network(path: Path) -> ContactNet:
    """The averaged weights of a state (what is evaluated and exported), in eval mode."""
    state = torch.load(path, map_location="cpu", weights_only=False)
    net = ContactNet(ContactArchitecture.from_dict(state["architecture"]))
    net.load_state_dict(state.get("ema", state["model"]))
    net.eval()
    return net


def _mover_rmse_cm(losses: dict[str, torch.Tensor], batch: dict[str, torch.Tensor]) -> float:
    """Decoded-height RMSE on this batch's mover pixels (training progress, not an evaluation)."""
    movers = losses["movers"]
    if not movers.any():
        return float("nan")
    truth = torch.nan_to_num(batch["height"].flatten(0, 1))
    return float(((losses["decoded"] - truth)[movers] ** 2).mean().sqrt() * 100)


class _CsvLog:
    """Append-only CSV whose header is taken from the first row written (or given)."""

    def __init__(self, path: Path, fields: list[str] | None):
        self.path, self.fields = path, fields
        self.file = None

    def write(self, row: dict[str, Any]) -> None:
        if self.file is None:
            fresh = not self.path.is_file() or self.path.stat().st_size == 0
            self.file = self.path.open("a", newline="")
            self.writer = csv.DictWriter(self.file, self.fields or list(row))
            if fresh:
                self.writer.writeheader()
        self.writer.writerow(row)
        self.file.flush()

    def close(self) -> None:
        if self.file is not None:
            self.file.close()
