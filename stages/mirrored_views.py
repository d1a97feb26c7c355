"""The height network's outputs averaged over a frame and its mirror image.

A network's errors on one object are not only noise from frame to frame: the detection head draws
each person's box a consistent pixel or so too tall or too short, and scores a few looks too low
in every frame (docs/results.md, 2026-12-06 thirty-third session). Run on the mirror image as well,
the same object is read by the same weights from another view; its errors there are partly
independent, and the average of the two reads is nearer the truth (test-time augmentation, as
detectors commonly evaluate with horizontal flips). It costs one more pass of the network a frame,
so it is opt-in (``height.mirror``): for archives, where accuracy matters more than frames/s. It is
for HeightNet v2 only: v1's height maps averaged so read Oxford's real people worse (8.9 -> 20.5
cm; docs/results.md, 2026-12-07 thirty-ninth session).

Every output is mirrored back before it is averaged, each by what it means:

* the ground logit is flipped left to right;
* v2's offsets point to the ground-contact point: flipped, and their horizontal component negated;
* the detection head's centre logits are flipped cell for cell, and its boxes (centre dx, dy from
  the cell's centre, width, height) flipped with dx negated; a cell's mirror is a cell only when
  the input width is a whole number of cells, which ``mirror_problem`` checks;
* the camera heads' roll (and only the roll) changes sign in the mirror image.
"""

from __future__ import annotations

import numpy as np

FLIPPED_MAPS = ("ground_logit", "centre_logit", "big_centre_logit")
"""Outputs (1 x C x H x W) that are mirrored by flipping their columns alone."""
FLIPPED_VECTORS = ("offsets", "box", "big_box")
"""Outputs (1 x C x H x W) whose channel 0 is a horizontal displacement: flipped and negated."""
CAMERA_ROLL = 1
"""Index of the roll in the camera heads' output (pitch, roll, log focal, their log-variances)."""


def mirror_input(tensor: np.ndarray) -> np.ndarray:
    """The network input (1 x 3 x H x W) of the mirror image."""
    return np.ascontiguousarray(tensor[..., ::-1])


def unmirrored(name: str, value: np.ndarray) -> np.ndarray:
    """Output ``name`` of the mirror image, as the unmirrored frame's would be."""
    if name in FLIPPED_MAPS:
        return value[..., ::-1]
    if name in FLIPPED_VECTORS:
        value = value[..., ::-1].copy()
        value[:, 0] *= -1.0
        return value
    if name == "camera":
        value = value.copy()
        value[:, CAMERA_ROLL] *= -1.0
        return value
    raise ValueError(f"no mirror rule for the network output {name!r}")


def unmirrored_outputs(mirrored: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Every output of the mirror image, as the unmirrored frame's would be (flipped maps are views:
    the average that reads them makes the new arrays)."""
    return {name: unmirrored(name, value) for name, value in mirrored.items()}


def averaged_with_mirror(outputs: dict[str, np.ndarray], mirror_read: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Each output averaged with the mirror image's, already mirrored back (``unmirrored_outputs``);
    logits are averaged as logits: the geometric mean of the odds."""
    return {name: (value + mirror_read[name]) * np.float32(0.5) for name, value in outputs.items()}


def mirror_problem(input_width: int, strides: tuple[int, ...]) -> str | None:
    """Why a network at this input width cannot be averaged with its mirror image, or None: each
    detection stride must divide the width, so that the mirror of a cell is a cell."""
    for stride in strides:
        if stride and input_width % stride:
            return (f"height.mirror needs an input width divisible by the detection head's stride {stride}, "
                    f"got {input_width}")
    return None
