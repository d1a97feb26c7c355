"""Training losses: scale-invariant log loss, height consistency between frames, ground BCE."""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from heightnet.encoding import HeightEncoding


def scale_invariant_log_loss(encoded: torch.Tensor, target: torch.Tensor, encoding: HeightEncoding,
                             mask: torch.Tensor, lam: float = 0.85) -> torch.Tensor:
    """Eigen et al. (2014), the paper's Eq. 1, per image then averaged over images with pixels.

    ``encoded`` is the network's log(target + offset); ``target`` the height (relative or metres),
    ground = 0. d = encoded - log(target + offset); loss = sqrt(mean d^2 - lam * mean(d)^2).
    """
    d = (encoded - torch.log(target.clamp(min=0) + encoding.offset)) * mask
    n = mask.flatten(1).sum(1)
    has = n > 0
    if not has.any():
        return encoded.sum() * 0.0
    n = n[has]
    d = d.flatten(1)[has]
    mean_sq = (d * d).sum(1) / n
    mean = d.sum(1) / n
    return torch.sqrt((mean_sq - lam * mean * mean).clamp(min=1e-8)).mean()


def sample_at(values: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Bilinear samples of B x 1 x H x W ``values`` at B x K x 2 pixel coordinates (x, y): B x K."""
    h, w = values.shape[-2:]
    grid = torch.stack([(points[..., 0] + 0.5) / w * 2 - 1, (points[..., 1] + 0.5) / h * 2 - 1], -1)
    return F.grid_sample(values, grid[:, :, None], mode="bilinear", align_corners=False)[:, 0, :, 0]


def height_consistency_loss(height_prev: torch.Tensor, height_next: torch.Tensor,
                            matches: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """The paper's Eq. 2: mean squared height difference of matched points in frames t-1 and t.

    Heights are decoded (not log) and in metres, so the loss is in m^2 whatever the target units.
    """
    if not valid.any():
        return height_prev.sum() * 0.0
    h0 = sample_at(height_prev, matches[..., :2])
    h1 = sample_at(height_next, matches[..., 2:])
    return ((h1 - h0) ** 2)[valid].mean()


def ground_loss(ground_logit: torch.Tensor, ground: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    loss = F.binary_cross_entropy_with_logits(ground_logit, ground, reduction="none")
    return (loss * mask).sum() / mask.sum().clamp(min=1)


@dataclass
class LossWeights:
    si_lambda: float = 0.85
    above_ground: float = 1.0
    above_ground_lambda: float = 0.0
    consistency: float = 1.0
    ground: float = 0.2


def heightnet_loss(encoded: torch.Tensor, ground_logit: torch.Tensor, batch: dict[str, torch.Tensor],
                   encoding: HeightEncoding, weights: LossWeights,
                   above_ground_threshold_m: float = 0.1) -> dict[str, torch.Tensor]:
    """All loss terms for a batch of B pairs (network outputs B*2 x 1 x H x W, pairs interleaved).

    total = SI(all labelled pixels) + above_ground * SI'(pixels above 0.1 m)
            + consistency * L_h(matched mover points) + ground * BCE(ground plane)
    The extra above-ground term keeps the few object pixels from drowning in ground pixels. Its
    own lambda defaults to 0 (plain log RMSE): with the paper's 0.85 a uniform under-estimate of
    every object costs only 15 % of its squared log error, and a model trained so read object
    heights at 0.62x truth (median over held-out mover pixels).
    """
    target = batch["target"].flatten(0, 1)
    labelled = torch.isfinite(target)
    target = torch.nan_to_num(target, nan=0.0)
    camera = batch["camera_height_m"].repeat_interleave(2)[:, None, None, None]
    threshold = above_ground_threshold_m / camera if encoding.target == "relative" \
        else torch.full_like(camera, above_ground_threshold_m)
    above = labelled & (target > threshold)
    si_all = scale_invariant_log_loss(encoded, target, encoding, labelled.float(), weights.si_lambda)
    si_above = scale_invariant_log_loss(encoded, target, encoding, above.float(),
                                        weights.above_ground_lambda)
    # Clamped before exp: an early wild prediction must not blow the squared loss up.
    decoded = torch.relu(torch.exp(encoded.clamp(max=3.5)) - encoding.offset)
    metres = encoding.metres_from_output(decoded, camera)
    pairs = metres.unflatten(0, (-1, 2))
    consistency = height_consistency_loss(pairs[:, 0], pairs[:, 1], batch["matches"],
                                          batch["match_valid"])
    ground = ground_loss(ground_logit, batch["ground"].flatten(0, 1), labelled.float())
    total = si_all + weights.above_ground * si_above + weights.consistency * consistency \
        + weights.ground * ground
    return {"total": total, "si": si_all, "si_above": si_above, "consistency": consistency,
            "ground": ground}
