"""Splitting a merged blob into the objects it holds.

Walkers side by side, a group shoulder to shoulder, a cyclist passing a pedestrian: the
background model and the height map each see one blob. Each splitter reads one cue: separate
peaks of the height map, separate pieces of the foreground, a row of heads on the outline.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class BlobSplittingConstants:
    """The blob splitters' fixed numbers: shares of a blob's size and height, the same for
    every camera (the rule is in docs/design.md, Configuration)."""

    # Height peaks: cores are the parts above this share of the blob's top, where the heads and
    # shoulders of people side by side stand apart and their hips (or a bench between them) do not.
    core_share: float = 0.6
    # A core counts when it is at least this share of the largest core and of the minimum object
    # area: smaller ones are a raised arm or a bag, not an object of their own.
    core_min_share: float = 0.15
    core_min_area_share: float = 0.25
    # Side by side on the foreground: a group of foreground pieces seeds a piece of its own when it
    # covers this share of the blob's rows (a person's piece spans most of the blob's height, an arm
    # or a bag does not) and is narrower than this share of its own height (upright, as people are).
    # Introduced on Oxford: a pair walking together, one 2.21 m "person", split; dev HOTA 0.597 -> 0.601.
    side_min_rows_share: float = 0.5
    side_max_aspect: float = 0.8
    # ... and only when the seeds together are at least this share of their height wide: two people,
    # not one person whose coat the background model broke in two.
    side_min_pair_aspect: float = 0.6
    # Split by heads: a blob at least this share of its height wide may be people side by side (one
    # person is narrower); heads are foreground tops this share of the height apart (about a shoulder
    # width), each standing this share of the height above the lowest point of the outline between
    # them (half the ~0.18 drop from crown to shoulders), and each reaching this share of the highest
    # (a shoulder or a raised hand does not). Introduced together with the speck filter, both
    # together: held-out HOTA 0.321 -> 0.359 (trk_test40).
    heads_min_aspect: float = 0.6
    heads_min_gap: float = 0.2
    heads_min_dip: float = 0.08
    heads_min_share: float = 0.75
    # ... and only a blob whose columns stand, in the median, no higher than a person can: above
    # object extraction's line for vehicles (``coarse_class``: 2.4 m) the dips on the outline are
    # not shoulders. A dark bus passing dark windows loses its roof's foreground in patches, and
    # its outline showed 5-8 "heads" (generator occlusion scene, seq 1: the bus's track split into
    # three, each firing a height rule).
    heads_max_height_m: float = 2.4


CONSTANTS = BlobSplittingConstants()


def split_by_height_peaks(blob: np.ndarray, heights: np.ndarray, min_area: float) -> list[np.ndarray]:
    """Split a blob where its height map shows separate objects.

    Two people walking side by side, or a person next to a car, merge into one foreground
    blob; their upper parts do not. The blob's "cores" are its parts higher than
    ``CONSTANTS.core_share`` of its top; with two or more sizeable cores every blob pixel goes to the
    nearest core. A taller object next to a much lower one (a bus and a child) stays merged.
    """
    values = heights[blob]
    if values.size < 2 * max(min_area, 1):
        return [blob]
    top = float(np.percentile(values, 97))
    core = (blob & (heights > CONSTANTS.core_share * top)).astype(np.uint8)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(core, connectivity=8)
    if count <= 2:
        return [blob]
    areas = stats[1:, cv2.CC_STAT_AREA]
    keep = [i + 1 for i, area in enumerate(areas)
            if area >= max(CONSTANTS.core_min_share * areas.max(), CONSTANTS.core_min_area_share * min_area)]
    if len(keep) < 2:
        return [blob]
    return _split_by_seeds(blob, [labels == label for label in keep], min_area)


def split_by_foreground(blob: np.ndarray, moving: np.ndarray, min_area: float) -> list[np.ndarray]:
    """Split a blob where its own foreground shows people side by side.

    The foreground is grown before it is cut to the height map (flat-coloured parts of an object
    drop out of the background model), and at the work size that growth bridges the few pixels
    between two people walking side by side; the network's height map is too smooth to part
    them either. The foreground itself still does: its pieces are grouped by the columns they
    cover (a person's fragments lie one above the other), and groups that are person-shaped
    (``CONSTANTS.side_min_rows_share`` of the blob's rows or more, narrower than ``CONSTANTS.side_max_aspect``) seed
    one piece each, if together they are wider than one person. A car's fragments are wider
    than tall and stay one object; a walker whose foreground comes in vertical stripes (MOG2's
    sparse masks) is too narrow for two.
    """
    fg = (blob & moving).astype(np.uint8)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(fg, connectivity=8)
    if count <= 2:
        return [blob]
    blob_rows = np.flatnonzero(blob.any(axis=1))
    span = blob_rows[-1] - blob_rows[0] + 1
    min_part_area = CONSTANTS.core_min_area_share * min_area
    parts = sorted((i for i in range(1, count) if stats[i, cv2.CC_STAT_AREA] >= min_part_area),
                   key=lambda i: stats[i, cv2.CC_STAT_LEFT])
    groups: list[list[int]] = []
    right = -1                    # first column right of the current group
    for i in parts:
        left, end = stats[i, cv2.CC_STAT_LEFT], stats[i, cv2.CC_STAT_LEFT] + stats[i, cv2.CC_STAT_WIDTH]
        if groups and left < right:
            groups[-1].append(i)
            right = max(right, end)
        else:
            groups.append([i])
            right = end
    seeds = []
    for group in groups:
        mask = np.isin(labels, group)
        rows, cols = np.nonzero(mask)
        height, width = rows.max() - rows.min() + 1, cols.max() - cols.min() + 1
        if height >= CONSTANTS.side_min_rows_share * span and width < CONSTANTS.side_max_aspect * height:
            seeds.append(mask)
    if len(seeds) < 2:
        return [blob]
    rows, cols = np.nonzero(np.logical_or.reduce(seeds))
    if cols.max() - cols.min() + 1 < CONSTANTS.side_min_pair_aspect * (rows.max() - rows.min() + 1):
        return [blob]             # as narrow as one person: one walker's foreground in stripes
    return _split_by_seeds(blob, seeds, min_area)


def _split_by_seeds(blob: np.ndarray, seeds: list[np.ndarray], min_area: float) -> list[np.ndarray]:
    """Every blob pixel to its nearest seed; the pieces, or the blob whole if fewer than two are big enough."""
    free = np.full(blob.shape, 255, np.uint8)
    for seed in seeds:
        free[seed] = 0
    # Label of the nearest seed component for every pixel (the seeds are the zero pixels).
    _, nearest = cv2.distanceTransformWithLabels(free, cv2.DIST_L2, 3, labelType=cv2.DIST_LABEL_CCOMP)
    pieces = []
    for seed in seeds:
        seed_labels = np.unique(nearest[seed])
        piece = blob & np.isin(nearest, seed_labels)
        if piece.sum() >= min_area:
            pieces.append(piece)
    return pieces if len(pieces) >= 2 else [blob]


def split_by_heads(part: np.ndarray, fg: np.ndarray, min_area: float,
                   heights: np.ndarray | None = None) -> list[np.ndarray]:
    """Split a wide blob into columns, one per head on its foreground outline.

    A group walking close together is one foreground blob with one smooth hump in the network's
    height map; ``split_by_foreground`` needs gaps that a crowd does not leave. Its outline does
    show the heads: the top row of foreground in each column dips between two people by their
    shoulders. Peaks of that outline at least ``CONSTANTS.heads_min_gap`` of the blob's height apart, with
    a dip of ``CONSTANTS.heads_min_dip`` between them, cut the blob at the dip. A car's roof is one flat
    peak and stays whole; so does a blob any of whose pieces would be wider than a person, and,
    given the height map (``heights``, the part's frame), one taller than a person: the median
    over its columns of their top height above ``CONSTANTS.heads_max_height_m`` (the median, so
    that a few columns grown into scenery behind a group do not decide).
    """
    rows = np.flatnonzero(part.any(axis=1))
    cols = np.flatnonzero(part.any(axis=0))
    if rows.size == 0:
        return [part]
    span = rows[-1] - rows[0] + 1
    if cols[-1] - cols[0] + 1 < CONSTANTS.heads_min_aspect * span:
        return [part]
    if heights is not None:
        column_tops = np.where(part, heights, -np.inf).max(axis=0)[cols]
        if float(np.median(column_tops)) > CONSTANTS.heads_max_height_m:
            return [part]
    moving = part & fg
    has = moving.any(axis=0)
    # Outline: how high above the part's bottom the foreground reaches in each column (0: none).
    outline = np.where(has, rows[-1] + 1 - np.argmax(moving, axis=0), 0).astype(float)
    reach = max(1, int(round(CONSTANTS.heads_min_gap * span / 2)))
    padded = np.pad(outline, reach, constant_values=0)
    local_max = np.lib.stride_tricks.sliding_window_view(padded, 2 * reach + 1).max(axis=1)
    # Heads of a group stand about as high as each other: a lower bump is a bag, a wheel, a hand.
    tall = outline >= CONSTANTS.heads_min_share * outline.max()
    peaks = np.flatnonzero((outline == local_max) & has & tall)
    # Peaks closer than a head's spacing are one head (a plateau gives a run of them): the highest.
    heads: list[int] = []
    for c in peaks:
        if heads and c - heads[-1] < CONSTANTS.heads_min_gap * span:
            if outline[c] > outline[heads[-1]]:
                heads[-1] = c
            continue
        heads.append(c)
    cuts = []
    for left, right in zip(heads, heads[1:]):
        between = outline[left:right + 1]
        lowest = np.flatnonzero(between == between.min())
        dip = left + int(lowest[len(lowest) // 2])   # the middle of a flat stretch of shoulders
        if min(outline[left], outline[right]) - outline[dip] >= CONSTANTS.heads_min_dip * span:
            cuts.append(dip)
    if not cuts:
        return [part]
    pieces = []
    for start, stop in zip([0] + cuts, cuts + [part.shape[1]]):
        piece = np.zeros_like(part)
        piece[:, start:stop] = part[:, start:stop]
        piece_cols = np.flatnonzero(piece.any(axis=0))
        if piece_cols.size and piece_cols[-1] - piece_cols[0] + 1 >= CONSTANTS.side_max_aspect * span:
            return [part]             # a piece wider than a person: not a row of people
        if piece.sum() >= min_area:
            pieces.append(piece)
    return pieces if len(pieces) >= 2 else [part]
