"""The HeightNet network: a LapDepth-style encoder / dense ASPP / Laplacian-pyramid decoder.

Structure (Song, Lim & Kim 2021, as used by the HeightNet paper):

* an encoder giving features at 1/2, 1/4, 1/8 and 1/16 of the input (its last stage dilated
  instead of strided, so the deepest map stays at 1/16);
* a dense atrous spatial pyramid block (DenseASPP) on the 1/16 map for context;
* a 5-level decoder (1/16 ... 1/1): the coarsest level predicts the encoded height, every finer
  level predicts a residual added to the upsampled coarser prediction, from the upsampled
  decoder features, the encoder skip at that scale and the *image's* Laplacian residual at that
  scale (the edges where heights jump);
* decoder blocks are pre-activation (GroupNorm -> ReLU -> convolution) with weight-standardised
  convolutions, which train stably at the small batches a CPU affords;
* beside the height, a ground-plane logit from the finest decoder features.

Two configurations of the same family: ``paper`` (ResNeXt-101 32x8d encoder, wide decoder) and
``light`` (a MobileNetV2-style encoder and a narrow decoder for CPU inference). Both train from
scratch: no pretrained weights can be downloaded here.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch
import torch.nn.functional as F
from torch import nn

from heightnet.encoding import HeightEncoding


@dataclass(frozen=True)
class Architecture:
    name: str
    backbone: str
    """'mobilenetv2', 'resnext50_32x4d' or 'resnext101_32x8d'."""
    width_mult: float
    """Channel multiplier of the MobileNetV2 encoder (ignored for ResNeXt)."""
    aspp_channels: int
    aspp_growth: int
    aspp_dilations: tuple[int, ...]
    decoder_channels: tuple[int, int, int, int, int]
    """Decoder width at 1/16, 1/8, 1/4, 1/2, 1/1."""
    level_blocks: tuple[int, int, int, int, int]
    """Pre-activation blocks per decoder level (the light model saves most at full resolution)."""
    head_kernel: int
    """Kernel of the per-level output convolutions (1 is much cheaper at full resolution)."""
    decoder_levels: int = 5
    """Decoder levels from 1/16 down: 5 ends at full resolution, 4 at 1/2, 3 at 1/4; the last
    level's prediction and ground logit are then upsampled (bilinear) to the input size. The
    levels at full and half resolution cost most of a light model's time: small convolutions,
    group norms and layout changes over many pixels."""


ARCHITECTURES = {
    "light": Architecture("light", "mobilenetv2", 0.75, 64, 32, (3, 6, 12), (64, 48, 32, 16, 8),
                          (2, 2, 2, 1, 1), 1),
    "paper": Architecture("paper", "resnext101_32x8d", 1.0, 512, 128, (3, 6, 12, 18, 24),
                          (512, 256, 128, 64, 32), (2, 2, 2, 2, 2), 3),
}
# ``light`` without its full-resolution decoder level (prediction at 1/2, upsampled): two thirds
# of its cost (ONNX Runtime, one thread, 320x192: 22.6 -> 15.0 ms), every other weight shared,
# so it fine-tunes from a trained ``light`` model (``train.init_onnx``).
ARCHITECTURES["light_half"] = replace(ARCHITECTURES["light"], name="light_half", decoder_levels=4)


def architecture_from_name(name: str, backbone: str = "") -> Architecture:
    """The named configuration, optionally with another encoder (e.g. 'paper' on ResNeXt-50)."""
    from core.errors import ConfigError

    if name not in ARCHITECTURES:
        raise ConfigError(f"unknown architecture {name!r} (known: {', '.join(ARCHITECTURES)})")
    arch = ARCHITECTURES[name]
    if backbone:
        if backbone not in ENCODERS:
            raise ConfigError(f"unknown backbone {backbone!r} (known: {', '.join(ENCODERS)})")
        arch = replace(arch, backbone=backbone)
    return arch


# ----------------------------------------------------------------------------- building blocks

class WSConv2d(nn.Conv2d):
    """Convolution with weight standardisation (Qiao et al. 2019): zero-mean, unit-std filters.

    Export traces the standardisation on constant weights, so ONNX constant folding removes it.
    """

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        w = self.weight
        mean = w.mean(dim=(1, 2, 3), keepdim=True)
        std = w.std(dim=(1, 2, 3), keepdim=True) + 1e-5
        return F.conv2d(x, (w - mean) / std, self.bias, self.stride, self.padding,
                        self.dilation, self.groups)


def group_norm(channels: int) -> nn.GroupNorm:
    groups = next(g for g in (16, 8, 4, 2, 1) if channels % g == 0 and channels // g >= 2) \
        if channels >= 2 else 1
    return nn.GroupNorm(groups, channels)


class PreActConv(nn.Sequential):
    """GroupNorm -> ReLU -> weight-standardised convolution."""

    def __init__(self, cin: int, cout: int, kernel: int = 3, dilation: int = 1):
        super().__init__(group_norm(cin), nn.ReLU(inplace=True),
                         WSConv2d(cin, cout, kernel, padding=dilation * (kernel // 2),
                                  dilation=dilation, bias=False))


class Head(nn.Sequential):
    """GroupNorm -> ReLU -> plain convolution: a prediction layer whose scale is its own
    (weight standardisation would undo a small initialisation)."""

    def __init__(self, cin: int, cout: int, kernel: int):
        super().__init__(group_norm(cin), nn.ReLU(inplace=True),
                         nn.Conv2d(cin, cout, kernel, padding=kernel // 2))


class DenseASPP(nn.Module):
    """Dense atrous spatial pyramid (Yang et al. 2018): each dilated branch sees all earlier ones."""

    def __init__(self, cin: int, channels: int, growth: int, dilations: tuple[int, ...]):
        super().__init__()
        self.reduce = PreActConv(cin, channels, 1)
        self.branches = nn.ModuleList()
        width = channels
        for d in dilations:
            self.branches.append(nn.Sequential(PreActConv(width, growth * 2, 1),
                                               PreActConv(growth * 2, growth, 3, dilation=d)))
            width += growth
        self.project = PreActConv(width, channels, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        features = [self.reduce(x)]
        for branch in self.branches:
            features.append(branch(torch.cat(features, 1)))
        return self.project(torch.cat(features, 1))


# ----------------------------------------------------------------------------- encoders

class InvertedResidual(nn.Module):
    def __init__(self, cin: int, cout: int, stride: int, expand: int, dilation: int = 1):
        super().__init__()
        hidden = cin * expand
        layers: list[nn.Module] = []
        if expand != 1:
            layers += [nn.Conv2d(cin, hidden, 1, bias=False), nn.BatchNorm2d(hidden),
                       nn.ReLU6(inplace=True)]
        layers += [nn.Conv2d(hidden, hidden, 3, stride, padding=dilation, dilation=dilation,
                             groups=hidden, bias=False), nn.BatchNorm2d(hidden), nn.ReLU6(inplace=True),
                   nn.Conv2d(hidden, cout, 1, bias=False), nn.BatchNorm2d(cout)]
        self.body = nn.Sequential(*layers)
        self.residual = stride == 1 and cin == cout

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.body(x)
        return x + y if self.residual else y


def _round(channels: float) -> int:
    return max(8, int(channels + 4) // 8 * 8)


class MobileNetV2Encoder(nn.Module):
    """MobileNetV2 (Sandler et al. 2018) to 1/16; its 1/32 stages run dilated at 1/16."""

    # expand, channels, repeats, stride (of the first block)
    SETTINGS = [(1, 16, 1, 1), (6, 24, 2, 2), (6, 32, 3, 2), (6, 64, 3, 2), (6, 96, 2, 1),
                (6, 160, 2, 1)]

    def __init__(self, width_mult: float):
        super().__init__()
        stem = _round(32 * width_mult)
        self.stem = nn.Sequential(nn.Conv2d(3, stem, 3, 2, 1, bias=False), nn.BatchNorm2d(stem),
                                  nn.ReLU6(inplace=True))
        stages: list[nn.Sequential] = []
        cin = stem
        for i, (expand, channels, repeats, stride) in enumerate(self.SETTINGS):
            cout = _round(channels * width_mult)
            dilation = 2 if i == len(self.SETTINGS) - 1 else 1
            blocks = [InvertedResidual(cin if r == 0 else cout, cout, stride if r == 0 else 1,
                                       expand, dilation) for r in range(repeats)]
            stages.append(nn.Sequential(*blocks))
            cin = cout
        # Group stages by output stride: 1/2, 1/4, 1/8, 1/16.
        self.to_2 = stages[0]
        self.to_4 = stages[1]
        self.to_8 = stages[2]
        self.to_16 = nn.Sequential(*stages[3:])
        self.channels = [_round(16 * width_mult), _round(24 * width_mult),
                         _round(32 * width_mult), cin]

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        f2 = self.to_2(self.stem(x))
        f4 = self.to_4(f2)
        f8 = self.to_8(f4)
        return [f2, f4, f8, self.to_16(f8)]


class ResNeXtBottleneck(nn.Module):
    def __init__(self, cin: int, planes: int, stride: int, groups: int, base_width: int,
                 dilation: int = 1):
        super().__init__()
        width = planes * base_width // 64 * groups
        cout = planes * 4
        self.body = nn.Sequential(
            nn.Conv2d(cin, width, 1, bias=False), nn.BatchNorm2d(width), nn.ReLU(inplace=True),
            nn.Conv2d(width, width, 3, stride, dilation, dilation, groups, bias=False),
            nn.BatchNorm2d(width), nn.ReLU(inplace=True),
            nn.Conv2d(width, cout, 1, bias=False), nn.BatchNorm2d(cout))
        self.shortcut = (nn.Sequential(nn.Conv2d(cin, cout, 1, stride, bias=False), nn.BatchNorm2d(cout))
                         if stride != 1 or cin != cout else nn.Identity())

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.relu(self.body(x) + self.shortcut(x))


class ResNeXtEncoder(nn.Module):
    """ResNeXt (Xie et al. 2017) with its last stage dilated, as LapDepth uses it."""

    def __init__(self, layers: tuple[int, int, int, int], groups: int, base_width: int):
        super().__init__()
        self.stem = nn.Sequential(nn.Conv2d(3, 64, 7, 2, 3, bias=False), nn.BatchNorm2d(64),
                                  nn.ReLU(inplace=True))
        self.pool = nn.MaxPool2d(3, 2, 1)
        cin = 64
        stages = []
        for i, (planes, repeats) in enumerate(zip((64, 128, 256, 512), layers)):
            stride = 1 if i in (0, 3) else 2
            dilation = 2 if i == 3 else 1
            blocks = []
            for r in range(repeats):
                blocks.append(ResNeXtBottleneck(cin, planes, stride if r == 0 else 1, groups,
                                                base_width, dilation))
                cin = planes * 4
            stages.append(nn.Sequential(*blocks))
        self.layer1, self.layer2, self.layer3, self.layer4 = stages
        self.channels = [64, 256, 512, 2048]

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        f2 = self.stem(x)
        f4 = self.layer1(self.pool(f2))
        f8 = self.layer2(f4)
        return [f2, f4, f8, self.layer4(self.layer3(f8))]


ENCODERS = {
    "mobilenetv2": lambda arch: MobileNetV2Encoder(arch.width_mult),
    "resnext50_32x4d": lambda arch: ResNeXtEncoder((3, 4, 6, 3), 32, 4),
    "resnext101_32x8d": lambda arch: ResNeXtEncoder((3, 4, 23, 3), 32, 8),
}


# ----------------------------------------------------------------------------- network

def image_pyramid_residuals(image: torch.Tensor, levels: int) -> list[torch.Tensor]:
    """Laplacian residuals of the image, finest first; the last entry is the coarsest image."""
    gaussians = [image]
    for _ in range(levels - 1):
        gaussians.append(F.avg_pool2d(gaussians[-1], 2))
    residuals = [g - F.interpolate(c, size=g.shape[-2:], mode="bilinear", align_corners=False)
                 for g, c in zip(gaussians[:-1], gaussians[1:])]
    return residuals + [gaussians[-1]]


class HeightNet(nn.Module):
    """Image (normalised RGB) -> (encoded height, ground logit), both full resolution."""

    def __init__(self, arch: Architecture, encoding: HeightEncoding):
        super().__init__()
        self.arch = arch
        self.encoding = encoding
        self.encoder = ENCODERS[arch.backbone](arch)
        skips = self.encoder.channels  # 1/2, 1/4, 1/8, 1/16
        c16, c8, c4, c2, c1 = arch.decoder_channels
        self.aspp = DenseASPP(skips[3], arch.aspp_channels, arch.aspp_growth, arch.aspp_dilations)
        widths = [c16, c8, c4, c2, c1]
        k = arch.head_kernel
        self.coarse = self._level(arch.aspp_channels + 3, c16, arch.level_blocks[0])
        self.coarse_head = Head(c16, 1, k)
        # Finer levels: inputs are upsampled features, encoder skip, 3 Laplacian channels, prediction.
        skip_at = [skips[2], skips[1], skips[0], 0]
        # Features are narrowed to the finer level's width *before* upsampling: the full-resolution
        # convolutions dominate the light model's run time.
        finer = arch.decoder_levels - 1
        if not 0 < finer <= 4:
            raise ValueError(f"decoder_levels must be 2..5, got {arch.decoder_levels}")
        self.narrow = nn.ModuleList(PreActConv(widths[i], widths[i + 1], 1) for i in range(finer))
        self.levels = nn.ModuleList()
        self.heads = nn.ModuleList()
        for i in range(finer):
            cin = widths[i + 1] + skip_at[i] + 3 + 1
            self.levels.append(self._level(cin, widths[i + 1], arch.level_blocks[i + 1]))
            # The finest head also gives the ground logit (channel 1): one pass at its resolution.
            self.heads.append(Head(widths[i + 1], 2 if i == finer - 1 else 1, k))
        self._init_heads()

    @staticmethod
    def _level(cin: int, cout: int, blocks: int) -> nn.Sequential:
        return nn.Sequential(PreActConv(cin, cout), *[PreActConv(cout, cout) for _ in range(blocks - 1)])

    def _init_heads(self) -> None:
        # Start from "everything is a little above ground" and near-zero residuals: calm first steps.
        head = self.coarse_head[-1]
        nn.init.normal_(head.weight, std=1e-3)
        nn.init.constant_(head.bias, self.encoding.ground_value + 1.0)
        for h in self.heads:
            nn.init.normal_(h[-1].weight, std=1e-3)
            nn.init.zeros_(h[-1].bias)

    def forward(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        f2, f4, f8, f16 = self.encoder(image)
        lap1, lap2, lap4, lap8, img16 = image_pyramid_residuals(image, 5)
        feat = self.coarse(torch.cat([self.aspp(f16), img16], 1))
        pred = self.coarse_head(feat)
        for narrow, level, head, skip, lap in zip(self.narrow, self.levels, self.heads,
                                                  (f8, f4, f2, None), (lap8, lap4, lap2, lap1)):
            size = lap.shape[-2:]
            feat = F.interpolate(narrow(feat), size=size, mode="bilinear", align_corners=False)
            pred = F.interpolate(pred, size=size, mode="bilinear", align_corners=False)
            inputs = [feat, lap, pred] if skip is None else [feat, skip, lap, pred]
            feat = level(torch.cat(inputs, 1))
            out = head(feat)
            pred = pred + out[:, :1]
        logit = out[:, 1:]
        if pred.shape[-2:] != image.shape[-2:]:
            size = image.shape[-2:]
            pred = F.interpolate(pred, size=size, mode="bilinear", align_corners=False)
            logit = F.interpolate(logit, size=size, mode="bilinear", align_corners=False)
        return pred, logit


class ExportedHeightNet(nn.Module):
    """What goes into the ONNX file: decodes the log encoding so ground is 0 and output >= 0."""

    def __init__(self, net: HeightNet):
        super().__init__()
        self.net = net
        self.offset = net.encoding.offset

    def forward(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        encoded, ground_logit = self.net(image)
        return torch.relu(torch.exp(encoded) - self.offset), ground_logit


def build_model(architecture: str, target: str, backbone: str = "") -> HeightNet:
    return HeightNet(architecture_from_name(architecture, backbone), HeightEncoding(target))


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())
