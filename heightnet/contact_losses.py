"""HeightNet v2 losses: offsets, metric height, the paper's two losses, ground and camera.

Every pixel term is averaged per object where objects matter: a far person of 40 pixels must
count for more than its pixel share next to a bus of 4,000, so mover pixels are weighted by
1/sqrt(pixels of their object) (each object then weighs sqrt of its size, not its size).

    total = offsets(movers, per object) + offset_all * offsets(every labelled pixel)
          + height * metric height(movers, decoded with the true camera, per object)
          + si * scale-invariant log loss (paper Eq. 1) on decoded mover heights
          + consistency * paper Eq. 2 on decoded heights at matched points of frames t-1, t
          + ground * BCE(ground plane; every pixel, plus movers per object)
          + camera * (Huber fit + NLL of the variance) of the camera heads (whole frames)
          + detection * (CenterNet focal loss on centre heatmaps + L1 on centre offsets and log
            box sizes at object centres), when the network has a detection head
          + big_objects * (the same two terms of the big-object head at 1/16), when it has one
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from stages.ground_contact import torch_heights_from_offsets
from heightnet.contact_model import BIG_STRIDE, BOX_UNIT_PX, DETECTION_STRIDE
from heightnet.losses import sample_at

ABOVE_GROUND_M = 0.1
# Huber transition points: offsets in input pixels, heights in metres.
OFFSET_DELTA_PX = 1.0
HEIGHT_DELTA_M = 0.05
LOG_OFFSET_M = 0.05
# The camera heads' log-variance is kept above this so that one easy image cannot claim
# certainty (and an infinite weight).
MIN_LOG_VARIANCE = -12.0
# Camera errors that count as one unit of the heads' fit loss: pitch and roll 0.05 rad (3 deg),
# log focal length 0.1 (10 %).
CAMERA_SCALE = (0.05, 0.05, 0.1)
# One unit of the horizon term: the horizon's height above the image centre, f tan(pitch), off by
# 2 % of the image height.
HORIZON_SCALE = 0.02


@dataclass
class ContactLossWeights:
    offset_all: float = 0.3
    height: float = 10.0
    si: float = 1.0
    consistency: float = 1.0
    ground: float = 0.2
    camera: float = 0.1
    detection: float = 1.0
    box_giou: float = 0.0
    big_objects: float = 1.0


# Instance ids are stored as uint16 (contact_data's cache): below this bound.
MAX_INSTANCES = 1 << 16


def object_weights(instance: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Per-pixel weight 1/sqrt(pixels of its object) on ``mask``, 0 elsewhere (N x 1 x H x W).

    Counted for the whole batch at once, each image's ids in a range of their own: no per-image
    loop, no size read back from a GPU (a loop over 64 images stalled a GPU step ~300 times)."""
    n = instance.shape[0]
    first = torch.arange(n, device=instance.device).view(n, *([1] * (instance.dim() - 1))) * MAX_INSTANCES
    key = (first + instance.long()).flatten()
    counts = torch.zeros(n * MAX_INSTANCES, dtype=torch.float32, device=instance.device)
    counts.scatter_add_(0, key, mask.flatten().float())
    return torch.where(mask, counts[key].view(mask.shape).clamp(min=1.0).rsqrt(), 0.0)


def weighted_mean(values: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    total = weights.sum()
    if total <= 0:
        return values.sum() * 0.0
    return (values * weights).sum() / total


def contact_loss(offsets: torch.Tensor, ground_logit: torch.Tensor, camera: torch.Tensor,
                 batch: dict[str, torch.Tensor], weights: ContactLossWeights,
                 detection: tuple[torch.Tensor, ...] | None = None) -> dict[str, torch.Tensor]:
    """All terms for B pairs (network outputs 2B x ..., frames t-1, t interleaved);
    ``detection`` is the head's (centre logits, boxes[, big-object centre logits, boxes]) when it
    has one."""
    target = batch["offsets"].flatten(0, 1)
    height_true = batch["height"].flatten(0, 1)
    labelled = torch.isfinite(target[:, :1]) & torch.isfinite(height_true)
    instance = batch["instance"].flatten(0, 1)
    movers = labelled & (instance > 0) & (height_true > ABOVE_GROUND_M)
    per_object = object_weights(instance, movers)
    target = torch.nan_to_num(target)
    height_true = torch.nan_to_num(height_true)

    offset_error = F.huber_loss(offsets, target, reduction="none", delta=OFFSET_DELTA_PX).sum(1, keepdim=True)
    losses = {"offset": weighted_mean(offset_error, per_object),
              "offset_all": weighted_mean(offset_error, labelled.float())}

    K, R, C = (batch[k].repeat_interleave(2, 0) for k in ("K", "R", "C"))
    height = torch_heights_from_offsets(offsets, K, R, C)
    losses["height"] = weighted_mean(F.huber_loss(height, height_true, reduction="none",
                                                  delta=HEIGHT_DELTA_M), per_object)
    log_error = torch.log(height.clamp(min=0) + LOG_OFFSET_M) - torch.log(height_true + LOG_OFFSET_M)
    losses["si"] = scale_invariant(log_error, movers)
    losses["consistency"] = consistency(height, batch["matches"], batch["match_valid"])
    losses["ground"] = ground_loss(ground_logit, batch["ground"].flatten(0, 1), labelled, per_object)
    losses["camera"] = camera_nll(camera, batch["camera_target"].repeat_interleave(2, 0),
                                  batch["camera_valid"].repeat_interleave(2, 0))
    losses["total"] = (losses["offset"] + weights.offset_all * losses["offset_all"]
                       + weights.height * losses["height"] + weights.si * losses["si"]
                       + weights.consistency * losses["consistency"] + weights.ground * losses["ground"]
                       + weights.camera * losses["camera"])
    if detection is not None and "det_centre" in batch:
        terms = detection_terms(detection[:2], batch, "det_", DETECTION_STRIDE, weights.box_giou)
        losses.update(terms)
        detection_total = terms["centre"] + terms["box"] + weights.box_giou * terms.get("giou", 0.0)
        if len(detection) == 4 and "det_big_centre" in batch:
            big = detection_terms(detection[2:], batch, "det_big_", BIG_STRIDE, weights.box_giou)
            losses.update({f"big_{key}": value for key, value in big.items()})
            detection_total = detection_total + weights.big_objects * (
                big["centre"] + big["box"] + weights.box_giou * big.get("giou", 0.0))
        losses["total"] = losses["total"] + weights.detection * detection_total
    losses["decoded"] = height.detach()
    losses["movers"] = movers
    return losses


def detection_terms(outputs: tuple[torch.Tensor, ...], batch: dict[str, torch.Tensor], prefix: str,
                    stride: int, giou: float) -> dict[str, torch.Tensor]:
    """One detection head's ``centre`` (focal) and ``box`` (L1) terms, and ``giou`` when its weight
    is set, against the batch's targets named ``prefix`` + centre, box, box_mask, ignore."""
    centre_logit, box = outputs
    ignore = batch[f"{prefix}ignore"].flatten(0, 1) if f"{prefix}ignore" in batch else None
    box_target, box_mask = batch[f"{prefix}box"].flatten(0, 1), batch[f"{prefix}box_mask"].flatten(0, 1)
    terms = {"centre": centre_focal(centre_logit, batch[f"{prefix}centre"].flatten(0, 1), ignore),
             "box": box_l1(box, box_target, box_mask, stride)}
    if giou > 0:
        terms["giou"] = box_giou(box, box_target, box_mask)
    return terms


def ground_loss(logit: torch.Tensor, ground: torch.Tensor, labelled: torch.Tensor,
                per_object: torch.Tensor) -> torch.Tensor:
    """Ground-plane cross-entropy over every labelled pixel, plus over the movers weighted per
    object. Averaged over the frame alone, a thin person's few pixels cost nothing: the first
    trained ground logit read movers at a median P(not ground) of 0.56, useless to the offset
    gate that cuts the offsets along it."""
    bce = F.binary_cross_entropy_with_logits(logit, ground, reduction="none")
    return weighted_mean(bce, labelled.float()) + weighted_mean(bce, per_object)


def scale_invariant(log_error: torch.Tensor, mask: torch.Tensor, lam: float = 0.85) -> torch.Tensor:
    """Eigen et al.'s loss (the paper's Eq. 1) per image, averaged over images with pixels."""
    d = (log_error * mask).flatten(1)
    n = mask.flatten(1).sum(1)
    has = n > 0
    if not has.any():
        return log_error.sum() * 0.0
    mean_sq = (d[has] ** 2).sum(1) / n[has]
    mean = d[has].sum(1) / n[has]
    return torch.sqrt((mean_sq - lam * mean ** 2).clamp(min=1e-8)).mean()


def consistency(height: torch.Tensor, matches: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """The paper's Eq. 2 on decoded metres: squared height change of matched points, t-1 -> t."""
    if not valid.any():
        return height.sum() * 0.0
    h0 = sample_at(height[0::2], matches[..., :2])
    h1 = sample_at(height[1::2], matches[..., 2:])
    return ((h1 - h0) ** 2)[valid].mean()


def camera_nll(camera: torch.Tensor, target: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """The camera heads' loss: Huber on each quantity's error in units of ``CAMERA_SCALE``, plus the
    Gaussian negative log-likelihood of the predicted log-variance around the *detached* mean.

    A plain Gaussian NLL lets a head answer a large error with a large variance, which scales the
    mean's gradient by 1/variance: the first heads sat at the training cameras' mean (pitch 6 deg,
    focal 27 %: the mean camera's own score). Decoupled, the mean learns at full strength and the
    variance still learns to say how far off the mean is (cf. Seitzer et al., ICLR 2022).

    Plus a Huber term on the horizon, f tan(pitch) in image heights: heights decoded with only the
    camera height depend on where the horizon is far more than on pitch and focal length apart
    (held out, at 64,000 images: the heads' camera with the true horizon put people at 28.9 cm
    and cars at 29.6, against 34.7 and 59.4 with the heads' own, and 26.7 / 26.8 with the true
    camera; with the true pitch or the true focal length alone, worse than the heads':
    ``python -m heightnet.camera_compare``)."""
    if not valid.any():
        return camera.sum() * 0.0
    n = target.shape[1]
    mean, log_var = camera[:, :n], camera[:, n:].clamp(min=MIN_LOG_VARIANCE)
    scale = mean.new_tensor(CAMERA_SCALE)
    fit = F.huber_loss(mean / scale, target / scale, reduction="none", delta=1.0).sum(1)
    nll = 0.5 * (torch.exp(-log_var) * (mean.detach() - target) ** 2 + log_var).sum(1)
    horizon = F.huber_loss(horizon_height(mean) / HORIZON_SCALE, horizon_height(target) / HORIZON_SCALE,
                           reduction="none", delta=1.0)
    return ((fit + nll) / n + horizon)[valid].mean()


def horizon_height(camera: torch.Tensor) -> torch.Tensor:
    """The horizon's height above the image centre, in image heights, from (pitch, roll, log
    focal length in image heights, ...) rows."""
    return torch.exp(camera[:, 2]) * torch.tan(camera[:, 0])


def centre_focal(logit: torch.Tensor, target: torch.Tensor, ignore: torch.Tensor | None = None,
                 alpha: float = 2.0, beta: float = 4.0) -> torch.Tensor:
    """CenterNet's penalty-reduced focal loss, per object (target 1 at centres, a Gaussian
    around them that lowers the penalty of near misses); no penalty for peaks on ``ignore``
    cells (B x 1 x h x w, 1 = ignored: objects the targets cannot box)."""
    p = torch.sigmoid(logit).clamp(1e-4, 1 - 1e-4)
    centres = target.eq(1).float()
    positive = -torch.log(p) * (1 - p) ** alpha * centres
    negative = -torch.log(1 - p) * p ** alpha * (1 - target) ** beta * (1 - centres)
    if ignore is not None:
        negative = negative * (1 - ignore)
    return (positive.sum() + negative.sum()) / centres.sum().clamp(min=1.0)


def box_l1(box: torch.Tensor, target: torch.Tensor, mask: torch.Tensor,
           stride: int = DETECTION_STRIDE) -> torch.Tensor:
    """L1 on the centre offset (in cells of ``stride`` input pixels) and the log box size,
    weighted by ``mask`` (object centres and the cells around them, ``detection_targets``; one
    per object)."""
    if not (mask > 0).any():
        return box.sum() * 0.0
    raw = torch.cat([box[:, :2] / stride, torch.log(box[:, 2:] / BOX_UNIT_PX)], 1)
    goal = torch.cat([target[:, :2] / stride, target[:, 2:]], 1)
    return ((raw - goal).abs() * mask).sum() / (4 * mask.sum())


def box_giou(box: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """1 - generalised IoU (Rezatofighi et al. 2019) of each cell's box with its target, weighted
    by ``mask`` as ``box_l1``.

    Why beside the L1: the L1 weighs each edge's error alone, the evaluation weighs the overlap
    (HOTA averages IoU thresholds up to 0.95; the head's boxes were 1-3 px off at each edge, a
    median IoU of 0.71). TTFNet (Liu et al. 2020) trains its boxes on GIoU alone. Both boxes are
    placed relative to their cell's centre, which cancels.
    """
    if not (mask > 0).any():
        return box.sum() * 0.0
    half = box[:, 2:] / 2
    pred = torch.cat([box[:, :2] - half, box[:, :2] + half], 1)
    size = torch.exp(target[:, 2:]) * BOX_UNIT_PX
    goal = torch.cat([target[:, :2] - size / 2, target[:, :2] + size / 2], 1)
    low, high = torch.maximum(pred[:, :2], goal[:, :2]), torch.minimum(pred[:, 2:], goal[:, 2:])
    inter = (high - low).clamp(min=0).prod(1, keepdim=True)
    area_pred = (pred[:, 2:] - pred[:, :2]).clamp(min=0).prod(1, keepdim=True)
    area_goal = (goal[:, 2:] - goal[:, :2]).prod(1, keepdim=True)
    union = (area_pred + area_goal - inter).clamp(min=1e-6)
    hull = (torch.maximum(pred[:, 2:], goal[:, 2:]) - torch.minimum(pred[:, :2], goal[:, :2])).prod(1, keepdim=True)
    giou = inter / union - (hull - union) / hull.clamp(min=1e-6)
    return ((1 - giou) * mask).sum() / mask.sum()
