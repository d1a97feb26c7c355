"""HeightNet v2's network: the offset gate (heightnet/contact_model.py)."""

import dataclasses

import torch
import torch.nn.functional as F

from heightnet.contact_model import ContactArchitecture, ContactNet, OffsetGate


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
