"""Association costs between predicted tracks and detections, and the Hungarian assignment.

Every cost here is a (tracks x detections) matrix; forbidden pairs are marked in a boolean
``allowed`` matrix rather than with magic large numbers, so the assignment never picks one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

Box = tuple[float, float, float, float]


def intersection_matrix(boxes_a: list[Box] | np.ndarray, boxes_b: list[Box] | np.ndarray) -> np.ndarray:
    """Overlap area of every box in ``a`` with every box in ``b`` (x, y, w, h)."""
    a = np.asarray(boxes_a, dtype=float).reshape(-1, 4)
    b = np.asarray(boxes_b, dtype=float).reshape(-1, 4)
    if len(a) == 0 or len(b) == 0:
        return np.zeros((len(a), len(b)))
    ax0, ay0 = a[:, 0:1], a[:, 1:2]
    ax1, ay1 = ax0 + a[:, 2:3], ay0 + a[:, 3:4]
    bx0, by0 = b[:, 0], b[:, 1]
    bx1, by1 = bx0 + b[:, 2], by0 + b[:, 3]
    inter_w = np.clip(np.minimum(ax1, bx1) - np.maximum(ax0, bx0), 0, None)
    inter_h = np.clip(np.minimum(ay1, by1) - np.maximum(ay0, by0), 0, None)
    return inter_w * inter_h


def iou_matrix(boxes_a: list[Box] | np.ndarray, boxes_b: list[Box] | np.ndarray) -> np.ndarray:
    """Intersection over union of every box in ``a`` with every box in ``b`` (x, y, w, h)."""
    a = np.asarray(boxes_a, dtype=float).reshape(-1, 4)
    b = np.asarray(boxes_b, dtype=float).reshape(-1, 4)
    inter = intersection_matrix(a, b)
    if inter.size == 0:
        return inter
    union = a[:, 2:3] * a[:, 3:4] + b[:, 2] * b[:, 3] - inter
    return np.where(union > 0, inter / np.maximum(union, 1e-9), 0.0)


@dataclass
class Assignment:
    matches: list[tuple[int, int]]
    """(track row, detection column) pairs."""
    unmatched_tracks: list[int]
    unmatched_detections: list[int]


def assign(cost: np.ndarray, allowed: np.ndarray) -> Assignment:
    """Minimum-cost one-to-one assignment (Hungarian) among the allowed pairs only."""
    n_tracks, n_detections = cost.shape
    matches: list[tuple[int, int]] = []
    if n_tracks and n_detections and allowed.any():
        # Forbidden pairs get a cost above any allowed total, then are dropped if still chosen.
        finite_cost = np.where(allowed, cost, 0.0)
        blocked = float(np.abs(finite_cost).sum() + 1.0) * 2.0
        rows, cols = linear_sum_assignment(np.where(allowed, cost, blocked))
        matches = [(int(r), int(c)) for r, c in zip(rows, cols) if allowed[r, c]]
    matched_rows = {r for r, _ in matches}
    matched_cols = {c for _, c in matches}
    return Assignment(
        matches=matches,
        unmatched_tracks=[r for r in range(n_tracks) if r not in matched_rows],
        unmatched_detections=[c for c in range(n_detections) if c not in matched_cols],
    )


@dataclass
class Region:
    """Where an object is in one frame: its box and, where known, its pixel mask (box-sized)."""

    box: Box
    mask: np.ndarray | None = None


def points_in_regions(points: np.ndarray, regions: list[Region]) -> np.ndarray:
    """N x R bool: point n lies on region r (inside the mask where there is one)."""
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    inside = np.zeros((len(points), len(regions)), dtype=bool)
    for r, region in enumerate(regions):
        x, y, w, h = region.box
        col = np.floor(points[:, 0] - x).astype(int)
        row = np.floor(points[:, 1] - y).astype(int)
        in_box = (col >= 0) & (row >= 0) & (col < int(round(w))) & (row < int(round(h)))
        if region.mask is not None and in_box.any():
            mh, mw = region.mask.shape
            hit = in_box & (col < mw) & (row < mh)
            on_mask = np.zeros(len(points), dtype=bool)
            on_mask[hit] = region.mask[row[hit], col[hit]]
            in_box = on_mask
        inside[:, r] = in_box
    return inside


def feature_votes(prev_pts: np.ndarray, curr_pts: np.ndarray, previous: list[Region],
                  current: list[Region]) -> np.ndarray:
    """Share of each previous region's matched points that land on each current region.

    A point matched from the previous frame to this one votes for "this blob continues that
    track". Rows: previous regions (tracks), columns: current regions (detections); each row
    sums to at most 1. Rows with no points are all zero (no evidence either way).
    """
    votes = np.zeros((len(previous), len(current)))
    if len(prev_pts) == 0 or not previous or not current:
        return votes
    start = points_in_regions(prev_pts, previous)
    end = points_in_regions(curr_pts, current)
    counts = start.T.astype(float) @ end.astype(float)
    totals = start.sum(axis=0).astype(float)[:, None]
    return np.divide(counts, totals, out=np.zeros_like(counts), where=totals > 0)


def direction_mismatch(velocities: np.ndarray, origins: list[Box], boxes: list[Box],
                       min_speed_px: float = 0.5, min_step_px: float = 2.0) -> np.ndarray:
    """How much the step from each track's last observed box to each box goes against its motion.

    OC-SORT's observation-centric momentum: two walkers who cross are easily swapped by box
    overlap alone, but each keeps walking its own way. ``(1 - cos angle) / 2`` between the track's
    velocity (pixels per frame, rows) and the step from its ``origins`` box centre to each box's
    centre (columns): 0 straight ahead, 1 straight back. 0 where the track barely moves or the
    step is too short to have a direction (no evidence either way).
    """
    velocities = np.asarray(velocities, dtype=float).reshape(-1, 2)
    mismatch = np.zeros((len(velocities), len(boxes)))
    if len(velocities) == 0 or len(boxes) == 0:
        return mismatch
    o = np.asarray(origins, dtype=float).reshape(-1, 4)
    b = np.asarray(boxes, dtype=float).reshape(-1, 4)
    steps = (b[None, :, :2] + b[None, :, 2:] / 2.0) - (o[:, None, :2] + o[:, None, 2:] / 2.0)
    step_len = np.linalg.norm(steps, axis=2)
    speed = np.linalg.norm(velocities, axis=1)[:, None]
    cos = np.einsum("tk,tdk->td", velocities, steps) / np.maximum(speed * step_len, 1e-9)
    evidence = (speed >= min_speed_px) & (step_len >= min_step_px)
    return np.where(evidence, (1.0 - cos) / 2.0, 0.0)
