import pytest
import torch

from heightnet.model import build_model, count_parameters, image_pyramid_residuals


@pytest.mark.parametrize("architecture", ["light", "light_half", "paper"])
def test_outputs_are_full_resolution_height_and_ground(architecture):
    torch.manual_seed(0)
    net = build_model(architecture, "relative").eval()
    with torch.no_grad():
        encoded, ground = net(torch.randn(1, 3, 64, 96))
    assert encoded.shape == (1, 1, 64, 96)
    assert ground.shape == (1, 1, 64, 96)
    assert torch.isfinite(encoded).all() and torch.isfinite(ground).all()


def test_light_model_is_mobile_sized_and_paper_model_is_not():
    assert 0.3e6 < count_parameters(build_model("light", "relative")) < 1.5e6
    assert count_parameters(build_model("paper", "relative", "resnext50_32x4d")) > 20e6


def test_light_half_is_light_without_its_full_resolution_level():
    light, half = build_model("light", "relative"), build_model("light_half", "relative")
    assert len(half.levels) == len(light.levels) - 1
    theirs = {k: v.shape for k, v in light.state_dict().items()}
    ours = {k: v.shape for k, v in half.state_dict().items() if not k.startswith("heads.2.2.")}
    assert all(theirs[k] == shape for k, shape in ours.items()), "every other weight is light's"
    assert half.state_dict()["heads.2.2.weight"].shape[0] == 2, "its finest head gives the ground logit too"
    with pytest.raises(ValueError, match="decoder_levels"):
        import dataclasses

        from heightnet.model import HeightNet
        HeightNet(dataclasses.replace(light.arch, decoder_levels=1), light.encoding)


def test_untrained_light_model_starts_near_ground_value():
    torch.manual_seed(0)
    net = build_model("light", "relative").eval()
    with torch.no_grad():
        encoded, _ = net(torch.randn(2, 3, 64, 96))
    # Heads start from "a little above ground" (log(0.01) + 1) with near-zero residuals.
    assert abs(float(encoded.mean()) - (net.encoding.ground_value + 1.0)) < 0.5


def test_laplacian_residuals_rebuild_the_image():
    image = torch.randn(1, 3, 32, 48)
    *residuals, coarse = image_pyramid_residuals(image, 4)
    rebuilt = coarse
    for residual in reversed(residuals):
        rebuilt = torch.nn.functional.interpolate(rebuilt, size=residual.shape[-2:], mode="bilinear",
                                                  align_corners=False) + residual
    assert torch.allclose(rebuilt, image, atol=1e-5)
