"""The scene's vertical edges sharpen the camera heads' pitch, roll and focal length.

Why: told only the mounting height, a v2 run takes pitch, roll and focal length from the
network's camera heads, which are off by about 4 degrees of pitch and 16 % of focal length on
cameras they never saw (docs/results.md, 2026-12-04 ninth session), and they never see a roll.
A picture holds a cue they do not use precisely: walls, poles, door frames and lamp posts stand
vertical, and in the image their straight edges all point at one point, the vertical vanishing
point, ``K R (0, 0, 1)``, which depends on nothing but pitch, roll and focal length. Here:

1. ``FrameSamples`` keeps a few grey frames spread over the run; their median is the scene
   without movers or rain streaks (``background``).
2. ``vertical_segments``: OpenCV's line segment detector on that background, long segments off
   the ground (ground markings and kerbs run in every direction; the network's ground mask says
   where they lie).
3. ``fit_to_edges``: the heads' estimate is the prior, with their spread and the correlation of
   their errors (pitch and focal length errors go together: the horizon, f tan(pitch), is what
   they see best); only segments pointing within ``GATE_DEG`` of the prior's vanishing point take
   part (roofs, kerbs and parked cars' sides do not), and a robust least-squares fit moves the
   three numbers as little as the prior allows while making the segments meet. The gate is
   then drawn again around the fit's vanishing point and the fit repeated (``GATE_ROUNDS``), so
   heads far off (a real long lens: 14 degrees of pitch) can still reach the edges' camera.

With fewer than ``MIN_EDGES`` segments agreeing (a park, a night scene) the heads stand alone.
Measured (docs/results.md, 2026-12-04 tenth session; ``python -m bench.camera_edges``): on 40
held-out generator cameras pitch 2.4 -> 1.8 degrees off (median), roll 1.0 -> 0.5, focal length
15 -> 9 %, a 1.70 m pole measured with the camera 16.3 -> 10.6 cm off; on Oxford Town Centre
pitch 34.3 -> 18.0 degrees (true 20.0), roll 0.1 -> 1.3 (1.4). But the run's v2 heights are not
better for it (held out the same, Oxford worse): the heads' camera errs together with the
network's offsets, and a truer camera alone undoes that. Hence opt-in (``[height]
vertical_edges``): a better answer to "how is my camera mounted", not to "how tall is that".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from stages.calibration import vertical_vanishing_point
from stages.ground_contact import camera_from_angles

WORK_WIDTH = 640
"""Frames are sampled at most this wide: the median and the segment detector cost grows with
pixels (1920x1080: 0.4 s a fit), and 640 columns resolve an edge's direction well enough."""
SAMPLE_EVERY = 3
"""Every third frame is sampled: consecutive frames are nearly the same picture."""
SAMPLES = 9
"""The median of nine frames: a walker or a rain streak is in fewer than half of them."""
FIRST_FIT_SAMPLES = 5
"""The first fit waits for five samples (frame 12), so a median exists."""
REFIT_MAX_FRAMES = 300
"""Fits come at doubling frame counts (as the heads' average settles), at most this far apart."""
MIN_LENGTH = 0.06
"""Segments shorter than this share of the image height are ignored (texture, not structure)."""
GATE_DEG = 8.0
"""A segment takes part if it points within this angle of the prior's vanishing point (then of
the last fit's)."""
GATE_ROUNDS = 3
"""Gate and fit this many times, each round gating around the last fit's vanishing point."""
MIN_EDGES = 3
"""Fewer agreeing segments than this: no fit, the heads alone."""
BOUND_SIGMAS = 3.0
"""The fit may move each value at most this many of the prior's standard deviations."""
EDGE_NOISE = 1.0 / 240.0
"""An edge's endpoint misses the vanishing line by about this share of the image height (one
pixel at 240 lines): the scale of the robust (Cauchy) loss, and the noise the spread assumes
before the inliers' own scatter is measured."""


@dataclass(frozen=True)
class EdgeFit:
    """The camera the heads and the edges agree on: pitch, roll (radians), log focal length in
    image heights, their standard deviations, and how many segments agreed."""

    values: np.ndarray
    std: np.ndarray
    edges: int


def vanishing_point(values: np.ndarray, width: int, height: int) -> np.ndarray:
    """Homogeneous image point of the world's vertical for (pitch, roll, log focal), in pixels
    of a width x height image with square pixels (at infinity for a level camera)."""
    pitch, roll, log_focal = (float(v) for v in values)
    return vertical_vanishing_point(camera_from_angles(width, height, 1.0, pitch, roll, math.exp(log_focal) * height))


def edge_residuals(point: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """How far (pixels) each segment's first end lies off the line from its middle to ``point``
    (homogeneous, so a vanishing point at infinity works): half its length times the sine of the
    angle by which it misses."""
    ones = np.ones(len(segments))
    middle = np.column_stack([(segments[:, :2] + segments[:, 2:]) / 2, ones])
    lines = np.cross(middle, point)
    ends = np.column_stack([segments[:, :2], ones])
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.einsum("ij,ij->i", ends, lines) / np.hypot(lines[:, 0], lines[:, 1])


def vertical_segments(gray: np.ndarray, ground: np.ndarray | None = None) -> np.ndarray:
    """N x 4 (x1, y1, x2, y2) straight segments of a grey image at least ``MIN_LENGTH`` of its
    height long, those whose middle lies on the ground (``ground``: a boolean mask of the image's
    size) dropped."""
    found = cv2.createLineSegmentDetector().detect(gray)[0]
    if found is None:
        return np.zeros((0, 4))
    segments = found.reshape(-1, 4).astype(np.float64)
    length = np.hypot(segments[:, 2] - segments[:, 0], segments[:, 3] - segments[:, 1])
    segments = segments[length >= MIN_LENGTH * gray.shape[0]]
    if ground is not None and len(segments):
        h, w = ground.shape
        middle = ((segments[:, :2] + segments[:, 2:]) / 2).astype(int)
        on_ground = ground[np.clip(middle[:, 1], 0, h - 1), np.clip(middle[:, 0], 0, w - 1)]
        segments = segments[~on_ground]
    return segments


def fit_to_edges(values: np.ndarray, std: np.ndarray, correlation: np.ndarray, segments: np.ndarray,
                 width: int, height: int) -> EdgeFit | None:
    """The heads' (pitch, roll, log focal) ``values`` refined by the vertical ``segments`` of a
    width x height image; None when fewer than ``MIN_EDGES`` agree.

    ``std`` and ``correlation`` (3 x 3) make the prior's covariance; a quantity known exactly (a
    calibration file's focal length) gets a tiny std and stays put. The fit may move each value
    at most ``BOUND_SIGMAS`` of its standard deviations. Its spread is the posterior's, with the edges'
    noise measured from the agreeing segments' own scatter (never below ``EDGE_NOISE``).
    """
    values, std = np.asarray(values, np.float64), np.asarray(std, np.float64)
    if len(segments) < MIN_EDGES or not (np.all(np.isfinite(values)) and np.all(np.isfinite(std))):
        return None
    covariance = np.diag(std) @ np.asarray(correlation, np.float64) @ np.diag(std)
    whiten = np.linalg.inv(np.linalg.cholesky(covariance))
    low, high = values - BOUND_SIGMAS * std, values + BOUND_SIGMAS * std
    half_length = np.hypot(segments[:, 2] - segments[:, 0], segments[:, 3] - segments[:, 1]) / 2
    estimate, solution, used = values, None, segments[:0]
    for _ in range(GATE_ROUNDS):
        with np.errstate(invalid="ignore", divide="ignore"):
            miss = np.abs(edge_residuals(vanishing_point(estimate, width, height), segments)) / half_length
        gated = segments[miss < math.sin(math.radians(GATE_DEG))]
        if len(gated) < MIN_EDGES:
            break
        if solution is not None and len(gated) == len(used) and np.array_equal(gated, used):
            break
        used = gated
        solution = _least_squares(values, whiten, used, width, height, estimate, (low, high))
        estimate = solution.x
    if solution is None:
        return None
    segments = used
    edge_rows = solution.fun[:len(segments)]
    inliers = np.abs(edge_rows) < 1.0
    if inliers.sum() < MIN_EDGES:
        return None
    # Posterior spread: the agreeing segments' Jacobian, their noise scaled to their own scatter.
    count = int(inliers.sum())
    scatter = max(1.0, float(np.sqrt(np.sum(edge_rows[inliers] ** 2) / max(count - 2, 1))))
    jacobian = np.vstack([solution.jac[:len(segments)][inliers] / scatter, whiten])
    posterior = np.linalg.inv(jacobian.T @ jacobian)
    return EdgeFit(solution.x, np.sqrt(np.diag(posterior)), count)


def _least_squares(prior: np.ndarray, whiten: np.ndarray, segments: np.ndarray, width: int, height: int,
                   start: np.ndarray, bounds: tuple[np.ndarray, np.ndarray]):
    """The robust fit: each segment's miss (in ``EDGE_NOISE`` units, longer segments weighing
    more) and the whitened distance from the prior, under a Cauchy loss."""
    from scipy.optimize import least_squares

    length = np.hypot(segments[:, 2] - segments[:, 0], segments[:, 3] - segments[:, 1])
    weights = np.sqrt(length / length.mean()) / (EDGE_NOISE * height)

    def residuals(theta: np.ndarray) -> np.ndarray:
        # A segment whose middle is the vanishing point has no direction to miss by: 0, not NaN.
        edges = np.nan_to_num(edge_residuals(vanishing_point(theta, width, height), segments)) * weights
        return np.concatenate([edges, whiten @ (theta - prior)])

    start = np.clip(start, bounds[0], bounds[1])
    return least_squares(residuals, start, loss="cauchy", f_scale=1.0, bounds=bounds)


class FrameSamples:
    """A few grey frames spread over the run, and when to fit again.

    One per camera and run. ``add`` keeps every ``SAMPLE_EVERY``-th frame (grey, at most
    ``WORK_WIDTH`` wide) in a ring of ``SAMPLES`` with its ground mask, and says when a fit is
    due: the first at ``FIRST_FIT_SAMPLES`` samples, then at doubling frame counts, at most
    ``REFIT_MAX_FRAMES`` apart. Deterministic in the frame count, so a file gives the same
    camera whether its stages run one after another or overlapped.
    """

    def __init__(self) -> None:
        self.frames = 0
        self._grey: list[np.ndarray] = []
        self._ground: list[np.ndarray] = []
        self._next_fit = 0

    def add(self, image_bgr: np.ndarray, ground_logit: np.ndarray | None) -> bool:
        """One frame (BGR, the source's size) and its ground logit (same size, or None);
        True when a fit is due now."""
        self.frames += 1
        if (self.frames - 1) % SAMPLE_EVERY:
            return False
        h, w = image_bgr.shape[:2]
        size = (w, h) if w <= WORK_WIDTH else (WORK_WIDTH, max(1, round(h * WORK_WIDTH / w)))
        grey = cv2.cvtColor(cv2.resize(image_bgr, size, interpolation=cv2.INTER_AREA), cv2.COLOR_BGR2GRAY)
        ground = (None if ground_logit is None else
                  cv2.resize(np.asarray(ground_logit, np.float32), size, interpolation=cv2.INTER_LINEAR) > 0)
        self._grey = (self._grey + [grey])[-SAMPLES:]
        self._ground = (self._ground + [ground])[-SAMPLES:]
        if len(self._grey) < FIRST_FIT_SAMPLES or self.frames < self._next_fit:
            return False
        self._next_fit = self.frames + min(self.frames, REFIT_MAX_FRAMES)
        return True

    def segments(self) -> tuple[np.ndarray, tuple[int, int]]:
        """Segments of the samples' median (``vertical_segments``) and that image's (width, height)."""
        if any(g.shape != self._grey[-1].shape for g in self._grey):
            self._grey, self._ground = self._grey[-1:], self._ground[-1:]  # the frame size changed
        background = np.median(np.stack(self._grey), axis=0).astype(np.uint8)
        masks = [g for g in self._ground if g is not None and g.shape == background.shape]
        ground = np.mean(masks, axis=0) > 0.5 if masks else None
        return vertical_segments(background, ground), (background.shape[1], background.shape[0])
