"""HeightNet v2 loss terms that are easy to get subtly wrong."""

from __future__ import annotations

import math

import torch

from heightnet.contact_losses import box_giou, box_l1, camera_nll, centre_focal, ground_loss, object_weights
from heightnet.detection_targets import BOX_UNIT_PX


def test_camera_mean_keeps_its_gradient_when_the_head_claims_a_large_variance():
    """With a plain Gaussian NLL a head that predicts a large variance mutes its own mean."""
    target = torch.tensor([[0.3, 0.0, 0.2]])
    valid = torch.tensor([True])
    grads = []
    for log_var in (-4.0, 4.0):
        camera = torch.tensor([[0.0, 0.0, 0.0, log_var, log_var, log_var]], requires_grad=True)
        camera_nll(camera, target, valid).backward()
        grads.append(camera.grad[0, :3].clone())
    torch.testing.assert_close(grads[0], grads[1])
    assert grads[0][0] < 0 and grads[0][1] == 0


def test_camera_loss_cares_most_about_where_the_horizon_is():
    """Two heads equally far off in pitch and focal length: the one whose errors keep the horizon
    (f tan(pitch)) in place costs less, as heights from a camera height need the horizon most."""
    import math

    target = torch.tensor([[0.5, 0.0, 0.0]])
    log_focal = math.log(math.tan(0.5) / math.tan(0.55))   # < 0: shorter lens, same horizon
    kept = torch.tensor([[0.55, 0.0, log_focal, 0.0, 0.0, 0.0]])
    moved = torch.tensor([[0.55, 0.0, -log_focal, 0.0, 0.0, 0.0]])
    valid = torch.tensor([True])
    assert camera_nll(kept, target, valid) < camera_nll(moved, target, valid) - 1.0


def test_camera_variance_learns_the_size_of_the_error():
    target = torch.tensor([[0.1, 0.0, 0.0]])
    log_var = torch.zeros(1, requires_grad=True)
    optimiser = torch.optim.SGD([log_var], lr=0.5)
    for _ in range(200):
        camera = torch.cat([torch.zeros(1, 3), log_var.expand(3)[None]], 1)
        loss = camera_nll(camera, target, torch.tensor([True]))
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    # One log-variance for three errors (0.1, 0, 0): the NLL's optimum is their mean square.
    assert abs(float(log_var.exp()) - 0.01 / 3) < 1e-3


def test_focal_loss_is_lower_at_the_right_peak_and_box_l1_only_counts_weighted_cells():
    target = torch.zeros(1, 1, 5, 5)
    target[0, 0, 2, 2] = 1.0
    right = torch.full((1, 1, 5, 5), -6.0)
    right[0, 0, 2, 2] = 6.0
    wrong = torch.full((1, 1, 5, 5), -6.0)
    wrong[0, 0, 0, 4] = 6.0
    assert centre_focal(right, target) < 0.01 < centre_focal(wrong, target)
    mask = torch.zeros(1, 1, 5, 5)
    mask[0, 0, 2, 2] = 1.0
    box = torch.full((1, 4, 5, 5), 16.0)  # everywhere: centre 16 px (4 cells) off, size 16 px
    goal = torch.zeros(1, 4, 5, 5)         # centre offset 0, log(size / 16 px) = 0
    # Only the masked cell counts: |4| + |4| + 0 + 0 over four numbers.
    assert abs(float(box_l1(box, goal, mask)) - 2.0) < 1e-6


def test_giou_loss_is_one_minus_the_overlap_and_pulls_apart_boxes_together():
    mask = torch.zeros(1, 1, 3, 3)
    mask[0, 0, 1, 1] = 1.0
    goal = torch.zeros(1, 4, 3, 3)
    goal[:, 0], goal[:, 1] = 2.0, -1.0                       # centre 2 px right of, 1 px above the cell's
    goal[:, 2], goal[:, 3] = math.log(10 / BOX_UNIT_PX), math.log(30 / BOX_UNIT_PX)   # 10 x 30 px
    exact = torch.zeros(1, 4, 3, 3)
    exact[:, 0], exact[:, 1], exact[:, 2], exact[:, 3] = 2.0, -1.0, 10.0, 30.0
    assert float(box_giou(exact, goal, mask)) < 1e-6
    wide = exact.clone()
    wide[:, 2] = 12.0                                        # the goal inside, IoU 10/12, hull = union
    assert abs(float(box_giou(wide, goal, mask)) - (1 - 10 / 12)) < 1e-5
    apart = exact.clone()
    apart[:, 0] = 22.0                                       # 20 px to the side: no overlap, a gap of 10
    apart.requires_grad_(True)
    loss = box_giou(apart, goal, mask)
    assert float(loss) > 1.0                                 # beyond what any overlap costs
    loss.backward()
    assert float(apart.grad[0, 0, 1, 1]) > 0                 # moving it back towards the goal helps
    assert float(apart.grad[0, 0, 0, 0]) == 0.0              # unweighted cells learn nothing


def test_each_object_weighs_the_root_of_its_own_image_s_masked_pixels():
    """Object ids repeat across images (each frame numbers its own movers): an object's pixels are
    counted in its own image, and only those under the mask."""
    instance = torch.zeros(3, 1, 4, 4, dtype=torch.int32)
    instance[0, 0, :2, :2] = 1          # 4 pixels
    instance[0, 0, 3, 3] = 2            # 1 pixel
    instance[1, 0, :, :] = 1            # 16 pixels, 9 of them masked
    mask = instance > 0
    mask[1, 0, 3, :] = False
    mask[1, 0, :3, 3] = False
    weights = object_weights(instance, mask)
    assert torch.allclose(weights[0, 0, 0, 0], torch.tensor(0.5)) and weights[0, 0, 3, 3] == 1.0
    assert torch.allclose(weights[1][mask[1]], torch.tensor(1 / 3))
    assert (weights[~mask] == 0).all() and (weights[2] == 0).all()


def test_a_small_mover_called_ground_costs_as_much_as_a_large_area_of_ground_called_object():
    """Averaged over the frame, 4 wrong pixels of a small person would cost 1/64 of the frame's
    ground being wrong; weighted per object they cost more than a quarter of the frame wrong."""
    ground = torch.ones(1, 1, 16, 16)
    instance = torch.zeros(1, 1, 16, 16, dtype=torch.long)
    ground[..., 7:9, 7:9] = 0
    instance[..., 7:9, 7:9] = 1
    labelled = torch.ones_like(ground, dtype=torch.bool)
    per_object = object_weights(instance, instance > 0)
    right = torch.where(ground > 0, 5.0, -5.0)
    mover_wrong = right.clone()
    mover_wrong[..., 7:9, 7:9] = 5.0
    ground_wrong = right.clone()
    ground_wrong[..., :4, :] = -5.0
    base = ground_loss(right, ground, labelled, per_object)
    assert ground_loss(mover_wrong, ground, labelled, per_object) - base > \
        ground_loss(ground_wrong, ground, labelled, per_object) - base


def test_peaks_on_ignored_cells_cost_nothing_but_the_objects_own_peak_still_counts():
    target = torch.zeros(1, 1, 5, 5)
    target[0, 0, 2, 2] = 1.0
    logit = torch.full((1, 1, 5, 5), -6.0)
    logit[0, 0, 2, 2] = 6.0
    logit[0, 0, 0, 0] = 6.0                  # a peak on, say, a parked car
    ignore = torch.zeros(1, 1, 5, 5)
    ignore[0, 0, 0, 0] = 1.0
    assert centre_focal(logit, target, ignore) < 0.01 < centre_focal(logit, target)
    missed = logit.clone()
    missed[0, 0, 2, 2] = -6.0
    assert centre_focal(missed, target, ignore) > 1.0
