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

The same loop trains on a GPU (``device = "cuda"``) when a machine with one is lent for a few
minutes: pairs are then prepared by ``loader_workers`` processes in the same order, and the
state is written with CPU tensors, so it resumes on the 2-core machine as any other.
"""

from __future__ import annotations

import copy
import csv
import dataclasses
import json
import math
import time
from pathlib import Path
from typing import Any, Iterator, Sequence

import torch

from core.config import TrainV2Config
from heightnet.contact_data import ContactPairDataset, ContactSampling, ContactSequence
from heightnet.contact_eval import evaluate, scores_row
from heightnet.contact_losses import ContactLossWeights, contact_loss
from heightnet.contact_model import ContactArchitecture, ContactNet
from heightnet.normalisation import MEAN, STD
from heightnet.train import collate, epoch_order

LOSS_FIELDS = ["total", "offset", "offset_all", "height", "si", "consistency", "ground", "camera",
               "centre", "box", "big_centre", "big_box", "mover_rmse_cm"]
WARMUP_STEPS = 200
DETECTION_HEAD = "detection_head."
BIG_OBJECT_HEAD = "detection_head.big."
# Modules a grown network may add to a state (contact_model.ContactArchitecture.grows_from).
GROWN_PARTS = ("context.", DETECTION_HEAD, "refinement.", "offset_gate.")
# The first convolution of a network grown with input channels (the position channels).
FIRST_CONVOLUTION = ("encoder.0.0.0.weight", "encoder.0.0.body.0.weight")


def architecture_of(config: TrainV2Config) -> ContactArchitecture:
    return ContactArchitecture(config.trunk, tuple(config.widths), 2 if config.camera_channels else 0,
                               tuple(config.context), config.detection, config.refine,
                               config.gate, config.position, config.detection and config.detection_context,
                               config.detection_blocks if config.detection else 0,
                               config.detection and config.detection_motion,
                               config.detection and config.detection_fine,
                               config.detection and config.detection_big)


def loss_weights_of(config: TrainV2Config) -> ContactLossWeights:
    return ContactLossWeights(config.offset_all_weight, config.height_weight, config.si_weight,
                              config.consistency_weight, config.ground_weight, config.camera_weight,
                              config.detection_weight, config.box_giou_weight)


def learning_rate(step: int, config: TrainV2Config, warmup_from: int = 0) -> float:
    """Linear warm-up, then constant, times ``lr_drop_factor`` for each of ``lr_drops`` passed:
    an open-ended run that accumulates over days has no end to decay towards, so it steps down
    where its held-out curve has flattened. A network grown from a state warms up again from the
    step it grew at (its optimiser moments start afresh)."""
    drops = sum(1 for at in config.lr_drops if step >= at)
    return config.lr * config.lr_drop_factor ** drops * min(1.0, (step - warmup_from + 1) / WARMUP_STEPS)


def parameter_groups(net: ContactNet) -> list[dict]:
    """The optimiser's groups: the network, then its detection head (its own learning rate,
    ``detection_lr_factor``). Within each, parameters in ``net.parameters()`` order."""
    named = list(net.named_parameters())
    head = [p for name, p in named if name.startswith(DETECTION_HEAD)]
    groups = [{"params": [p for name, p in named if not name.startswith(DETECTION_HEAD)]}]
    return groups + [{"params": head}] if head else groups


def group_learning_rates(step: int, config: TrainV2Config, warmup_from: int = 0) -> list[float]:
    """Learning rate of each of ``parameter_groups``' groups (network, detection head)."""
    base = learning_rate(step, config, warmup_from)
    head = config.detection_lr_factor if step >= config.detection_lr_from else 1.0
    return [base, base * head]


def train_contact(config: TrainV2Config, sequences: Sequence[ContactSequence],
                  held_out: Sequence[ContactSequence] = (), resume: bool = False,
                  progress: bool = True, max_steps: int | None = None,
                  max_seconds: float | None = None) -> dict[str, Any]:
    """Train until ``config.steps`` (``max_steps``: at most this many in this call;
    ``max_seconds``: stop, with the state written, once this much time has passed)."""
    from tqdm import tqdm

    started = time.time()
    torch.set_num_threads(max(1, config.threads))
    device = training_device(config.device)
    run_dir = Path(config.out)
    run_dir.mkdir(parents=True, exist_ok=True)
    checkpoint_path = run_dir / "checkpoint.pt"
    torch.manual_seed(config.seed)
    net = ContactNet(architecture_of(config)).to(device)   # before the optimiser: its state follows
    optimiser = torch.optim.AdamW(parameter_groups(net), lr=config.lr, weight_decay=config.weight_decay)
    ema = copy.deepcopy(net)
    step, images, warmup_from = 0, 0, 0
    measured: dict[str, Any] = {}
    trained = trained_prefix(config)
    if trained and not checkpoint_path.is_file():
        raise ValueError(f"train_v2.head_only and big_head_only train a head of a trained network, and "
                         f"{checkpoint_path} holds none: resume a state or set both false")
    if checkpoint_path.is_file():
        if not resume:
            raise FileExistsError(f"{checkpoint_path} exists: resume it or choose another output folder")
        step, images, warmup_from = load_state(checkpoint_path, net, optimiser, config, ema)
        measured = camera_measurements(checkpoint_path, bool(trained))
        for name in ("log.csv", "curve.csv"):   # rows logged after the checkpoint are logged again
            _drop_rows_after(run_dir / name, step)
    (run_dir / "config.json").write_text(json.dumps(dataclasses.asdict(config), indent=2))

    sampling = ContactSampling(crop_probability=config.crop_probability,
                               camera_channels=config.camera_channels, detection=config.detection,
                               detection_stride=net.arch.detection_stride,
                               appearance=config.appearance, still_pairs=config.still_pairs,
                               whole_boxes=config.whole_boxes, zoom_probability=config.zoom_crops,
                               centre_core=config.centre_core,
                               big_objects=config.detection and config.detection_big)
    dataset = ContactPairDataset(sequences, config.input_width, config.input_height, sampling,
                                 config.max_matches, config.seed)
    per_epoch = max(1, len(dataset) // config.batch_size)
    loss_weights = loss_weights_of(config)
    end = config.steps if max_steps is None else min(config.steps, step + max_steps)
    # waiting_share: of the time between log rows, the share spent waiting for the next batch
    # (near 1: the pairs' preparation, not the network, bounds the rate; add loader_workers).
    log = _CsvLog(run_dir / "log.csv", ["step", "images", "lr", *LOSS_FIELDS, "images_per_s", "waiting_share"])
    curve = _CsvLog(run_dir / "curve.csv", None)
    net.train()
    if trained:
        _freeze_all_but(net, ema, trained)
        if progress:
            print(f"train_v2.{'big_head_only' if config.big_head_only else 'head_only'}: {trained[:-1]} "
                  "trains alone; the rest keeps its averaged weights")
    sums: dict[str, float] = {}
    counted, tick, tick_images, waited = 0, time.time(), 0, 0.0
    bar = tqdm(total=end, initial=step, desc="train v2", disable=not progress, dynamic_ncols=True)
    batches = pair_batches(dataset, config, step, end, per_epoch, device)
    try:
        asked = time.time()
        for batch in batches:
            waited += time.time() - asked
            batch = training_batch(batch, device)
            pairs = len(batch["image"])
            for group, lr in zip(optimiser.param_groups, group_learning_rates(step, config, warmup_from)):
                group["lr"] = lr
            channels = batch["camera_channels"].flatten(0, 1) if "camera_channels" in batch else None
            previous = pair_previous(batch["image"]) if net.arch.detection_motion else None
            offsets, ground, camera, *detection = net(batch["image"].flatten(0, 1), channels,
                                                      batch["window"].flatten(0, 1), previous)
            losses = contact_loss(offsets, ground, camera, batch, loss_weights, tuple(detection) or None)
            optimiser.zero_grad(set_to_none=True)
            losses["total"].backward()
            torch.nn.utils.clip_grad_norm_(net.parameters(), 5.0)
            optimiser.step()
            update_average(ema, net, config.ema_decay, trained)
            step += 1
            images += 2 * pairs
            tick_images += 2 * pairs
            out_of_time = max_seconds is not None and time.time() - started >= max_seconds
            last = step == end or out_of_time
            values = {k: float(losses[k].detach()) for k in LOSS_FIELDS[:-1] if k in losses}
            values["mover_rmse_cm"] = _mover_rmse_cm(losses, batch)
            for k, v in values.items():
                if math.isfinite(v):
                    sums[k] = sums.get(k, 0.0) + v
            counted += 1
            bar.update(1)
            bar.set_postfix(loss=f"{values['total']:.2f}", rmse_cm=f"{values['mover_rmse_cm']:.0f}")
            if step % config.log_every == 0 or last:
                elapsed = max(1e-9, time.time() - tick)
                log.write({"step": step, "images": images, "lr": f"{learning_rate(step - 1, config, warmup_from):.3g}",
                           **{k: f"{sums.get(k, float('nan')) / max(1, counted):.5f}" for k in LOSS_FIELDS},
                           "images_per_s": f"{tick_images / elapsed:.2f}", "waiting_share": f"{waited / elapsed:.2f}"})
                sums, counted, tick, tick_images, waited = {}, 0, time.time(), 0, 0.0
            if held_out and (step % config.eval_every == 0 or last):
                scores = evaluate(_on_cpu(ema), held_out, config.input_width, config.input_height,
                                  whole_boxes=config.whole_boxes)
                curve.write({"step": step, "images": images,
                             **{k: f"{v:.2f}" for k, v in scores_row(scores).items()}})
                tick, waited = time.time(), 0.0   # evaluation time is not training throughput
            if step % config.checkpoint_every == 0 or last:
                save_state(checkpoint_path, net, optimiser, step, images, config, ema, warmup_from, measured)
            if out_of_time:
                break
            asked = time.time()
    finally:
        batches.close()
        bar.close()
        log.close()
        curve.close()
    return {"step": step, "images": images, "net": net, "ema": ema}


def pair_previous(images: torch.Tensor) -> torch.Tensor:
    """For the B x 2 pairs' images flattened as the network takes them (t-1, t, t-1, t, ...),
    the other frame of each one's pair: the previous frame for t, the next for t-1, so that both
    see the same change (the motion path reads its absolute value)."""
    return images.flip(1).flatten(0, 1)


def training_device(name: str) -> torch.device:
    """The configured device, or a one-line error where this machine has none of that kind."""
    if name == "cpu":
        return torch.device("cpu")
    if name == "cuda":
        if not torch.cuda.is_available():
            raise ValueError("train_v2.device = 'cuda' but this machine's torch sees no CUDA GPU")
        torch.backends.cudnn.benchmark = True   # one input size throughout: pick the fastest kernels once
        return torch.device("cuda")
    raise ValueError(f"train_v2.device must be 'cpu' or 'cuda', got {name!r}")


def training_batch(batch: dict[str, torch.Tensor], device: torch.device) -> dict[str, torch.Tensor]:
    """A collated batch on ``device`` in the types the network and losses take: images
    normalised (``normalisation.normalise``, bit for bit), labels widened to float32, instance
    ids to int64. The dataset hands out compact types so that loader processes copy less."""
    widened = {}
    for key, value in batch.items():
        value = value.to(device, non_blocking=True)
        if key == "image":
            shape = (3, 1, 1)
            value = ((value.float() * (1.0 / 255.0) - value.new_tensor(MEAN, dtype=torch.float32).view(shape))
                     / value.new_tensor(STD, dtype=torch.float32).view(shape))
        elif key == "instance":
            value = value.long()
        elif value.dtype in (torch.float16, torch.uint8):
            value = value.float()
        widened[key] = value
    return widened


def pair_batches(dataset: ContactPairDataset, config: TrainV2Config, first_step: int, end: int,
                 per_epoch: int, device: torch.device) -> Iterator[dict[str, torch.Tensor]]:
    """The batches of steps ``first_step`` .. ``end`` - 1: step s takes the pairs at its place in
    its epoch's order (``epoch_order``), so a run resumed at any step draws what it would have.
    With ``loader_workers`` the same batches are prepared by processes ahead of the loop."""
    steps = _StepPairs(config.seed, config.batch_size, per_epoch, len(dataset), first_step, end)
    if config.loader_workers <= 0:
        for keys in steps:
            yield collate([dataset.sample(item, epoch) for epoch, item in keys])
        return
    import cv2
    from torch.utils.data import DataLoader

    # The loader processes are the parallelism: each resizes on one OpenCV thread. Set here, before
    # they fork (set in a forked process, OpenCV waits for its parent's thread pool forever).
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        loader = DataLoader(_EpochPairs(dataset), batch_sampler=steps, num_workers=config.loader_workers,
                            collate_fn=collate, pin_memory=device.type == "cuda", prefetch_factor=4)
        yield from loader
    finally:
        cv2.setNumThreads(threads)


class _StepPairs:
    """Per step, the (epoch, pair) keys of its batch; iterable again (a DataLoader batch sampler)."""

    def __init__(self, seed: int, batch_size: int, per_epoch: int, pairs: int, first_step: int, end: int):
        self.seed, self.batch_size, self.per_epoch, self.pairs = seed, batch_size, per_epoch, pairs
        self.first_step, self.end = first_step, end

    def __len__(self) -> int:
        return max(0, self.end - self.first_step)

    def __iter__(self) -> Iterator[list[tuple[int, int]]]:
        order_of, order = -1, None
        for step in range(self.first_step, self.end):
            epoch, position = divmod(step, self.per_epoch)
            if epoch != order_of:
                order_of, order = epoch, epoch_order(self.seed, epoch, self.pairs)
            items = order[position * self.batch_size:(position + 1) * self.batch_size]
            yield [(epoch, int(i)) for i in items]


class _EpochPairs:
    """``dataset`` indexed by (epoch, pair) keys, for loader processes that cannot share its epoch."""

    def __init__(self, dataset: ContactPairDataset):
        self.dataset = dataset

    def __len__(self) -> int:
        return len(self.dataset)

    def __getitem__(self, key: tuple[int, int]) -> dict[str, Any]:
        epoch, item = key
        return self.dataset.sample(item, epoch)


def _on_cpu(net: torch.nn.Module) -> torch.nn.Module:
    """``net`` itself on the CPU, else a CPU copy (the evaluation feeds NumPy frames)."""
    if next(net.parameters()).device.type == "cpu":
        return net
    return copy.deepcopy(net).cpu()


def update_average(ema: torch.nn.Module, net: torch.nn.Module, decay: float, prefix: str = "") -> None:
    """Exponential moving average of the weights (and BatchNorm statistics): at a constant
    learning rate the last iterate wanders, and its held-out scores with it; the average is
    what is evaluated and exported. Only entries named with ``prefix`` (all by default): frozen
    parts stay bit for bit."""
    with torch.no_grad():
        for (name, averaged), current in zip(ema.state_dict().items(), net.state_dict().values()):
            if not name.startswith(prefix):
                continue
            if averaged.dtype.is_floating_point:
                averaged.mul_(decay).add_(current, alpha=1 - decay)
            else:
                averaged.copy_(current)


CAMERA_MEASUREMENTS = ("camera_spread_scale", "camera_spread", "camera_error_correlation")
"""State keys that ``python -m heightnet.camera_fresh --write`` adds: how far the camera heads'
guesses fall from unseen cameras, which ``heightpipe export`` puts in the model (the run widens
the heads' spread by it)."""


def camera_measurements(path: Path, head_only: bool) -> dict[str, Any]:
    """The camera heads' measurements held by the state at ``path``, to be written with every
    later state of a head-only run: its camera heads are frozen, so what was measured of them
    still holds. A run that trains them leaves the measurements behind (they would describe heads
    that no longer exist) and says so: measure them again before exporting."""
    state = torch.load(path, map_location="cpu", weights_only=False)
    measured = {key: state[key] for key in CAMERA_MEASUREMENTS if key in state}
    if measured and not head_only:
        print(f"the camera heads train: the measurement of their spread in {path} no longer holds and "
              "is not kept; run python -m heightnet.camera_fresh --write before exporting")
        return {}
    return measured


def save_state(path: Path, net: torch.nn.Module, optimiser: torch.optim.Optimizer, step: int,
               images: int, config: TrainV2Config, ema: torch.nn.Module | None = None,
               warmup_from: int = 0, measured: dict[str, Any] | None = None) -> None:
    """Atomically write the compact state: weights and their average in float32, Adam moments in
    float16, and ``measured`` (``camera_measurements``) as it was."""
    opt = optimiser.state_dict()
    # state_dict() hands out the live per-parameter dicts: build new ones, never edit those.
    opt["state"] = {index: {key: _cpu(_compact(key, value)) for key, value in state.items()}
                    for index, state in opt["state"].items()}
    tmp = path.with_suffix(".tmp")
    torch.save({"model": _cpu_weights(net), "ema": _cpu_weights(ema or net), "optimiser": opt,
                "step": step, "images": images, "warmup_from": warmup_from,
                "architecture": net.arch.to_dict(), "input_size": [config.input_width, config.input_height],
                "config": dataclasses.asdict(config), **(measured or {})}, tmp)
    tmp.replace(path)


def _cpu_weights(net: torch.nn.Module) -> dict[str, torch.Tensor]:
    return {name: value.cpu() for name, value in net.state_dict().items()}


def _cpu(value: Any) -> Any:
    return value.cpu() if isinstance(value, torch.Tensor) else value


def _compact(key: str, value: Any) -> Any:
    if key == "exp_avg":
        return value.to(torch.float16)
    if key == "exp_avg_sq":   # stored as its square root: tiny second moments stay representable
        return value.sqrt().to(torch.float16)
    return value


def trained_prefix(config: TrainV2Config) -> str:
    """The parameters a run trains, by name prefix: the big-object head alone
    (``big_head_only``), the detection head (``head_only``), or everything ("")."""
    if config.big_head_only:
        return BIG_OBJECT_HEAD
    return DETECTION_HEAD if config.head_only else ""


def _freeze_all_but(net: ContactNet, ema: ContactNet, prefix: str) -> None:
    """Only the parameters named ``prefix`` learn (the detection head, or its big-object head):
    every other part takes the averaged weights (what is exported) and keeps them, no gradients,
    running as at inference (BatchNorm on its running statistics), so the head trains on exactly
    the features the exported network gives it."""
    if net.detection_head is None:
        raise ValueError("train_v2.head_only needs the detection head (train_v2.detection = true)")
    if prefix == BIG_OBJECT_HEAD and net.detection_head.big is None:
        raise ValueError("train_v2.big_head_only needs the big-object head (train_v2.detection_big = true)")
    averaged = ema.state_dict()
    with torch.no_grad():
        for name, value in net.state_dict().items():
            if not name.startswith(prefix):
                value.copy_(averaged[name])
    for name, parameter in net.named_parameters():
        parameter.requires_grad_(name.startswith(prefix))
    net.eval()
    net.get_submodule(prefix[:-1]).train()


def load_state(path: Path, net: torch.nn.Module, optimiser: torch.optim.Optimizer | None,
               config: TrainV2Config | None = None, ema: torch.nn.Module | None = None) -> tuple[int, int, int]:
    """Restore a state into ``net`` (and ``optimiser``, ``ema``); returns step, images seen and
    the step the learning-rate warm-up runs from. A state written before the average existed
    starts the average from its weights. A state of a smaller network that this one grows from
    (``ContactArchitecture.grows_from``: new parts that start as no-ops) loads its weights into
    the shared parts; the optimiser then starts afresh and warms up again."""
    state = torch.load(path, map_location="cpu", weights_only=False)
    held = ContactArchitecture.from_dict(state["architecture"])
    grown = False
    if config is not None:
        wanted = architecture_of(config)
        grown = wanted.grows_from(held)
        if (held != wanted and not grown) or state["input_size"] != [config.input_width, config.input_height]:
            raise ValueError(f"cannot resume {path}: it holds {held.to_dict()} at "
                             f"{state['input_size']}, the config asks for {wanted.to_dict()} "
                             f"at {[config.input_width, config.input_height]}")
    for module, weights in ((net, state["model"]), (ema, state.get("ema", state["model"]))):
        if module is None:
            continue
        if grown:
            weights = _widen_first_convolution(weights, module.state_dict())
        missing, unexpected = module.load_state_dict(weights, strict=not grown)
        if unexpected or any(not key.startswith(GROWN_PARTS) for key in missing):
            raise ValueError(f"cannot grow the network of {path}: missing {missing}, unexpected {unexpected}")
    step, images = int(state["step"]), int(state["images"])
    if grown:
        print(f"grew the network of {path} at step {step}: {held.to_dict()} -> {wanted.to_dict()}; "
              "optimiser moments start afresh")
        return step, images, step
    if optimiser is not None:
        opt = state["optimiser"]
        for s in opt["state"].values():
            if "exp_avg" in s:
                s["exp_avg"] = s["exp_avg"].float()
            if "exp_avg_sq" in s:
                s["exp_avg_sq"] = s["exp_avg_sq"].float() ** 2
        optimiser.load_state_dict(_in_groups(opt, net, optimiser))
    return step, images, int(state.get("warmup_from", 0))


def _in_groups(opt: dict, net: torch.nn.Module, optimiser: torch.optim.Optimizer) -> dict:
    """A saved optimiser state re-indexed for ``optimiser``'s groups. States saved before the
    detection head had a group of its own hold one group, indexed in ``net.parameters()`` order;
    ``parameter_groups`` keeps that order within each group, so index i moves to the position its
    parameter has now."""
    groups = optimiser.param_groups
    if len(opt["param_groups"]) == len(groups):
        return opt
    position = {id(p): i for i, p in enumerate(net.parameters())}
    order = [position[id(p)] for group in groups for p in group["params"]]   # new index -> old
    moved = {new: opt["state"][old] for new, old in enumerate(order) if old in opt["state"]}
    saved = opt["param_groups"][0]
    start, regrouped = 0, []
    for group in groups:
        count = len(group["params"])
        regrouped.append({**{k: v for k, v in saved.items() if k != "params"},
                          "params": list(range(start, start + count))})
        start += count
    return {"state": moved, "param_groups": regrouped}


def _widen_first_convolution(weights: dict[str, torch.Tensor], wanted: dict[str, torch.Tensor]
                             ) -> dict[str, torch.Tensor]:
    """A state's weights with its first convolution given zero weights for the input channels
    the grown network adds after the old ones: the new inputs start unseen."""
    weights = dict(weights)
    for key in FIRST_CONVOLUTION:
        if key in weights and key in wanted and weights[key].shape != wanted[key].shape:
            old, new = weights[key], wanted[key]
            if old.shape[0] != new.shape[0] or old.shape[2:] != new.shape[2:] or old.shape[1] > new.shape[1]:
                raise ValueError(f"cannot grow {key} from {tuple(old.shape)} to {tuple(new.shape)}")
            widened = torch.zeros_like(new)
            widened[:, :old.shape[1]] = old
            weights[key] = widened
    return weights


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


def _drop_rows_after(path: Path, step: int) -> None:
    """Remove the rows of a log past ``step``: a run stopped between checkpoints logged steps
    that the resumed run will take, and log, again."""
    if not path.is_file():
        return
    fields, rows = _read_csv(path)
    kept = [row for row in rows if int(row["step"]) <= step]
    if fields and len(kept) < len(rows):
        _write_csv(path, fields, kept)


def _read_csv(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    with path.open(newline="") as f:
        reader = csv.DictReader(f)
        rows = list(reader)
        return list(reader.fieldnames or []), rows


def _write_csv(path: Path, fields: list[str], rows: list[dict[str, str]]) -> None:
    """Rewrites the whole file: header, then ``rows`` (empty in the fields a row lacks)."""
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fields, restval="")
        writer.writeheader()
        writer.writerows(rows)


class _CsvLog:
    """Append-only CSV whose header is taken from the first row written (or given). A file
    written with fewer columns (a network grown since) is rewritten once with the new header,
    its old rows left empty in the new columns."""

    def __init__(self, path: Path, fields: list[str] | None):
        self.path, self.fields = path, fields
        self.file = None

    def write(self, row: dict[str, Any]) -> None:
        if self.file is None:
            fields = self.fields or list(row)
            if self.path.is_file() and self.path.stat().st_size > 0:
                old_fields, old_rows = _read_csv(self.path)
                if old_fields and old_fields != fields:
                    fields = old_fields + [k for k in fields if k not in old_fields]
                    _write_csv(self.path, fields, old_rows)
            fresh = not self.path.is_file() or self.path.stat().st_size == 0
            self.file = self.path.open("a", newline="")
            self.writer = csv.DictWriter(self.file, fields, restval="")
            if fresh:
                self.writer.writeheader()
        self.writer.writerow(row)
        self.file.flush()

    def close(self) -> None:
        if self.file is not None:
            self.file.close()
