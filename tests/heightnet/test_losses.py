import math

import torch

from heightnet.encoding import HeightEncoding
from heightnet.losses import height_consistency_loss, sample_at, scale_invariant_log_loss

ENC = HeightEncoding("relative")


def encode(target):
    return torch.log(target + ENC.offset)


def test_scale_invariant_loss_is_zero_for_a_perfect_prediction():
    target = torch.rand(2, 1, 8, 8) * 0.5
    mask = torch.ones_like(target)
    assert float(scale_invariant_log_loss(encode(target), target, ENC, mask)) < 1e-3


def test_scale_invariant_loss_forgives_a_global_log_shift_more_than_noise():
    torch.manual_seed(0)
    target = torch.rand(1, 1, 16, 16) * 0.5
    mask = torch.ones_like(target)
    shift = torch.full_like(target, 0.3)
    noise = torch.randn_like(target)
    noise = noise / noise.pow(2).mean().sqrt() * 0.3  # same mean square as the shift
    shifted = scale_invariant_log_loss(encode(target) + shift, target, ENC, mask, lam=0.85)
    noisy = scale_invariant_log_loss(encode(target) + noise, target, ENC, mask, lam=0.85)
    assert math.isclose(float(shifted), 0.3 * math.sqrt(0.15), rel_tol=1e-3)
    assert float(noisy) > 2 * float(shifted)
    fully_invariant = scale_invariant_log_loss(encode(target) + shift, target, ENC, mask, lam=1.0)
    assert float(fully_invariant) < 1e-3


def test_scale_invariant_loss_ignores_masked_pixels():
    target = torch.rand(1, 1, 8, 8)
    prediction = encode(target).clone()
    prediction[..., :4, :] += 5.0
    mask = torch.zeros_like(target)
    mask[..., 4:, :] = 1
    assert float(scale_invariant_log_loss(prediction, target, ENC, mask)) < 1e-3


def test_consistency_loss_zero_for_equal_heights_at_matches_and_positive_otherwise():
    prev = torch.zeros(1, 1, 10, 10)
    nxt = torch.zeros(1, 1, 10, 10)
    prev[0, 0, 2, 3] = 1.7   # a head at (x=3, y=2) in frame t-1 ...
    nxt[0, 0, 2, 6] = 1.7    # ... moved to (x=6, y=2) in frame t
    matches = torch.tensor([[[3.0, 2.0, 6.0, 2.0], [0, 0, 0, 0]]])
    valid = torch.tensor([[True, False]])
    assert float(height_consistency_loss(prev, nxt, matches, valid)) == 0.0
    nxt[0, 0, 2, 6] = 1.2
    assert math.isclose(float(height_consistency_loss(prev, nxt, matches, valid)), 0.25, rel_tol=1e-5)


def test_sample_at_reads_pixel_centres():
    values = torch.arange(12.0).reshape(1, 1, 3, 4)
    points = torch.tensor([[[0.0, 0.0], [3.0, 2.0], [1.5, 1.0]]])
    assert torch.allclose(sample_at(values, points), torch.tensor([[0.0, 11.0, 5.5]]), atol=1e-5)
