"""A detection's colour signature, and how far apart two signatures are.

The tracker's appearance cue (``stages.tracking``): two walkers side by side have overlapping
boxes, near the same motion and near the same height, and their tracks swapped back and forth
on Oxford Town Centre (people 7 and 15: six times in 40 frames); their clothes differ. A
signature is a coarse hue-saturation-value histogram of the middle of the box (the object's
own pixels where the extractor has a mask: not the street beside it), normalised to sum 1; two
are compared by the Hellinger distance, 0 for the same colours, 1 for colours in no common bin.
Coarse on purpose: a walker's colours shift with the light across a scene and his pose, and
small boxes (a 15 x 50 px generator walker) hold few pixels per bin.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class ColourSignatureConstants:
    """Fixed numbers of the colour signature (the rule is in docs/design.md, Configuration)."""

    # Hue, saturation, value bins.
    bins: tuple[int, int, int] = (8, 4, 4)
    # The middle of the box: a side margin of this share of its width (arms, the street beside)...
    side_margin: float = 0.2
    # ... and of its height above and below (the hair's and the shoes' few pixels, the ground).
    end_margin: float = 0.1
    # Fewer of the object's own pixels in the middle than this: the whole middle is used.
    min_pixels: int = 10


CONSTANTS = ColourSignatureConstants()


def colour_signature(image: np.ndarray, box: tuple[float, float, float, float],
                     mask: np.ndarray | None = None) -> np.ndarray | None:
    """The HSV histogram (flat, sums to 1) of the middle of ``box`` (x, y, w, h) in the BGR
    ``image``, over the mask's pixels where ``mask`` (box-sized bool) has enough there; None
    where the middle is under two pixels wide or tall (nothing to compare)."""
    frame_h, frame_w = image.shape[:2]
    x, y, w, h = box
    x0, y0 = max(int(x + CONSTANTS.side_margin * w), 0), max(int(y + CONSTANTS.end_margin * h), 0)
    x1 = min(int(x + (1.0 - CONSTANTS.side_margin) * w), frame_w)
    y1 = min(int(y + (1.0 - CONSTANTS.end_margin) * h), frame_h)
    if x1 - x0 < 2 or y1 - y0 < 2:
        return None
    middle = cv2.cvtColor(np.ascontiguousarray(image[y0:y1, x0:x1]), cv2.COLOR_BGR2HSV)
    own = _mask_over(mask, (int(round(x)), int(round(y))), (x0, y0, x1, y1))
    histogram = cv2.calcHist([middle], [0, 1, 2], own, list(CONSTANTS.bins), [0, 180, 0, 256, 0, 256]).ravel()
    total = float(histogram.sum())
    return histogram / total if total > 0 else None


def signature_distances(a: list[np.ndarray | None], b: list[np.ndarray | None]) -> np.ndarray:
    """Hellinger distance of every signature in ``a`` to every one in ``b`` (0 same, 1 disjoint);
    NaN where either is None."""
    out = np.full((len(a), len(b)), np.nan)
    rows = [i for i, s in enumerate(a) if s is not None]
    cols = [j for j, s in enumerate(b) if s is not None]
    if rows and cols:
        overlap = np.sqrt(np.stack([a[i] for i in rows])) @ np.sqrt(np.stack([b[j] for j in cols])).T
        out[np.ix_(rows, cols)] = np.sqrt(np.clip(1.0 - overlap, 0.0, 1.0))
    return out


def _mask_over(mask: np.ndarray | None, origin: tuple[int, int],
               corners: tuple[int, int, int, int]) -> np.ndarray | None:
    """The box-sized ``mask`` (its top-left pixel at ``origin``) cut to ``corners`` as uint8, or
    None (all pixels) where there is no mask, it does not cover the corners, or it holds too few
    pixels there."""
    if mask is None:
        return None
    x0, y0, x1, y1 = corners
    part = mask[y0 - origin[1]:y1 - origin[1], x0 - origin[0]:x1 - origin[0]]
    if y0 < origin[1] or x0 < origin[0] or part.shape != (y1 - y0, x1 - x0):
        return None
    if np.count_nonzero(part) < CONSTANTS.min_pixels:
        return None
    return part.astype(np.uint8)
