"""The camera heads on cameras the network never saw: how wrong, how sure, and can a refit help.

    python -m heightnet.camera_fresh --data DIR [DIR ...] [--state heightnet/state/v2/checkpoint.pt]
                                     [--test DIR ...] [--write]

Why. Told only the camera height, a run takes pitch, roll and focal length from the camera
heads, and their error, not the offsets', is most of its height error (``python -m
heightnet.camera_compare``: held out, people 33.6 cm with the heads' camera, 17.0 with the true
one). The trunk was trained on 1,200 cameras, each seen ~575 times, and the heads have learnt
those scenes rather than the cue: within 1.1 deg of the pitch on them, 3.3 deg on fresh cameras
of the same generator split and 3.8 on held-out ones (docs/results.md, 2026-12-04, ninth
session). Their log-variances learnt the training cameras' errors too, so the spread a run
reports (``pitch 31.2 +-2.4 deg``) was 2.2-2.4 times too small for pitch and focal length on any
camera it had not seen. Fresh cameras are cheap (the generator renders one a second), so both
can be measured, and the spread corrected, on a CPU.

What. Every camera's first frame, whole and squashed to the training input size as a run feeds
it, and its mirror image (roll negated), goes through the frozen encoder once; the pooled
bottleneck the heads read (``contact_model.camera_features``) is kept with the true pitch, roll
and focal length. Then:

* the heads' errors, and their reported spread against them: ``spread_scale`` is the root mean
  square of each quantity's error in units of its reported standard deviation (1 = honest).
  ``--write`` stores it in the state (``camera_spread_scale``); ``heightpipe export`` puts it in
  the model's metadata, and a run multiplies the heads' spread by it (``stages/contact_heights.py``).
  ``error_correlation``, the correlation of those scaled errors (pitch and focal length errors
  go together: the horizon is what the heads see best), is stored and exported beside it; the
  run's fit to the scene's vertical edges needs it (``stages/vertical_edges.py``).
* a refit of the heads on those features (the same two layers, from the trained weights, the
  training loss ``camera_nll``, the epoch with the lowest mean horizon error on a seeded sixth of
  the cameras held back): does anything in the frozen features say more about the camera than
  the heads read? Measured: no (held-out mean horizon error 6.71 -> 6.54 %, best epoch 1), so
  better heads need the trunk trained on many more cameras, and the refit is only reported.

``--test`` datasets are reported only, never chosen or measured on.
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch
from torch import nn

from heightnet.contact_data import camera_targets, synth_pinhole
from heightnet.contact_losses import camera_nll
from heightnet.contact_model import ContactNet, camera_features
from heightnet.normalisation import normalise


@dataclass
class CameraExamples:
    """Pooled bottleneck features (N x F), camera targets (N x 3: pitch, roll, log focal in image
    heights) and the camera each row came from (N; a frame and its mirror share one)."""

    features: np.ndarray
    targets: np.ndarray
    cameras: np.ndarray

    @property
    def camera_count(self) -> int:
        return len(np.unique(self.cameras))

    def subset(self, rows: np.ndarray) -> "CameraExamples":
        return CameraExamples(self.features[rows], self.targets[rows], self.cameras[rows])


@dataclass
class RefitSettings:
    """How the heads are refitted (the training run's learning rate and weight decay)."""

    epochs: int = 60
    lr: float = 1e-3
    weight_decay: float = 1e-4
    batch_size: int = 32
    held_back: float = 1 / 6
    """Share of the cameras kept out of the fit to choose the epoch on."""
    seed: int = 0


def camera_examples(net: ContactNet, sequences, width: int, height: int, progress: bool = False) -> CameraExamples:
    """Features and targets of each generator sequence's first frame and its mirror image."""
    from tqdm import tqdm

    features, targets, cameras = [], [], []
    net.eval()
    for index, seq in enumerate(tqdm(sequences, desc="cameras", unit="camera", disable=not progress)):
        rgb = seq.frame(0).rgb
        target = camera_targets(synth_pinhole(seq.meta.camera), rgb.shape[0])
        image = cv2.resize(rgb, (width, height), interpolation=cv2.INTER_AREA)
        batch = torch.from_numpy(np.stack([normalise(image), normalise(image[:, ::-1].copy())]))
        with torch.no_grad():
            _, bottleneck = net.encode(batch)
            features.append(camera_features(bottleneck).numpy())
        mirrored = target.copy()
        mirrored[1] = -mirrored[1]   # a mirror image's roll is the opposite
        targets += [target, mirrored]
        cameras += [index, index]
    return CameraExamples(np.concatenate(features).astype(np.float32), np.stack(targets).astype(np.float32),
                          np.asarray(cameras))


def held_back_rows(cameras: np.ndarray, share: float, seed: int) -> np.ndarray:
    """Rows of a seeded ``share`` of the cameras (at least one), whole cameras only."""
    unique = np.unique(cameras)
    count = max(1, int(round(share * len(unique))))
    chosen = np.random.default_rng(seed).choice(unique, size=count, replace=False)
    return np.isin(cameras, chosen)


def horizon(values: np.ndarray) -> np.ndarray:
    """Height of the horizon above the image centre, image heights: f tan(pitch) (as the loss's)."""
    return np.exp(values[:, 2]) * np.tan(values[:, 0])


def camera_errors(outputs: np.ndarray, targets: np.ndarray) -> dict[str, float]:
    """Median absolute pitch and roll (degrees), focal length (%), horizon (% of the image height)
    and the mean horizon error (%: its tail is what puts a run's heights off)."""
    focal = np.abs(np.expm1(outputs[:, 2] - targets[:, 2])) * 100
    off = np.abs(horizon(outputs) - horizon(targets)) * 100
    return {"pitch_deg": float(np.degrees(np.median(np.abs(outputs[:, 0] - targets[:, 0])))),
            "roll_deg": float(np.degrees(np.median(np.abs(outputs[:, 1] - targets[:, 1])))),
            "focal_pct": float(np.median(focal)), "horizon_pct": float(np.median(off)),
            "horizon_mean_pct": float(np.mean(off))}


def head_outputs(head: nn.Module, features: np.ndarray) -> np.ndarray:
    with torch.no_grad():
        return head(torch.from_numpy(features)).numpy()


def refit_head(head: nn.Module, fit: CameraExamples, check: CameraExamples,
               settings: RefitSettings) -> tuple[nn.Module, int, list[float]]:
    """A copy of ``head`` trained on ``fit``; the epoch with the lowest mean horizon error on
    ``check`` is returned (0 = the head as given), with that error per epoch (epoch 0 first).

    On one thread: the head's matrices are too small to share out (two threads on a busy
    2-core machine made it 8x slower)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return _refit_head(head, fit, check, settings)
    finally:
        torch.set_num_threads(threads)


def _refit_head(head: nn.Module, fit: CameraExamples, check: CameraExamples,
                settings: RefitSettings) -> tuple[nn.Module, int, list[float]]:
    torch.manual_seed(settings.seed)
    head = copy.deepcopy(head).train()
    optimiser = torch.optim.AdamW(head.parameters(), settings.lr, weight_decay=settings.weight_decay)
    features, targets = torch.from_numpy(fit.features), torch.from_numpy(fit.targets)

    def check_error() -> float:
        return camera_errors(head_outputs(head, check.features), check.targets)["horizon_mean_pct"]

    history = [check_error()]
    best_epoch, best = 0, copy.deepcopy(head.state_dict())
    for epoch in range(1, settings.epochs + 1):
        order = torch.randperm(len(features))
        for start in range(0, len(order), settings.batch_size):
            rows = order[start:start + settings.batch_size]
            loss = camera_nll(head(features[rows]), targets[rows], torch.ones(len(rows), dtype=torch.bool))
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
        history.append(check_error())
        if history[-1] < history[best_epoch]:
            best_epoch, best = epoch, copy.deepcopy(head.state_dict())
    head.load_state_dict(best)
    return head.eval(), best_epoch, history


def scaled_errors(outputs: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """The heads' errors (pitch, roll, log focal) in units of the standard deviation they report
    (``outputs``' last three columns are log-variances, clipped as a run clips them)."""
    from stages.camera_heads import HEAD_VALUES, MAX_ABS_LOG_VAR

    std = np.exp(0.5 * np.clip(outputs[:, HEAD_VALUES:], -MAX_ABS_LOG_VAR, MAX_ABS_LOG_VAR))
    return (outputs[:, :HEAD_VALUES] - targets) / std


def spread_scale(outputs: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """Per quantity, the root mean square of ``scaled_errors``: 1 where the reported spread is
    honest, 2 where it is half what it should be."""
    return np.sqrt(np.mean(scaled_errors(outputs, targets) ** 2, axis=0))


def error_correlation(outputs: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """3 x 3 correlation of ``scaled_errors`` about zero (the errors are not re-centred: a bias is
    part of the error)."""
    z = scaled_errors(outputs, targets)
    second = z.T @ z / len(z)
    norm = np.sqrt(np.diag(second))
    return second / np.outer(norm, norm)


def with_spread_scale(state: dict, scale: np.ndarray, record: dict, correlation: np.ndarray | None = None) -> dict:
    """The training state with ``camera_spread_scale`` and ``camera_error_correlation`` (what
    export writes into the model) and a ``camera_spread`` record of how they were measured."""
    state = dict(state)
    state["camera_spread_scale"] = [float(v) for v in scale]
    if correlation is not None:
        state["camera_error_correlation"] = [[float(v) for v in row] for row in correlation]
    state["camera_spread"] = record
    return state


def generator_settings(folder: Path) -> dict:
    """What made a generator dataset (its manifest's seed, split, size and options): the record
    of a measurement must not name a folder that is gone with the machine."""
    manifest = json.loads((folder / "manifest.json").read_text())
    return {"seed": manifest.get("seed"), "split": manifest.get("split"),
            "sequences": len(manifest.get("sequences", [])), "options": manifest.get("generator_options", {})}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", nargs="+", required=True, metavar="DIR",
                        help="generator datasets of fresh cameras (not the ones the network was trained on)")
    parser.add_argument("--state", default="heightnet/state/v2/checkpoint.pt", help="training state to measure")
    parser.add_argument("--write", action="store_true",
                        help="store the measured spread scale in the state (then `heightpipe export` it)")
    parser.add_argument("--test", nargs="*", default=[], metavar="DIR",
                        help="more datasets to report on (never measured or chosen on)")
    parser.add_argument("--epochs", type=int, default=RefitSettings.epochs, help="refit epochs")
    parser.add_argument("--seed", type=int, default=RefitSettings.seed)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--no-progress", action="store_true")


def main(argv: list[str] | None = None) -> int:
    import datetime

    from heightnet.contact_train import load_network
    from synth.dataset import list_sequences

    parser = argparse.ArgumentParser(prog="python -m heightnet.camera_fresh", description=__doc__.split("\n\n")[0])
    add_arguments(parser)
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    state_path = Path(args.state)
    if not state_path.is_file():
        print(f"error: no training state at {state_path}", file=sys.stderr)
        return 2
    for folder in [*args.data, *args.test]:
        if not (Path(folder) / "manifest.json").is_file():
            print(f"error: {folder} is not a generator dataset (no manifest.json)", file=sys.stderr)
            return 2
    state = torch.load(state_path, map_location="cpu", weights_only=False)
    net = load_network(state_path)
    width, height = state["input_size"]
    settings = RefitSettings(epochs=args.epochs, seed=args.seed)

    def examples(folders: list[str]) -> CameraExamples:
        sequences = [seq for folder in folders for seq in list_sequences(folder)]
        return camera_examples(net, sequences, width, height, progress=not args.no_progress)

    fresh = examples(args.data)
    tests = {Path(folder).name: examples([folder]) for folder in args.test}
    check_rows = held_back_rows(fresh.cameras, settings.held_back, settings.seed)
    fit, check = fresh.subset(~check_rows), fresh.subset(check_rows)
    head, epoch, history = refit_head(net.camera_head, fit, check, settings)

    print(f"refit on {fit.camera_count} fresh cameras, {check.camera_count} held back: "
          f"best epoch {epoch} of {settings.epochs} (held-back mean horizon error {history[0]:.2f} -> "
          f"{history[epoch]:.2f} %)")
    print("| cameras | heads | pitch (deg) | roll (deg) | focal (%) | horizon (%) | horizon mean (%) |")
    print("|---|---|---|---|---|---|---|")
    parts = [("fresh, held back", check), *tests.items()]
    trained = {name: head_outputs(net.camera_head, part.features) for name, part in parts}
    for name, part in parts:
        for label, outputs in (("trained", trained[name]), ("refitted", head_outputs(head, part.features))):
            e = camera_errors(outputs, part.targets)
            print(f"| {name} ({part.camera_count}) | {label} | {e['pitch_deg']:.2f} | {e['roll_deg']:.2f} | "
                  f"{e['focal_pct']:.1f} | {e['horizon_pct']:.2f} | {e['horizon_mean_pct']:.2f} |")
    print("\nthe trained heads' error in units of their reported spread (root mean square; 1 = honest):")
    print("| cameras | pitch | roll | log focal |")
    print("|---|---|---|---|")
    fresh_outputs = head_outputs(net.camera_head, fresh.features)
    scale = spread_scale(fresh_outputs, fresh.targets)
    correlation = error_correlation(fresh_outputs, fresh.targets)
    for name, part in [(f"fresh, all {fresh.camera_count} (the scale)", fresh), *tests.items()]:
        z = scale if part is fresh else spread_scale(trained[name], part.targets)
        print(f"| {name} | {z[0]:.2f} | {z[1]:.2f} | {z[2]:.2f} |")
    print(f"correlation of those errors on the fresh cameras: pitch-roll {correlation[0, 1]:.2f}, "
          f"pitch-focal {correlation[0, 2]:.2f}, roll-focal {correlation[1, 2]:.2f}")
    if args.write:
        record = {"datasets": [generator_settings(Path(f)) for f in args.data],
                  "cameras": fresh.camera_count, "measured": datetime.date.today().isoformat()}
        tmp = state_path.with_suffix(".tmp")
        torch.save(with_spread_scale(state, scale, record, correlation), tmp)
        tmp.replace(state_path)
        print(f"wrote the spread scale and error correlation into {state_path} (now `heightpipe export` it)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
