"""Training targets of the detection head: centre heatmaps and boxes from instance masks.

The generator labels every mover's pixels (instance ids) and their class (semantic map). An
object's box is the extent of its visible pixels in the training window; its target is a
CenterNet heatmap (Zhou et al. 2019) with an elliptical Gaussian as wide and tall as the box
(TTFNet's shape, Liu et al. 2020: a tall thin person gets a tall thin peak), and its box (the
offset of its centre from the cell, log width and height) at the centre cell and, as TTFNet
does, at the cells around it that its Gaussian covers. Trained at the centre cell only, the head
drew good boxes there (IoU >= 0.5 for 85 % of the dev set's people) but its peaks often landed
one or two cells away, where the box had never been trained: 65 % of its detections were good
(docs/results.md, 2026-12-04, fourth session).

Parked vehicles have no instances in the generator, so their boxes are unknown; calling them
background taught the head to tell a parked car from a moving one by its place in the scene
(docs/results.md, 2026-12-04), which real footage does not follow and a car-park operator does
not want. Their cells are ignored instead: the head is neither asked for them nor penalised.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from heightnet.contact_model import BIG_STRIDE, BOX_UNIT_PX, DETECTION_CLASSES, DETECTION_STRIDE
from stages.heightnet_model import CONSTANTS as MODEL_CONSTANTS
from synth.dataset import CLASS_NAMES, COARSE_CLASS

# Boxes smaller than this (input pixels, height) are not asked for: a 3-pixel person is noise.
MIN_BOX_PX = 4.0
# A mover less in view than this is boxed by its visible pixels even with whole boxes: the head
# is not asked to guess a whole walker from a hand (evaluation does not count such objects).
WHOLE_BOX_MIN_VISIBLE = 0.3
# Gaussian width as a share of the box (TTFNet's alpha) and its floor in input pixels (half a
# cell of the 1/4 head; half a cell of any coarser head).
GAUSSIAN_ALPHA = 0.54
MIN_SIGMA_PX = 2.0
# Box targets cover the cells where the object's Gaussian reaches this (about 1.5 sigma) and
# those within DETECTION_STRIDE pixels of its centre cell (a small person's peak lands one 1/4
# cell off: the eight around it at 1/4, the 24 at 1/2); where regions meet,
# the smaller object's wins (TTFNet's rule), but no object takes another's centre. Half of each
# object's box weight sits at its centre cell, half is spread over its cells in proportion to
# the Gaussian, so every object weighs the same.
BOX_REGION = 0.3
CENTRE_BOX_SHARE = 0.5
# With a centre core (``detection_targets``' ``core``), objects at least this tall (input pixels)
# are centres wherever their Gaussian reaches ``core``, not at one cell: near objects, the ones
# the head missed (80 px and more at 320x240), and no walker of the usual 10-40 px.
CORE_MIN_PX = 64.0
# The big-object head (``big_object_targets``) is taught objects at least BIG_MIN_PX tall (input
# pixels); objects from BIG_IGNORE_PX up to that are neither asked of it nor held against it (a
# 56 px car is the small head's, but a big-object peak on it is no mistake). The run time drops
# the head's boxes shorter than what it was taught: one number for both.
BIG_MIN_PX = MODEL_CONSTANTS.big_min_height_px
BIG_IGNORE_PX = 48.0


@dataclass(frozen=True)
class Box:
    cls: int
    x0: float
    y0: float
    x1: float
    y1: float


def window_boxes(instance: np.ndarray, semantic: np.ndarray, scale_x: float, scale_y: float,
                 flip: bool, width: int, whole: dict[int, tuple[float, ...]] | None = None,
                 origin: tuple[int, int] = (0, 0)) -> list[Box]:
    """Boxes of the movers in a native-resolution window, in input pixels after resize/flip.

    A box spans the mover's pixels in view, or with ``whole`` (mover id -> x0, y0, x1, y1 in
    frame pixels and visible share, ``ContactSequence.whole_boxes``; ``origin`` is the window's
    top-left in the frame) the whole mover, hidden parts included, cut to the window, for those
    at least ``WHOLE_BOX_MIN_VISIBLE`` in view.

    Why whole boxes: evaluation (like MOT's) and the heights want the whole object, its feet
    behind a car included; boxes of the parts in view teach the head to end a half-hidden
    walker at the car's roof.
    """
    boxes = []
    window_h, window_w = instance.shape[:2]
    slices = ndimage.find_objects(instance.astype(np.int32))
    for index, found in enumerate(slices, start=1):
        if found is None:
            continue
        ys, xs = found
        pixels = instance[found] == index
        classes = np.bincount(semantic[found][pixels], minlength=len(CLASS_NAMES))
        # Generator classes in the tracker's coarse terms; others (parked vehicles, furniture)
        # are background.
        name = COARSE_CLASS.get(CLASS_NAMES[int(classes.argmax())])
        if name is None:
            continue
        x0, x1, y0, y1 = xs.start, xs.stop, ys.start, ys.stop
        box = whole.get(index) if whole is not None else None
        if box is not None and box[4] >= WHOLE_BOX_MIN_VISIBLE:
            x0, x1 = np.clip([box[0] - origin[0], box[2] - origin[0]], 0, window_w)
            y0, y1 = np.clip([box[1] - origin[1], box[3] - origin[1]], 0, window_h)
        x0, x1 = x0 * scale_x, x1 * scale_x
        y0, y1 = y0 * scale_y, y1 * scale_y
        if y1 - y0 < MIN_BOX_PX:
            continue
        if flip:
            x0, x1 = width - x1, width - x0
        boxes.append(Box(DETECTION_CLASSES.index(name), float(x0), float(y0), float(x1), float(y1)))
    return boxes


def ignored_cells(parked: np.ndarray, stride: int = DETECTION_STRIDE) -> np.ndarray:
    """1 x h x w: heatmap cells (``stride`` input pixels square) that show any of a parked
    vehicle (``parked``: an input-sized boolean mask), plus DETECTION_STRIDE pixels around them,
    where a peak of the neighbouring 1/4 cell would sit (no more for cells coarser than that)."""
    h, w = parked.shape[0] // stride, parked.shape[1] // stride
    cells = parked[:h * stride, :w * stride].reshape(h, stride, w, stride)
    cells = cells.any(axis=(1, 3))
    if DETECTION_STRIDE // stride:   # (iterations=0 would dilate until nothing changes)
        cells = ndimage.binary_dilation(cells, iterations=DETECTION_STRIDE // stride)
    return cells[None].astype(np.float32)


def detection_targets(boxes: list[Box], width: int, height: int, ignore: np.ndarray | None = None,
                      stride: int = DETECTION_STRIDE, core: float = 0.0) -> dict[str, np.ndarray]:
    """``centre`` C x h x w heatmap in [0, 1], ``box`` 4 x h x w (dx, dy in input pixels from the
    cell centre to the box centre; log(w / unit), log(h / unit)), ``box_mask`` 1 x h x w, the
    box loss's weight (one per object, ``BOX_REGION``) and ``ignore`` 1 x h x w (1 = no penalty
    for a peak there; ``ignored_cells``), zero at centres; cells of ``stride`` input pixels.

    ``core`` > 0: an object at least ``CORE_MIN_PX`` tall is a centre at every cell it owns where
    its Gaussian reaches ``core``, not at its centre cell alone. Why: the head scored near, big
    objects' centre cells at 0.05-0.09 even on its own training samples (docs/results.md,
    2026-12-07): inside a van's flat side one cell looks like the next, so one cell of 1 among
    cells of 0.9 is a target the head cannot place, and the loss settled on a low score all over
    the object. A core of cells is one it can; the objects stage already drops boxes lying inside
    a stronger one, so one object's several peaks leave one box. Measured later, what helped near
    objects was the core's weight in the focal loss (each cell counts as an object), not its
    shape, and small walkers paid for it (docs/results.md, 2026-12-07, thirty-sixth session)."""
    cw, ch = width // stride, height // stride
    reach = DETECTION_STRIDE // stride
    centre = np.zeros((len(DETECTION_CLASSES), ch, cw), np.float32)
    box = np.zeros((4, ch, cw), np.float32)
    mask = np.zeros((1, ch, cw), np.float32)
    ignored = np.zeros((1, ch, cw), np.float32) if ignore is None else ignore.copy()
    gx = np.arange(cw, dtype=np.float32)
    gy = np.arange(ch, dtype=np.float32)
    owner = np.full((ch, cw), -1)
    centres = np.zeros((ch, cw), bool)
    placed = []   # (box, centre cell, Gaussian)
    # Big boxes first, so that where centres collide the smaller (harder) object keeps its cell.
    for b in sorted(boxes, key=lambda b: -(b.x1 - b.x0) * (b.y1 - b.y0)):
        cx, cy = (b.x0 + b.x1) / 2, (b.y0 + b.y1) / 2
        i, j = int(cx // stride), int(cy // stride)
        if not (0 <= i < cw and 0 <= j < ch):
            continue
        bw, bh = b.x1 - b.x0, b.y1 - b.y0
        floor = max(MIN_SIGMA_PX, stride / 2)
        sx = max(floor, GAUSSIAN_ALPHA * bw / 6) / stride
        sy = max(floor, GAUSSIAN_ALPHA * bh / 6) / stride
        g = np.exp(-((gx - i) ** 2)[None, :] / (2 * sx * sx) - ((gy - j) ** 2)[:, None] / (2 * sy * sy))
        np.maximum(centre[b.cls], g, out=centre[b.cls])
        centre[b.cls, j, i] = 1.0
        region = g >= BOX_REGION
        region[max(j - reach, 0):j + reach + 1, max(i - reach, 0):i + reach + 1] = True
        region &= ~centres
        region[j, i] = True
        owner[region] = len(placed)
        centres[j, i] = True
        placed.append((b, (i, j), g))
    for k, (b, (i, j), g) in enumerate(placed):
        if owner[j, i] != k:      # a smaller object's centre took this one's cell
            continue
        cells = owner == k
        spread = np.where(cells, g, 0.0)
        weight = (1 - CENTRE_BOX_SHARE) * spread / spread.sum()
        weight[j, i] += CENTRE_BOX_SHARE
        if core > 0 and b.y1 - b.y0 >= CORE_MIN_PX:
            core_cells = cells & (g >= core)
            centre[b.cls][core_cells] = 1.0
            centres |= core_cells
        rows, cols = np.nonzero(cells)
        box[0, rows, cols] = (b.x0 + b.x1) / 2 - (gx[cols] + 0.5) * stride
        box[1, rows, cols] = (b.y0 + b.y1) / 2 - (gy[rows] + 0.5) * stride
        box[2, rows, cols] = math.log((b.x1 - b.x0) / BOX_UNIT_PX)
        box[3, rows, cols] = math.log((b.y1 - b.y0) / BOX_UNIT_PX)
        mask[0, rows, cols] = weight[rows, cols]
    ignored[0][centres] = 0.0
    return {"centre": centre, "box": box, "box_mask": mask, "ignore": ignored}


def big_object_targets(boxes: list[Box], width: int, height: int, parked: np.ndarray) -> dict[str, np.ndarray]:
    """``detection_targets`` of the big-object head (cells of ``BIG_STRIDE`` input pixels): the
    objects at least ``BIG_MIN_PX`` tall; cells where an object of ``BIG_IGNORE_PX`` up to that
    would be a centre (its Gaussian reaching ``BOX_REGION``), like parked vehicles' (``parked``:
    an input-sized boolean mask), are ignored. Smaller objects are background to this head: the
    small head finds them."""
    big = [b for b in boxes if b.y1 - b.y0 >= BIG_MIN_PX]
    band = [b for b in boxes if BIG_IGNORE_PX <= b.y1 - b.y0 < BIG_MIN_PX]
    ignore = ignored_cells(parked, BIG_STRIDE)
    if band:
        near_big = detection_targets(band, width, height, stride=BIG_STRIDE)["centre"].max(0) >= BOX_REGION
        ignore = np.maximum(ignore, near_big[None].astype(np.float32))
    return detection_targets(big, width, height, ignore, BIG_STRIDE)
