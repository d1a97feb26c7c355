"""HeightNet v2's network: the offset gate, the position channels and the detection head's grown
parts, its motion path among them (heightnet/contact_model.py)."""

import dataclasses

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from heightnet.contact_data import position_window
from heightnet.contact_model import ContactArchitecture, ContactNet, OffsetGate, motion_channels, position_channels


def test_the_gate_starts_open_so_a_gated_network_equals_the_ungated_one():
    arch = ContactArchitecture(widths=(8, 8, 16, 16), refine=4)
    plain = ContactNet(arch).eval()
    gated = ContactNet(dataclasses.replace(arch, gate=True)).eval()
    gated.load_state_dict(plain.state_dict(), strict=False)
    with torch.no_grad():
        plain.offset_head.weight.normal_(0, 0.1)   # non-zero offsets to compare
        gated.offset_head.weight.copy_(plain.offset_head.weight)
        x = torch.randn(1, 3, 64, 64)
        assert torch.equal(plain(x)[0], gated(x)[0])


def fitted_error(gate: OffsetGate | None, steps: int = 300) -> float:
    """Fit a half-resolution offset field, upsampled, to a 1-pixel-wide object's offsets on
    ground that has none, and return the worst error on the object (pixels)."""
    target = torch.zeros(1, 1, 16, 16)
    target[..., 4:12, 7] = 10.0
    ground_logit = torch.where(target > 0, -4.0, 4.0)
    field = torch.zeros(1, 1, 8, 8, requires_grad=True)
    params = [field] + (list(gate.parameters()) if gate is not None else [])
    optimiser = torch.optim.Adam(params, lr=0.1)
    for _ in range(steps):
        offsets = F.interpolate(field, size=(16, 16), mode="bilinear", align_corners=False)
        if gate is not None:
            offsets = offsets * gate(ground_logit)
        loss = ((offsets - target) ** 2).mean()
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    return float((offsets - target).detach()[target > 0].abs().max())


def test_the_gate_lets_half_resolution_offsets_reach_a_thin_objects_full_value():
    """Without the gate a half-resolution field blurs a thin object into the ground around it (it
    cannot be 10 on the object and 0 beside it); the learnt gate cuts a smooth field at the
    ground logit's outline, from its open start."""
    assert fitted_error(None) > 3.0
    assert fitted_error(OffsetGate()) < 0.5


@pytest.mark.parametrize("x0, y0, w, h, flip", [(0, 0, 640, 480, False), (0, 0, 640, 480, True),
                                                (100, 40, 320, 240, False), (100, 40, 320, 240, True)])
def test_position_channels_say_where_each_input_pixel_lies_in_its_source_frame(x0, y0, w, h, flip):
    """Input pixel (row i, column j) of a window resized to 32 x 24 shows the source frame
    (640 x 480) at the window's point ((j + 0.5) / 32, (i + 0.5) / 24), mirrored with the frame
    when flipped: the channels give that point from -1 to 1 across the (mirrored) frame."""
    window = torch.from_numpy(position_window(x0, y0, w, h, 640, 480, flip))[None]
    channels = position_channels(torch.zeros(1, 3, 24, 32), window)[0].numpy()
    j, i = np.meshgrid(np.arange(32), np.arange(24))
    column = (j + 0.5) / 32 * w
    source_x = x0 + (w - column if flip else column)
    source_y = y0 + (i + 0.5) / 24 * h
    x = 2 * source_x / 640 - 1
    np.testing.assert_allclose(channels[0], -x if flip else x, atol=1e-6)
    np.testing.assert_allclose(channels[1], 2 * source_y / 480 - 1, atol=1e-6)


def test_the_whole_frame_is_the_default_window():
    image = torch.zeros(2, 3, 24, 32)
    whole = torch.from_numpy(position_window(0, 0, 640, 480, 640, 480, False))[None].expand(2, 4)
    assert torch.equal(position_channels(image), position_channels(image, whole))


@pytest.mark.parametrize("grown_part, new_keys, last_weight", [
    ({"detection_context": True}, "detection_head.context.", lambda head: head.context[2].weight),
    ({"detection_blocks": 1}, "detection_head.blocks.", lambda head: head.blocks[0][2].weight),
    ({"detection_motion": True}, "detection_head.motion.", lambda head: head.motion[4].weight),
])
def test_the_heads_grown_parts_start_as_a_no_op_then_learn(grown_part, new_keys, last_weight):
    """A head grown with the 1/16 context path or a residual block gives the heatmaps and boxes of
    the head it grew from (the new part's last convolution starts at zero), and the part then
    receives gradients; a state with the part does not grow into one without it."""
    arch = ContactArchitecture(widths=(8, 8, 16, 16), context=(2,), detection=True)
    plain = ContactNet(arch).eval()
    grown_arch = dataclasses.replace(arch, **grown_part)
    assert grown_arch.grows_from(arch) and not arch.grows_from(grown_arch)
    grown = ContactNet(grown_arch).eval()
    missing, unexpected = grown.load_state_dict(plain.state_dict(), strict=False)
    assert not unexpected and missing and all(k.startswith(new_keys) for k in missing)
    x = torch.randn(1, 3, 64, 64)
    with torch.no_grad():
        for old, new in zip(plain(x), grown(x)):
            assert torch.equal(old, new)
    grown(x)[3].sum().backward()
    assert last_weight(grown.detection_head).grad.abs().sum() > 0


def test_motion_channels_are_each_cells_mean_and_largest_change():
    """Per detection cell (4 x 4 input pixels): the mean and the largest of each pixel's largest
    colour change; none on a first frame (no previous) or on a frame that did not change."""
    image = torch.zeros(1, 3, 16, 16)
    previous = image.clone()
    previous[0, 1, 5, 6] = -2.0      # one pixel of cell (1, 1) changed in one channel
    previous[0, 0, 5, 6] = 1.0
    motion = motion_channels(image, previous)
    assert motion.shape == (1, 2, 4, 4)
    expected_mean, expected_max = torch.zeros(4, 4), torch.zeros(4, 4)
    expected_mean[1, 1], expected_max[1, 1] = 2.0 / 16, 2.0
    assert torch.allclose(motion[0, 0], expected_mean) and torch.equal(motion[0, 1], expected_max)
    assert not motion_channels(image, None).any() and not motion_channels(image, image).any()


def test_a_motion_head_reads_the_change_and_nothing_else_does():
    """With a trained-looking motion path (its last convolution no longer zero): a frame that did
    not change reads as a first frame; one that did changes the heatmaps and boxes, never the
    offsets, ground or camera (the trunk does not see the previous frame)."""
    torch.manual_seed(0)
    net = ContactNet(ContactArchitecture(widths=(8, 8, 16, 16), detection=True, detection_motion=True)).eval()
    torch.nn.init.normal_(net.detection_head.motion[4].weight, std=0.5)
    torch.nn.init.normal_(net.detection_head.box.weight, std=0.1)     # an untrained box layer is constant
    x, other = torch.randn(1, 3, 64, 64), torch.randn(1, 3, 64, 64)
    with torch.no_grad():
        first, same, moved = net(x), net(x, previous=x), net(x, previous=other)
    for a, b in zip(first, same):
        assert torch.equal(a, b)
    for name, a, b in zip(("offsets", "ground", "camera", "centre", "box"), first, moved):
        assert torch.equal(a, b) == (name in ("offsets", "ground", "camera")), name


def test_a_fine_head_starts_as_the_quarter_head_upsampled_then_learns():
    """The fine path (``detection_fine``) puts the heatmaps and boxes at 1/2: grown from a 1/4
    head it starts with that head's logits bilinearly upsampled and with boxes that decode to the
    same boxes (an offset to a box centre is linear across cells); its correction then learns."""
    arch = ContactArchitecture(widths=(8, 8, 16, 16), context=(2,), detection=True, detection_blocks=1)
    torch.manual_seed(0)
    quarter = ContactNet(arch).eval()
    with torch.no_grad():
        for p in quarter.detection_head.parameters():
            p.add_(0.1 * torch.randn_like(p))
    fine_arch = dataclasses.replace(arch, detection_fine=True)
    assert fine_arch.grows_from(arch) and not arch.grows_from(fine_arch)
    assert (arch.detection_stride, fine_arch.detection_stride) == (4, 2)
    fine = ContactNet(fine_arch).eval()
    missing, unexpected = fine.load_state_dict(quarter.state_dict(), strict=False)
    assert not unexpected and missing and all(k.startswith("detection_head.fine.") for k in missing)
    x = torch.randn(1, 3, 64, 96)
    with torch.no_grad():
        *_, centre4, box4 = quarter(x)
        *_, centre2, box2 = fine(x)
    assert centre4.shape[-2:] == (16, 24) and centre2.shape[-2:] == (32, 48)
    up = F.interpolate(centre4, scale_factor=2, mode="bilinear", align_corners=False)
    assert torch.allclose(centre2, up, atol=1e-5)
    # The box centres the fine cells read are the 1/4 head's decoded centres upsampled (away
    # from the border, where the upsampling clamps), in input pixels.
    def decoded_x(box, stride):
        return (torch.arange(box.shape[-1]) + 0.5) * stride + box[0, 0]

    up_x = F.interpolate(decoded_x(box4, 4)[None, None], scale_factor=2, mode="bilinear", align_corners=False)[0, 0]
    assert torch.allclose(decoded_x(box2, 2)[1:-1, 1:-1], up_x[1:-1, 1:-1], atol=1e-3)
    fine(x)[3].sum().backward()
    assert fine.detection_head.fine[2].weight.grad.abs().sum() > 0
