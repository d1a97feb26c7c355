"""HeightNet v2: a small UNet that predicts ground-contact offsets, the ground, and the camera.

Outputs for an input of W x H (both multiples of 32):

* ``offsets`` B x 2 x H x W: (du, dv) in input pixels to each pixel's ground-contact point
  (``stages/ground_contact.py``), predicted at half resolution and upsampled — a full-resolution
  head costs more on a CPU than any encoder layer for almost no parameters;
* ``ground_logit`` B x 1 x H x W: the ground plane (the paper's segmentation stage);
* ``camera`` B x 6: pitch (rad), roll (rad), log of the vertical focal length in image heights,
  then the log-variance of each (the heads' own uncertainty), from pooled deepest features:
  image-level camera regression as in Hold-Geoffroy et al. (CVPR 2018), for users who know only
  the mounting height;
* with ``detection``: ``centre_logit`` B x 3 x H/4 x W/4 (person, cyclist, vehicle centre
  heatmaps) and ``box`` B x 4 x H/4 x W/4 (the centre's offset from its cell centre and the box
  width and height, all in input pixels): a CenterNet-style head (Zhou et al. 2019) on the same
  features, so objects cost no second network; with ``detection_motion`` the head also reads
  how much each of its cells changed since the frame before (a second input, ``previous``);
  with ``detection_fine`` both are at H/2 x W/2; with ``detection_big`` a second head of its
  own for near, big objects adds ``big_centre_logit`` B x 3 x H/16 x W/16 and ``big_box``
  B x 4 x H/16 x W/16 (same meaning, cells of 16 input pixels).

The offset of a pixel on a person's head is the person's height in pixels, so every pixel must
see down to its object's foot. Four stride-2 levels of two 3x3 convolutions see about 90 input
pixels, and the first trained network's offsets saturated at 20-30 px (people 40-60 px tall read
at half their height). ``context`` adds residual dilated 3x3 convolutions at 1/16 (dilations 2,
4, 8 see another ~450 px) whose last BatchNorm starts at zero: a grown network starts as the
network it grew from, so an accumulated training state carries over.

Offsets predicted at half resolution and upsampled blur thin objects into the ground around them:
exact offsets averaged to 160x120 and upsampled bilinearly decode people's tops 24 cm low and
cyclists' 31 cm (cars 3 cm; 50 held-out cameras). ``refine`` > 0 adds a full-resolution
refinement: two 3x3 convolutions over the image and the upsampled predictions, whose residual
(last convolution zero at the start) moves offsets and ground onto the object edges the image
shows — a few channels and no upsampled features, so that it costs a fraction of one encoder
level (with the 16 decoder channels upsampled too it cost a third of the training speed).

``gate`` multiplies the offsets by a full-resolution gate that closes on the ground (whose
offset is zero by definition). The half-resolution offset head then no longer has to draw a thin
person's outline: it can predict a smooth field, the object's offset on and around the object,
and the gate cuts it at the outline the refined ground logit draws. Exact offsets averaged to
160x120 decode people's tops 27 cm low; the same averaged over above-ground pixels only and cut
by the exact full-resolution ground, 8 cm (cut by a half-resolution ground thresholded, 9 cm; 30
held-out cameras). The gate is ``1 - depth * sigmoid(sharpness * ground_logit + shift)``, three
learnt scalars, ``depth`` starting at 0 (open): the first trained network's ground logit was too
weak to cut with (movers' median P(not ground) 0.56), and gating by it at once put people 73 cm
off (26 ungated), so the gate starts as a no-op. It did not open itself (depth 0.012 after 2,000
steps: closing it costs at once on mover pixels and pays on the ground beside them only once the
field has un-blurred), so the committed run had it set shut (depth 1, sharpness 4) at 80,000
images, when its ground logit had learnt the movers (heightnet/README.md).

Two trunks of equal width, chosen by measurement (``heightnet/README.md``): ``plain`` (3x3
convolution, BatchNorm, ReLU, twice per level) and ``depthwise`` (MobileNetV2 inverted
residuals, as the v1 light model). ``camera_channels`` > 0 adds per-pixel camera-embedding
input channels (CAM-Convs, Facil et al. CVPR 2019), computed from a known camera.

``position`` adds two input channels: where each input pixel lies in its source frame, -1 to 1
across the frame's width and height (CoordConv, Liu et al. NeurIPS 2018). A pixel's
ground-contact point lies on the line to the vertical vanishing point, so offsets lean by the
pixel's position in the frame: the committed network's offsets did not lean (du against the
true lean, slope 0.03 on held-out cameras) and its object tops came out where the lean matters,
at the frame's sides. Convolutions cannot see where they are, and training crops hide it
further; these channels say it, crop and flip included (``position_window``). At run time the
whole frame is the window, so the exported model's inputs stay the image alone. The new
channels' first-convolution weights start at zero, so a grown network starts as the one it grew
from.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

# One unit of the offset head's output, in input pixels: targets run from 0 to a few hundred
# pixels, and unit-scale outputs train better than raw pixel values.
OFFSET_UNIT_PX = 32.0
DEPTHWISE_EXPAND = 3.35
CAMERA_OUTPUTS = ("pitch_rad", "roll_rad", "log_focal_y")
DETECTION_CLASSES = ("person", "cyclist", "vehicle")
# Input pixels per cell of the big-object head (``BigObjectHead``): the deepest features, where a
# van 100 px tall spans six cells and every cell sees all of it.
BIG_STRIDE = 16
# Hidden channels of the big-object head, and the box size its box output starts at (input
# pixels): the objects it is taught are 64 px tall and more.
BIG_WIDTH = 64
BIG_BOX_START_PX = 96.0
# Input pixels per cell of the detection head's trunk (its motion path too, and the unit of its
# box offsets); the outputs are at half that with the fine path (``ContactArchitecture.detection_fine``).
DETECTION_STRIDE = 4
# Box sizes are predicted as log(size / BOX_UNIT_PX): far people of 8 px and buses of 300 px
# are then equally easy targets.
BOX_UNIT_PX = 16.0
# Initial centre probability (CenterNet's prior): the heatmap starts almost empty, as it mostly is.
CENTRE_PRIOR = 0.1
# Hidden channels of the detection head's residual blocks, in multiples of its width.
DETECTION_BLOCK_EXPAND = 2
# Hidden channels of the fine path (``DetectionHead``, ``fine_width``), which brings the head
# from 1/4 to 1/2 resolution; kept small because it runs on four times the cells.
FINE_HIDDEN = 16
# The detection head's motion path (``DetectionHead``, ``motion_channels``): its input channels
# (each cell's mean and largest change) and hidden width.
MOTION_CHANNELS = 2
MOTION_WIDTH = 16
# Position input channels (x, y in the source frame) and the window of a whole frame in their
# units: x = x_start + x_span * (column + 0.5) / width, likewise y.
POSITION_CHANNELS = 2
WHOLE_FRAME_WINDOW = (-1.0, 2.0, -1.0, 2.0)


@dataclass(frozen=True)
class ContactArchitecture:
    trunk: str = "plain"                       # "plain" or "depthwise"
    widths: tuple[int, ...] = (16, 32, 64, 128)  # encoder at 1/2, 1/4, 1/8, 1/16
    camera_channels: int = 0                   # CAM-Conv input channels (0 = RGB only)
    context: tuple[int, ...] = ()              # dilations of residual context blocks at 1/16
    detection: bool = False                    # centre heatmaps and boxes at 1/4
    refine: int = 0                            # channels of the full-resolution refinement (0 = none)
    gate: bool = False                         # offsets cut by a gate on the ground logit
    position: bool = False                     # source-frame coordinate input channels
    detection_context: bool = False            # the detection head also reads the 1/16 context
    detection_blocks: int = 0                  # residual blocks in the detection head
    detection_motion: bool = False             # the detection head also reads the change from the last frame
    detection_fine: bool = False               # the detection head's outputs at 1/2, from the 1/2 decoder features
    detection_big: bool = False                # a second head of its own for near, big objects at 1/16

    @property
    def detection_stride(self) -> int:
        """Input pixels per cell of the centre heatmaps and boxes."""
        return DETECTION_STRIDE // 2 if self.detection_fine else DETECTION_STRIDE

    def to_dict(self) -> dict:
        return {"trunk": self.trunk, "widths": list(self.widths), "camera_channels": self.camera_channels,
                "context": list(self.context), "detection": self.detection, "refine": self.refine,
                "gate": self.gate, "position": self.position, "detection_context": self.detection_context,
                "detection_blocks": self.detection_blocks, "detection_motion": self.detection_motion,
                "detection_fine": self.detection_fine, "detection_big": self.detection_big}

    @classmethod
    def from_dict(cls, d: dict) -> "ContactArchitecture":
        return cls(d["trunk"], tuple(d["widths"]), int(d["camera_channels"]),
                   tuple(d.get("context", ())), bool(d.get("detection", False)), int(d.get("refine", 0)),
                   bool(d.get("gate", False)), bool(d.get("position", False)),
                   bool(d.get("detection_context", False)), int(d.get("detection_blocks", 0)),
                   bool(d.get("detection_motion", False)), bool(d.get("detection_fine", False)),
                   bool(d.get("detection_big", False)))

    def grows_from(self, old: "ContactArchitecture") -> bool:
        """True if this network is ``old`` plus new parts only (context blocks, a detection
        head, a refinement, the gate, the position channels, the head's context path, residual
        blocks, motion path and fine path, the big-object head) — parts that start as no-ops, so
        ``old``'s weights carry over (the fine path starts as the 1/4 outputs upsampled; the
        big-object head adds outputs of its own and changes none of the others)."""
        same_core = (self.trunk, self.widths, self.camera_channels) == (old.trunk, old.widths, old.camera_channels)
        return (same_core and self.context[:len(old.context)] == old.context
                and (self.detection or not old.detection) and old.refine in (0, self.refine)
                and (self.gate or not old.gate) and (self.position or not old.position)
                and (self.detection_context or not old.detection_context)
                and (self.detection or not self.detection_context)
                and (self.detection or not self.detection_blocks)
                and (self.detection_motion or not old.detection_motion)
                and (self.detection or not self.detection_motion)
                and (self.detection_fine or not old.detection_fine)
                and (self.detection or not self.detection_fine)
                and (self.detection_big or not old.detection_big)
                and (self.detection or not self.detection_big)
                and self.detection_blocks >= old.detection_blocks and self != old)


def conv_bn_relu(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, stride, 1, bias=False), nn.BatchNorm2d(cout),
                         nn.ReLU(inplace=True))


class InvertedResidual(nn.Module):
    """MobileNetV2 block: 1x1 expand, 3x3 depthwise, 1x1 project (residual when shapes match)."""

    def __init__(self, cin: int, cout: int, stride: int = 1, expand: float = 4.0):
        super().__init__()
        mid = int(round(cin * expand))
        self.body = nn.Sequential(
            nn.Conv2d(cin, mid, 1, bias=False), nn.BatchNorm2d(mid), nn.ReLU6(inplace=True),
            nn.Conv2d(mid, mid, 3, stride, 1, groups=mid, bias=False), nn.BatchNorm2d(mid),
            nn.ReLU6(inplace=True),
            nn.Conv2d(mid, cout, 1, bias=False), nn.BatchNorm2d(cout))
        self.residual = stride == 1 and cin == cout

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.body(x)
        return x + y if self.residual else y


class ContextBlock(nn.Module):
    """Residual dilated 3x3 convolution, then a 1x1; the last BatchNorm's scale starts at zero
    so that the block starts as the identity (Goyal et al. 2017's zero-init residuals)."""

    def __init__(self, width: int, dilation: int):
        super().__init__()
        self.body = nn.Sequential(
            nn.Conv2d(width, width, 3, padding=dilation, dilation=dilation, bias=False),
            nn.BatchNorm2d(width), nn.ReLU(inplace=True),
            nn.Conv2d(width, width, 1, bias=False), nn.BatchNorm2d(width))
        nn.init.zeros_(self.body[-1].weight)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.relu(x + self.body(x))


class Refinement(nn.Module):
    """Full-resolution residual correction of the upsampled offsets and ground logit, from the
    image's edges."""

    def __init__(self, channels: int, outputs: int = 3):
        super().__init__()
        self.body = nn.Sequential(
            nn.Conv2d(3 + outputs, channels, 3, padding=1), nn.ReLU(inplace=True),
            nn.Conv2d(channels, outputs, 3, padding=1))
        nn.init.zeros_(self.body[-1].weight)
        nn.init.zeros_(self.body[-1].bias)

    def forward(self, image: torch.Tensor, predictions: torch.Tensor) -> torch.Tensor:
        return predictions + self.body(torch.cat([image, predictions], 1))


class OffsetGate(nn.Module):
    """``1 - depth * sigmoid(sharpness * ground_logit + shift)``: with ``depth`` 0 it is open
    everywhere, so a grown network starts exactly as the one it grew from; all three scalars
    train with the rest."""

    def __init__(self):
        super().__init__()
        self.depth = nn.Parameter(torch.tensor(0.0))
        self.sharpness = nn.Parameter(torch.tensor(1.0))
        self.shift = nn.Parameter(torch.tensor(0.0))

    def forward(self, ground_logit: torch.Tensor) -> torch.Tensor:
        return 1 - self.depth * torch.sigmoid(self.sharpness * ground_logit + self.shift)


class DetectionHead(nn.Module):
    """Centre heatmaps (logits) and boxes from the 1/4-resolution decoder features and, with
    ``context_width``, from the 1/16 context too: a car 100 px tall spans 6 cells there but 25
    at 1/4, where the 32 decoder channels shared with the offsets saw it only as parts (big
    objects peaked at 0.17, docs/results.md 2026-12-04). The context path's last convolution
    starts at zero, so a head grown with it starts as the head without it.

    ``blocks`` residual blocks (3x3 convolution to ``DETECTION_BLOCK_EXPAND`` x the width, ReLU,
    3x3 back, the last starting at zero) deepen the head before its trunk: with one convolution
    the head underfit its own training cameras as much as held-out ones (person recall 0.42 /
    0.39 at 604,000 images, docs/results.md 2026-12-04, fifth session).

    With ``motion``, a third path reads how much each cell changed since the last frame
    (``motion_channels``): what moves is an object wherever the picture looks unlike the
    generator's, and the rule that let motion confirm weak boxes (``objects.score_motion``) is a
    hand-set threshold the head can learn instead. It too starts at zero.

    With ``fine_width``, the trunk's features are upsampled to 1/2 and corrected there from the
    decoder's 1/2 features (``fine_width`` channels) before the centre and box convolutions: at
    1/4 of a 320x240 input a cell is 4 px, as wide as a far walker, and the boxes were 1-3 px off
    at each edge however they were trained (GIoU did not tighten them, docs/results.md
    2026-12-06), while half of the objects lost inside another's box had their centres within
    8 px of it. The correction's last convolution starts at zero and the outputs are 1x1
    convolutions, which commute with the bilinear upsampling: the head starts as its 1/4 outputs
    upsampled, the box offsets included (an offset to the box centre is linear across the cells,
    so it interpolates exactly).

    With ``big_width`` (the context's channels), a second head of its own (``BigObjectHead``)
    reads the 1/16 context for near, big objects, and ``forward`` returns its centre logits and
    boxes after this head's."""

    def __init__(self, width: int, context_width: int = 0, blocks: int = 0, motion: bool = False,
                 fine_width: int = 0, big_width: int = 0):
        super().__init__()
        self.big = BigObjectHead(big_width, motion) if big_width else None
        self.context = None
        if context_width:
            self.context = nn.Sequential(nn.Conv2d(context_width, width, 3, padding=1), nn.ReLU(inplace=True),
                                         nn.Conv2d(width, width, 1))
            nn.init.zeros_(self.context[2].weight)
            nn.init.zeros_(self.context[2].bias)
        self.motion = None
        if motion:
            self.motion = nn.Sequential(nn.Conv2d(MOTION_CHANNELS, MOTION_WIDTH, 3, padding=1), nn.ReLU(inplace=True),
                                        nn.Conv2d(MOTION_WIDTH, MOTION_WIDTH, 3, padding=1), nn.ReLU(inplace=True),
                                        nn.Conv2d(MOTION_WIDTH, width, 1))
            nn.init.zeros_(self.motion[4].weight)
            nn.init.zeros_(self.motion[4].bias)
        self.blocks = nn.ModuleList(_zero_residual(width, DETECTION_BLOCK_EXPAND * width) for _ in range(blocks))
        self.trunk = nn.Sequential(nn.Conv2d(width, width, 3, padding=1), nn.ReLU(inplace=True))
        self.fine = None
        if fine_width:
            self.fine = nn.Sequential(nn.Conv2d(width + fine_width, FINE_HIDDEN, 3, padding=1), nn.ReLU(inplace=True),
                                      nn.Conv2d(FINE_HIDDEN, width, 1))
            nn.init.zeros_(self.fine[2].weight)
            nn.init.zeros_(self.fine[2].bias)
        self.centre = nn.Conv2d(width, len(DETECTION_CLASSES), 1)
        self.box = nn.Conv2d(width, 4, 1)
        nn.init.constant_(self.centre.bias, math.log(CENTRE_PRIOR / (1 - CENTRE_PRIOR)))
        nn.init.zeros_(self.box.weight)
        nn.init.zeros_(self.box.bias)

    def forward(self, x: torch.Tensor, context: torch.Tensor | None = None,
                motion: torch.Tensor | None = None, half: torch.Tensor | None = None
                ) -> tuple[torch.Tensor, ...]:
        """Centre logits, and boxes (dx, dy, w, h) in input pixels; ``half``: the decoder's 1/2
        features (the fine path). With the big-object head, its centre logits and boxes follow."""
        big = () if self.big is None else self.big(context, motion)
        if self.context is not None:
            x = x + F.interpolate(self.context(context), size=x.shape[-2:], mode="bilinear", align_corners=False)
        if self.motion is not None:
            x = x + self.motion(motion)
        for block in self.blocks:
            x = x + block(x)
        y = self.trunk(x)
        if self.fine is not None:
            y = F.interpolate(y, size=half.shape[-2:], mode="bilinear", align_corners=False)
            y = y + self.fine(torch.cat([y, half], 1))
        return (self.centre(y), decoded_boxes(self.box(y), DETECTION_STRIDE), *big)


class BigObjectHead(nn.Module):
    """Centre heatmaps and boxes of near, big objects (64 input pixels tall and more) at 1/16, from
    the context features (and each 1/16 cell's motion), with weights and a loss of their own.

    Why a head of its own: the 1/2 head found almost no object taller than 80 px at 320x240
    (a van, a person beside a low camera), and teaching it them harder (a core of centre cells)
    cost it the small walkers that are three quarters of what is evaluated (docs/results.md,
    2026-12-07, thirty-sixth session): one set of weights traded one size against the other. At
    1/16 a van is a few cells, every one of which sees all of it, and what this head learns
    cannot take anything from the small head (FCOS assigns objects to feature levels by size
    for the same reason, Tian et al. 2019). Starts with the prior's empty heatmap, so a grown
    network adds no box until trained."""

    def __init__(self, context_width: int, motion: bool = False):
        super().__init__()
        self.motion = motion
        cin = context_width + (MOTION_CHANNELS if motion else 0)
        self.body = nn.Sequential(nn.Conv2d(cin, BIG_WIDTH, 3, padding=1), nn.ReLU(inplace=True),
                                  nn.Conv2d(BIG_WIDTH, BIG_WIDTH, 3, padding=2, dilation=2), nn.ReLU(inplace=True),
                                  nn.Conv2d(BIG_WIDTH, BIG_WIDTH, 3, padding=1), nn.ReLU(inplace=True))
        self.centre = nn.Conv2d(BIG_WIDTH, len(DETECTION_CLASSES), 1)
        self.box = nn.Conv2d(BIG_WIDTH, 4, 1)
        nn.init.constant_(self.centre.bias, math.log(CENTRE_PRIOR / (1 - CENTRE_PRIOR)))
        nn.init.zeros_(self.box.weight)
        with torch.no_grad():
            self.box.bias.copy_(torch.tensor([0.0, 0.0, math.log(BIG_BOX_START_PX / BOX_UNIT_PX),
                                              math.log(BIG_BOX_START_PX / BOX_UNIT_PX)]))

    def forward(self, context: torch.Tensor, motion: torch.Tensor | None = None
                ) -> tuple[torch.Tensor, torch.Tensor]:
        """Centre logits and boxes (dx, dy from the 1/16 cell's centre, w, h; input pixels).
        ``motion``: the 1/4 motion channels (mean and largest change), pooled here to 1/16."""
        x = context
        if self.motion:
            pool = BIG_STRIDE // DETECTION_STRIDE
            x = torch.cat([x, F.avg_pool2d(motion[:, :1], pool), F.max_pool2d(motion[:, 1:], pool)], 1)
        y = self.body(x)
        return self.centre(y), decoded_boxes(self.box(y), BIG_STRIDE)


def decoded_boxes(raw: torch.Tensor, unit: int) -> torch.Tensor:
    """A box convolution's raw output as boxes: the centre's offset in units of ``unit`` input
    pixels (the head's trunk cell) and the size as log(size / BOX_UNIT_PX), both to input pixels."""
    return torch.cat([raw[:, :2] * unit, BOX_UNIT_PX * torch.exp(raw[:, 2:].clamp(max=6.0))], 1)


def motion_channels(image: torch.Tensor, previous: torch.Tensor | None) -> torch.Tensor:
    """B x 2 x H/4 x W/4: each detection cell's mean and largest change since ``previous`` (the
    largest absolute difference over the three normalised colour channels, per pixel); zero without
    a previous frame (a run's first frame)."""
    if previous is None:
        change = torch.zeros_like(image[:, :1])
    else:
        change = (image[:, :3] - previous[:, :3]).abs().amax(1, keepdim=True)
    return torch.cat([F.avg_pool2d(change, DETECTION_STRIDE), F.max_pool2d(change, DETECTION_STRIDE)], 1)


def _zero_residual(width: int, hidden: int) -> nn.Sequential:
    """3x3 convolution to ``hidden`` channels, ReLU, 3x3 back to ``width``, the last at zero: added
    to its input it starts as the identity."""
    body = nn.Sequential(nn.Conv2d(width, hidden, 3, padding=1), nn.ReLU(inplace=True),
                         nn.Conv2d(hidden, width, 3, padding=1))
    nn.init.zeros_(body[2].weight)
    nn.init.zeros_(body[2].bias)
    return body


def position_channels(image: torch.Tensor, window: torch.Tensor | None = None) -> torch.Tensor:
    """B x 2 x H x W: each input pixel's x and y in its source frame (-1 to 1 across it), from the
    window's (x_start, x_span, y_start, y_span) in those units; None = the whole frame."""
    batch, _, height, width = image.shape
    if window is None:
        window = image.new_tensor(WHOLE_FRAME_WINDOW).expand(batch, 4)
    fx = (torch.arange(width, dtype=image.dtype, device=image.device) + 0.5) / width
    fy = (torch.arange(height, dtype=image.dtype, device=image.device) + 0.5) / height
    gx = window[:, 0:1] + window[:, 1:2] * fx     # B x W
    gy = window[:, 2:3] + window[:, 3:4] * fy     # B x H
    return torch.stack([gx[:, None, :].expand(batch, height, width),
                        gy[:, :, None].expand(batch, height, width)], 1)


def level(trunk: str, cin: int, cout: int, stride: int) -> nn.Sequential:
    if trunk == "plain":
        return nn.Sequential(conv_bn_relu(cin, cout, stride), conv_bn_relu(cout, cout))
    if trunk == "depthwise":
        # Expanded so that the parameter count is within a few per cent of the plain trunk's.
        return nn.Sequential(InvertedResidual(cin, cout, stride, DEPTHWISE_EXPAND),
                             InvertedResidual(cout, cout, 1, DEPTHWISE_EXPAND))
    raise ValueError(f"unknown trunk {trunk!r} (known: plain, depthwise)")


class ContactNet(nn.Module):
    """Encoder to 1/16 (plus context), decoder with skips back to 1/2, heads at 1/2 (refined at
    full resolution), detection at 1/4 (or 1/2, ``detection_fine``), camera from the bottleneck.
    Returns (offsets, ground, camera[, centre, box[, big_centre, big_box]])."""

    def __init__(self, arch: ContactArchitecture = ContactArchitecture()):
        super().__init__()
        self.arch = arch
        w = arch.widths
        cin = 3 + arch.camera_channels + (POSITION_CHANNELS if arch.position else 0)
        strides = (2, 2, 2, 2)
        self.encoder = nn.ModuleList()
        prev = cin
        for width, stride in zip(w, strides):
            self.encoder.append(level(arch.trunk, prev, width, stride))
            prev = width
        self.decoder = nn.ModuleList()
        for i in range(len(w) - 1, 0, -1):   # 1/16 -> 1/8 -> 1/4 -> 1/2
            self.decoder.append(level(arch.trunk, w[i] + w[i - 1], w[i - 1], 1))
        self.context = nn.Sequential(*(ContextBlock(w[-1], d) for d in arch.context))
        self.detection_head = (DetectionHead(w[1], w[-1] if arch.detection_context else 0, arch.detection_blocks,
                                             arch.detection_motion, w[0] if arch.detection_fine else 0,
                                             w[-1] if arch.detection_big else 0)
                               if arch.detection else None)
        self.refinement = Refinement(arch.refine) if arch.refine else None
        self.offset_gate = OffsetGate() if arch.gate else None
        self.offset_head = nn.Conv2d(w[0], 2, 3, padding=1)
        self.ground_head = nn.Conv2d(w[0], 1, 3, padding=1)
        self.camera_head = nn.Sequential(nn.Linear(2 * w[-1], 64), nn.ReLU(inplace=True),
                                         nn.Linear(64, 2 * len(CAMERA_OUTPUTS)))
        nn.init.zeros_(self.offset_head.weight)
        nn.init.zeros_(self.offset_head.bias)

    def encode(self, image: torch.Tensor, camera_channels: torch.Tensor | None = None,
               window: torch.Tensor | None = None) -> tuple[list[torch.Tensor], torch.Tensor]:
        """The encoder's outputs (1/2 to 1/16) and the bottleneck after the context blocks."""
        x = image if camera_channels is None else torch.cat([image, camera_channels], 1)
        if self.arch.position:
            x = torch.cat([x, position_channels(image, window)], 1)
        skips = []
        for block in self.encoder:
            x = block(x)
            skips.append(x)
        return skips, self.context(x)

    def forward(self, image: torch.Tensor, camera_channels: torch.Tensor | None = None,
                window: torch.Tensor | None = None, previous: torch.Tensor | None = None):
        """``window`` (B x 4, ``position_window``) says where each image lies in its source frame;
        None = the whole frame, as at run time. ``previous``: the frame before each image (the
        detection head's motion path; None = no change)."""
        skips, x = self.encode(image, camera_channels, window)
        bottleneck = x
        camera = self.camera_head(camera_features(bottleneck))
        quarter = None
        for block, skip in zip(self.decoder, reversed(skips[:-1])):
            x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            x = block(torch.cat([x, skip], 1))
            if skip is skips[1]:
                quarter = x
        half = x
        size = image.shape[-2:]
        # Offsets in units of OFFSET_UNIT_PX and the ground logit, upsampled (and refined).
        predictions = F.interpolate(torch.cat([self.offset_head(x), self.ground_head(x)], 1), size=size,
                                    mode="bilinear", align_corners=False)
        if self.refinement is not None:
            predictions = self.refinement(image[:, :3], predictions)
        offsets, ground = predictions[:, :2] * OFFSET_UNIT_PX, predictions[:, 2:]
        if self.offset_gate is not None:
            offsets = offsets * self.offset_gate(ground)
        if self.detection_head is None:
            return offsets, ground, camera
        motion = motion_channels(image, previous) if self.arch.detection_motion else None
        return (offsets, ground, camera, *self.detection_head(quarter, bottleneck, motion, half))


def camera_features(bottleneck: torch.Tensor) -> torch.Tensor:
    """What the camera heads read: the bottleneck's mean and maximum over the image (B x 2C)."""
    return torch.cat([bottleneck.mean((2, 3)), bottleneck.amax((2, 3))], 1)


def count_parameters(net: nn.Module) -> int:
    return sum(p.numel() for p in net.parameters())
