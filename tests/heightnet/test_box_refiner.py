"""Training the box refiner: samples from a model's boxes, targets, mirrored reads, learning, export."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import onnxruntime as ort
import torch

from core.packets import NetworkDetections
from heightnet.box_refiner import (RefinerSamples, batch_tensors, collect_samples, edge_errors, edge_targets,
                                   export_refiner, train_refiner, BoxRefinerNet)
from stages.box_refinement import CROPS_INPUT, EDGES_OUTPUT, SIZES_INPUT
from synth.dataset import ObjectTruth


def _block_samples(count: int = 64, seed: int = 0) -> RefinerSamples:
    """Dark blocks on light images, each boxed 2-3 px too wide on the left and too short at the
    foot: what a refiner must learn to undo."""
    rng = np.random.default_rng(seed)
    images, head, truth = [], [], []
    for _ in range(count):
        image = np.full((96, 128, 3), 190, np.uint8) + rng.integers(0, 20, (96, 128, 3), dtype=np.uint8)
        w, h = rng.uniform(10, 18), rng.uniform(24, 40)
        x0, y0 = rng.uniform(20, 128 - w - 20), rng.uniform(15, 96 - h - 15)
        image[int(round(y0)):int(round(y0 + h)), int(round(x0)):int(round(x0 + w))] = 30
        truth.append([round(x0), round(y0), round(x0 + w), round(y0 + h)])
        head.append([truth[-1][0] - rng.uniform(2, 3), truth[-1][1], truth[-1][2], truth[-1][3] - rng.uniform(2, 3)])
        images.append(image)
    return RefinerSamples(images, np.arange(count), np.array(head, np.float32), np.array(truth, np.float32))


def test_targets_are_the_true_edges_offsets_in_shares_of_the_box():
    targets = edge_targets(np.array([[10, 20, 30, 60]], np.float32), np.array([[12, 18, 30, 64]], np.float32))
    np.testing.assert_allclose(targets, [[0.1, -0.05, 0.0, 0.1]])


def test_a_mirrored_read_swaps_the_left_and_right_edges():
    samples = _block_samples(2)
    rows = np.array([0, 1])
    plain = batch_tensors(samples, rows, samples.head.copy(), np.array([False, False]))
    mirrored = batch_tensors(samples, rows, samples.head.copy(), np.array([True, True]))
    # The left edge was drawn too far out; mirrored, that error is the right edge's.
    np.testing.assert_allclose(mirrored[2][:, [2, 1, 0, 3]].numpy(), -plain[2].numpy() * [1, -1, 1, -1], atol=1e-6)
    # The same pixels, mirrored (OpenCV rounds a few interpolations the other way).
    np.testing.assert_allclose(mirrored[0].numpy(), plain[0].numpy()[..., ::-1], atol=1.01 / 255)


def test_training_learns_the_heads_steady_errors():
    samples, held_out = _block_samples(192, seed=1), _block_samples(64, seed=2)
    net = train_refiner(samples, epochs=6, seed=0, batch=32, progress=False)
    head, refined = edge_errors(net, held_out)
    assert head[0] > 2.0 and head[3] > 2.0
    assert refined[0] < 0.6 * head[0] and refined[3] < 0.6 * head[3]


def test_the_export_runs_as_the_network_does(tmp_path):
    torch.manual_seed(0)
    net = BoxRefinerNet().eval()
    torch.nn.init.normal_(net.edges.weight, std=0.01)
    path = tmp_path / "r.onnx"
    assert export_refiner(net, path, "abc") > 0
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    crops = np.random.default_rng(0).random((5, 3, 64, 32)).astype(np.float32) - 0.5
    sizes = np.zeros((5, 2), np.float32)
    got = session.run([EDGES_OUTPUT], {CROPS_INPUT: crops, SIZES_INPUT: sizes})[0]
    with torch.no_grad():
        expected = net(torch.from_numpy(crops), torch.from_numpy(sizes)).numpy()
    np.testing.assert_allclose(got, expected, atol=1e-5)


@dataclass
class _Info:
    input_width: int = 64
    input_height: int = 48


class _FakeModel:
    """Boxes every frame's walker 1 px too far left at half the frame's scale, and one car."""

    info = _Info()

    def run(self, bgr):
        return _Outputs(NetworkDetections(np.array([[19, 10, 40, 50], [60, 60, 100, 90]], np.float32),
                                          ("person", "vehicle"), np.array([0.9, 0.9], np.float32)))


@dataclass
class _Outputs:
    detections: NetworkDetections


class _Sequence:
    def __len__(self):
        return 2

    def image_bgr(self, i):
        return np.zeros((96, 128, 3), np.uint8)

    def objects(self, i):
        return [ObjectTruth(id=1, cls="pedestrian", box=(20.0, 10.0, 20.0, 40.0), visible_fraction=1.0 - 0.6 * i,
                            height_m=1.7, ground_xy_m=(0.0, 0.0))]


def test_samples_pair_the_models_person_boxes_with_walkers_in_view_at_the_input_scale():
    samples = collect_samples([_Sequence()], _FakeModel(), progress=False)
    # Frame 1's walker is mostly hidden (40 % in view): not a sample; the car is not refined.
    assert len(samples) == 1 and len(samples.images) == 1 and samples.images[0].shape == (48, 64, 3)
    np.testing.assert_allclose(samples.head[0], [9.5, 5, 20, 25])
    np.testing.assert_allclose(samples.truth[0], [10, 5, 20, 25])
