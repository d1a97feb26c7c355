import json

import cv2
import numpy as np
import pytest

from heightnet.data import Augmentation, PairDataset, apply_colour, match_features
from heightnet.losses import sample_at


def test_matches_join_points_of_equal_true_height_on_the_same_mover(cached_sequences):
    seq = cached_sequences[0]
    total = 0
    for t in range(1, len(seq)):
        m = seq.matches(t)
        total += len(m)
        h0 = seq.height_m[t - 1][np.round(m[:, 1]).astype(int), np.round(m[:, 0]).astype(int)]
        h1 = seq.height_m[t][np.round(m[:, 3]).astype(int), np.round(m[:, 2]).astype(int)]
        # Billboards move sideways at a fixed distance: a tracked point keeps its height.
        assert np.nanmedian(np.abs(h0.astype(float) - h1.astype(float))) < 0.1
    assert total > 10


def test_matches_across_different_instances_are_rejected():
    rgb = np.random.default_rng(0).integers(0, 255, (40, 40, 3), dtype=np.uint8)
    ids0 = np.zeros((40, 40), np.uint16)
    ids0[5:35, 5:35] = 1
    ids1 = np.where(ids0 > 0, 2, 0).astype(np.uint16)   # same pixels, another object's id
    assert len(match_features(rgb, rgb, ids0, ids0)) > 0
    assert len(match_features(rgb, rgb, ids0, ids1)) == 0


def test_augmented_pairs_keep_matches_on_equal_targets(cached_sequences):
    dataset = PairDataset(cached_sequences, 64, 48, "relative", Augmentation(), max_matches=32)
    checked = 0
    for i in range(len(dataset)):
        item = dataset[i]
        assert item["image"].shape == (2, 3, 48, 64) and item["target"].shape == (2, 1, 48, 64)
        m = item["matches"][item["match_valid"]]
        if not len(m):
            continue
        import torch

        target = torch.nan_to_num(torch.from_numpy(item["target"]))
        mover = torch.from_numpy(item["mover"]).float()
        near0 = sample_at(mover[:1], torch.from_numpy(m[None, :, :2]))[0]
        near1 = sample_at(mover[1:], torch.from_numpy(m[None, :, 2:]))[0]
        keep = (near0 > 0.99) & (near1 > 0.99)   # away from object edges after resizing
        h0 = sample_at(target[:1], torch.from_numpy(m[None, :, :2]))[0][keep]
        h1 = sample_at(target[1:], torch.from_numpy(m[None, :, 2:]))[0][keep]
        if len(h0):
            assert float((h0 - h1).abs().median()) < 0.03   # relative units (~10 cm at 3.5 m)
            checked += 1
    assert checked > 0


def test_same_item_same_epoch_is_deterministic(cached_sequences):
    dataset = PairDataset(cached_sequences, 64, 48, "relative", Augmentation())
    a, b = dataset[2], dataset[2]
    assert np.array_equal(a["image"], b["image"]) and np.array_equal(a["matches"], b["matches"])
    dataset.epoch = 1
    assert not np.array_equal(dataset[2]["image"], a["image"])


def test_dataset_hash_names_every_dataset_a_model_was_trained_on(tmp_path):
    from heightnet.data import dataset_hash

    for name, sequences in (("a", ["seq00000"]), ("b", ["seq00001"])):
        (tmp_path / name).mkdir()
        (tmp_path / name / "manifest.json").write_text(json.dumps({"sequences": sequences}))
    a, b = tmp_path / "a", tmp_path / "b"
    assert dataset_hash(a) == dataset_hash([a])
    assert dataset_hash([a, b]) not in (dataset_hash(a), dataset_hash(b))
    assert dataset_hash([a, b], {"seed": 0}) != dataset_hash([a, b], {"seed": 1})


@pytest.mark.parametrize("params", [[1.0, 1.0, 1.0], [1.25, 0.75, 1.3], [0.75, 1.25, 0.7], [1.2, 1.2, 0.0]])
def test_colour_jitter_is_the_three_steps_in_one_colour_matrix(params):
    """Brightness, contrast about the mean, saturation about each pixel's grey, clipped: the one
    OpenCV pass agrees with the steps done in floats to one grey level, flipped views included."""
    rgb = cv2.GaussianBlur(np.random.default_rng(1).integers(0, 256, (60, 80, 3), dtype=np.uint8), (5, 5), 1)
    brightness, contrast, saturation = params
    x = rgb.astype(np.float64) * brightness
    x = (x - x.mean()) * contrast + x.mean()
    grey = x.mean(axis=2, keepdims=True)
    steps = np.clip((x - grey) * saturation + grey, 0, 255).astype(np.uint8)
    for image, expected in ((rgb, steps), (rgb[:, ::-1], steps[:, ::-1])):
        got = apply_colour(image, params)
        assert got.dtype == np.uint8 and got.shape == image.shape
        assert np.abs(got.astype(int) - expected.astype(int)).max() <= 1
