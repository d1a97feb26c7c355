"""Train the box refiner (stages/box_refinement.py) on a detection model's own people's boxes.

    python -m heightnet.box_refiner data/v2_ma data/v2_mb --out stages/models/box_refiner.onnx

For every frame of the training sequences the detection model runs as it does in a run (the
frame squashed to its input, ``HeightNetModel.run``); each of its person boxes that overlaps a
walker in view (IoU >= ``MIN_IOU``, at least ``MIN_VISIBLE`` of the walker in view) becomes a
sample: the crop around the box (``box_crops``) and how far each of the walker's true edges lies
from the box's, in shares of the box's width and height. The refiner learns those offsets with an
L1 loss measured in input pixels (what the edges are off by), on mirrored crops too (the left edge
becomes the right), and on boxes nudged at random by up to ``JITTER`` of their size, so that it
also sees boxes the head might have drawn. Only training-split sequences may be given (held-out
layouts stay held out); ``--check`` reports the edges before and after on other sequences.

The refiner learns one model's errors: after the detection head is trained again, train this
again (its metadata records the model's SHA-256, and ``height.box_refiner = "auto"`` refines only
that model's boxes).
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch
import torch.nn as nn

from stages.box_refinement import (CROPS_INPUT, EDGES_OUTPUT, SIZES_INPUT, box_crops, file_digest, refiner_inputs)
from stages.centre_detections import box_iou

CROP_SIZE = (32, 64)
"""Width, height of the refiner's crops: a walker's box is about twice as tall as wide."""
MARGIN = (0.5, 0.25)
"""The crop holds the box grown by half its width at each side and a quarter of its height above
and below: room for edges the head drew up to that far inside the walker."""
REFINED_CLASSES = ("person",)
MIN_IOU = 0.3
MIN_VISIBLE = 0.5
JITTER = 0.05
"""Each edge of a nudged box moves by up to this share of the box's size (uniform)."""
NUDGED_SHARE = 0.5
WIDTH = 32
OPSET = 17


@dataclass
class RefinerSamples:
    """Person boxes of a detection model with the true boxes of the walkers they are about, in
    the input pixels of the image each was read from (``images[image_index[i]]``)."""

    images: list[np.ndarray]
    image_index: np.ndarray
    head: np.ndarray
    truth: np.ndarray

    def __len__(self) -> int:
        return len(self.image_index)


class BoxRefinerNet(nn.Module):
    """Crop (3 x 64 x 32) and log box size -> the four edges' offsets (left, top, right,
    bottom) in shares of the box's width and height. 3x3 convolutions in two stride-2 stages keep
    the crop's layout (an edge is a place in it, so the features are not pooled away); few
    channels at the crop's full size, where a convolution costs most (about 15 million
    multiply-adds a box); a 1x1 convolution narrows them before the one hidden layer."""

    def __init__(self, width: int = WIDTH, crop_size: tuple[int, int] = CROP_SIZE):
        super().__init__()

        def block(cin: int, cout: int, stride: int) -> nn.Sequential:
            return nn.Sequential(nn.Conv2d(cin, cout, 3, stride, 1, bias=False), nn.BatchNorm2d(cout), nn.ReLU())

        self.features = nn.Sequential(block(3, width // 2, 1), block(width // 2, width, 2), block(width, width, 1),
                                      block(width, 2 * width, 2), block(2 * width, 2 * width, 1),
                                      nn.Conv2d(2 * width, width // 2, 1), nn.ReLU())
        cells = (crop_size[0] // 4) * (crop_size[1] // 4)
        self.hidden = nn.Linear(width // 2 * cells + 2, 128)
        self.edges = nn.Linear(128, 4)
        nn.init.zeros_(self.edges.weight)
        nn.init.zeros_(self.edges.bias)

    def forward(self, crops: torch.Tensor, log_size: torch.Tensor) -> torch.Tensor:
        x = torch.cat([self.features(crops).flatten(1), log_size], 1)
        return self.edges(torch.relu(self.hidden(x)))


def collect_samples(sequences, model, progress: bool = True) -> RefinerSamples:
    """Run the detection ``model`` (a ``HeightNetModel`` without a refiner) on every frame of
    ``sequences`` (``SynthSequence``s: ``image_bgr`` and ``objects`` of each frame) and pair its
    person boxes with the walkers in view, one-to-one by IoU."""
    from scipy.optimize import linear_sum_assignment
    from tqdm import tqdm

    from synth.dataset import COARSE_CLASS

    size = (model.info.input_width, model.info.input_height)
    images, index, head, truth = [], [], [], []
    for sequence in tqdm(sequences, desc="refiner samples", unit="seq", disable=not progress):
        for frame in range(len(sequence)):
            bgr = sequence.image_bgr(frame)
            found = model.run(bgr).detections
            walkers = [o for o in sequence.objects(frame)
                       if COARSE_CLASS.get(o.cls) == "person" and o.visible_fraction >= MIN_VISIBLE]
            people = [i for i, c in enumerate(found.classes) if c in REFINED_CLASSES]
            if not walkers or not people:
                continue
            scale = np.array([size[0] / bgr.shape[1], size[1] / bgr.shape[0]] * 2, np.float32)
            boxes = found.boxes[people] * scale
            true = np.array([[x, y, x + w, y + h] for x, y, w, h in (o.box for o in walkers)], np.float32) * scale
            iou = box_iou(boxes, true)
            rows, cols = linear_sum_assignment(-iou)
            pairs = [(r, c) for r, c in zip(rows, cols) if iou[r, c] >= MIN_IOU]
            if not pairs:
                continue
            images.append(cv2.resize(bgr, size, interpolation=cv2.INTER_AREA))
            for r, c in pairs:
                index.append(len(images) - 1)
                head.append(boxes[r])
                truth.append(true[c])
    return RefinerSamples(images, np.array(index, np.int64), np.array(head, np.float32).reshape(-1, 4),
                          np.array(truth, np.float32).reshape(-1, 4))


def edge_targets(boxes: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """How far each true edge lies from the box's (left, top, right, bottom), in shares of the
    box's width and height: what the refiner predicts."""
    w, h = boxes[:, 2] - boxes[:, 0], boxes[:, 3] - boxes[:, 1]
    return ((truth - boxes) / np.stack([w, h, w, h], 1)).astype(np.float32)


def nudged(boxes: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """``boxes`` with ``NUDGED_SHARE`` of them moved: each edge by up to ``JITTER`` of the size."""
    w, h = boxes[:, 2] - boxes[:, 0], boxes[:, 3] - boxes[:, 1]
    shift = rng.uniform(-JITTER, JITTER, boxes.shape) * np.stack([w, h, w, h], 1)
    shift *= (rng.random(len(boxes)) < NUDGED_SHARE)[:, None]
    return (boxes + shift).astype(np.float32)


def batch_tensors(samples: RefinerSamples, rows: np.ndarray, boxes: np.ndarray, mirror: np.ndarray):
    """The refiner's inputs and targets for ``rows`` read at ``boxes``; rows flagged in ``mirror``
    are read as from the mirrored image: ``box_crops`` maps pixel centres, so that crop is this one
    flipped, and the box's left and right edges swap (each target negated)."""
    crops = np.stack([box_crops(samples.images[samples.image_index[row]], box[None], CROP_SIZE, MARGIN)[0]
                      for row, box in zip(rows, boxes)])
    targets = edge_targets(boxes, samples.truth[rows])
    crops[mirror] = crops[mirror][:, :, ::-1]
    targets[mirror] = targets[mirror][:, [2, 1, 0, 3]] * np.array([-1, 1, -1, 1], np.float32)
    pixels, sizes = refiner_inputs(crops, boxes)
    return torch.from_numpy(pixels), torch.from_numpy(sizes), torch.from_numpy(targets)


def pixel_error(edges: torch.Tensor, targets: torch.Tensor, boxes: np.ndarray) -> torch.Tensor:
    """|edge offset error| in input pixels, N x 4."""
    w = torch.from_numpy(boxes[:, 2] - boxes[:, 0])
    h = torch.from_numpy(boxes[:, 3] - boxes[:, 1])
    return ((edges - targets) * torch.stack([w, h, w, h], 1)).abs()


def train_refiner(samples: RefinerSamples, epochs: int, seed: int, batch: int = 128,
                  learning_rate: float = 2e-3, progress: bool = True) -> BoxRefinerNet:
    """A refiner trained on ``samples`` (one-cycle AdamW, seeded)."""
    from tqdm import tqdm

    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    net = BoxRefinerNet()
    steps = epochs * -(-len(samples) // batch)
    optimiser = torch.optim.AdamW(net.parameters(), learning_rate / 2, weight_decay=1e-4)
    schedule = torch.optim.lr_scheduler.OneCycleLR(optimiser, learning_rate, total_steps=steps)
    bar = tqdm(total=steps, desc="refiner training", unit="step", disable=not progress)
    for _ in range(epochs):
        net.train()
        order = rng.permutation(len(samples))
        for start in range(0, len(order), batch):
            rows = order[start:start + batch]
            boxes = nudged(samples.head[rows], rng)
            pixels, sizes, targets = batch_tensors(samples, rows, boxes, rng.random(len(rows)) < 0.5)
            loss = pixel_error(net(pixels, sizes), targets, boxes).mean()
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            schedule.step()
            bar.update(1)
            bar.set_postfix(px=f"{loss.item():.2f}")
    bar.close()
    return net.eval()


def edge_errors(net: BoxRefinerNet, samples: RefinerSamples) -> tuple[np.ndarray, np.ndarray]:
    """Mean |error| of each edge (left, top, right, bottom; input pixels) of the samples' boxes as
    the head drew them and as refined."""
    rows = np.arange(len(samples))
    boxes = samples.head
    pixels, sizes, targets = batch_tensors(samples, rows, boxes, np.zeros(len(rows), bool))
    with torch.no_grad():
        refined = pixel_error(net(pixels, sizes), targets, boxes).mean(0).numpy()
    head = pixel_error(torch.zeros_like(targets), targets, boxes).mean(0).numpy()
    return head, refined


def export_refiner(net: BoxRefinerNet, out: Path, model_sha256: str) -> int:
    """Write ``net`` as ONNX (any number of crops) with the metadata ``BoxRefiner`` reads; checks
    that ONNX Runtime gives what PyTorch does. Returns the file's size in bytes."""
    import onnxruntime as ort

    from heightnet.export import save_with_metadata

    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".tmp.onnx")
    generator = torch.Generator().manual_seed(0)
    example = (torch.rand(3, 3, CROP_SIZE[1], CROP_SIZE[0], generator=generator) - 0.5,
               torch.randn(3, 2, generator=generator))
    torch.onnx.export(net.eval(), example, str(tmp), input_names=[CROPS_INPUT, SIZES_INPUT],
                      output_names=[EDGES_OUTPUT], opset_version=OPSET, do_constant_folding=True, dynamo=False,
                      dynamic_axes={CROPS_INPUT: {0: "boxes"}, SIZES_INPUT: {0: "boxes"}, EDGES_OUTPUT: {0: "boxes"}})
    save_with_metadata(tmp, out, {"heightpipe.crop_size": json.dumps(list(CROP_SIZE)),
                                  "heightpipe.margin": json.dumps(list(MARGIN)),
                                  "heightpipe.refined_classes": json.dumps(list(REFINED_CLASSES)),
                                  "heightpipe.detection_model_sha256": model_sha256})
    with torch.no_grad():
        expected = net(*example).numpy()
    session = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    got = session.run([EDGES_OUTPUT], {CROPS_INPUT: example[0].numpy(), SIZES_INPUT: example[1].numpy()})[0]
    if float(np.abs(got - expected).max()) > 1e-4:
        raise ValueError(f"ONNX Runtime differs from PyTorch in {out}")
    return out.stat().st_size


def main(argv: list[str] | None = None) -> None:
    from stages.heightnet_model import HeightNetModel, model_file
    from synth.dataset import list_sequences

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", type=Path, nargs="+", help="synth datasets (their training-split sequences)")
    parser.add_argument("--out", type=Path, required=True, help="the refiner's ONNX file")
    parser.add_argument("--model", default="v2", help="the detection model whose boxes it refines (default: v2)")
    parser.add_argument("--epochs", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--check", type=Path, action="append", default=[],
                        help="synth dataset whose sequences (any split) report the edges before and after")
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args(argv)
    for path in [*args.data, *args.check]:
        if not path.is_dir():
            raise SystemExit(f"heightpipe: error: not a synth dataset folder: {path}")
    if args.epochs < 1:
        raise SystemExit(f"heightpipe: error: --epochs must be at least 1, got {args.epochs}")
    model = HeightNetModel(model_file(args.model))
    if not model.info.detection:
        raise SystemExit(f"heightpipe: error: {model.path} has no detection head to refine")
    sequences = [s for path in args.data for s in list_sequences(path, split="train")]
    if not sequences:
        raise SystemExit(f"heightpipe: error: no training-split sequences under {', '.join(map(str, args.data))}")
    samples = collect_samples(sequences, model, progress=not args.no_progress)
    if len(samples) == 0:
        raise SystemExit("heightpipe: error: the model boxed no walker in these sequences: nothing to learn from")
    print(f"{len(samples)} person boxes from {len(samples.images)} frames", file=sys.stderr)
    net = train_refiner(samples, args.epochs, args.seed, progress=not args.no_progress)
    size = export_refiner(net, args.out, file_digest(model.path))
    print(f"wrote {args.out} ({size / 1e6:.2f} MB)")
    for path in args.check:
        check = collect_samples(list_sequences(path), model, progress=not args.no_progress)
        head, refined = edge_errors(net, check)
        def edges(errors: np.ndarray) -> str:
            return " / ".join(f"{v:.2f}" for v in errors) + f" (mean {errors.mean():.2f})"

        print(f"{path}: {len(check)} person boxes, |edge error| in input px (left / top / right / bottom): "
              f"head {edges(head)} -> refined {edges(refined)}")


if __name__ == "__main__":
    main()
