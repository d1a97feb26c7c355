"""The scene's straight lines sharpen the camera heads' pitch, roll and focal length.

Why: told only the mounting height, a v2 run takes pitch, roll and focal length from the
network's camera heads, which are off by about 4 degrees of pitch and 16 % of focal length on
cameras they never saw (docs/results.md, 2026-12-04 ninth session), and they never see a roll.
A picture holds two cues they read imprecisely. Walls, poles, door frames and lamp posts stand
vertical, and in the image their edges all point at one point, the vertical vanishing point
``K R (0, 0, 1)``, below the image at f cot(pitch) and to the side by the roll. Kerbs, lane
markings and parking bays lie in parallel families on the ground, and each family meets at a
point of the horizon, f tan(pitch) above the centre: the one quantity the heads see best, and
the one heights depend on most. Here:

1. ``FrameSamples`` keeps a few grey frames spread over the run; their median is the scene
   without movers or rain streaks.
2. ``scene_segments``: OpenCV's line segment detector on that median, long segments only, told
   apart by the network's ground mask: off the ground (candidates for the verticals) and on it.
3. ``ground_families``: at most two families of parallel ground lines, at least ``MIN_FAMILY``
   segments each, meeting within the prior's reach of its horizon.
4. ``fit_to_edges``: the heads' estimate is the prior, with their spread and the correlation of
   their errors (pitch and focal length errors go together); only off-ground segments pointing
   within ``GATE_DEG`` of the prior's vanishing point take part (roofs and parked cars' sides do
   not); a robust least-squares fit moves the three numbers, and each family's point along the
   horizon, as little as the prior allows while making the verticals meet and each family meet
   on the horizon. The gate is then drawn again around the fit's vanishing point and the fit
   repeated (``GATE_ROUNDS``), so heads far off (a real long lens: 14 degrees of pitch) can
   still reach the scene's camera.
5. The families are searched again around the fitted horizon and, if more are found, the fit
   repeated: heads far off (200 px on one held-out camera) put a family outside the band drawn
   around their horizon.
6. Two families that cross near a right angle on the ground are fitted again crossing at
   exactly one (``ORTHOGONAL_GATE_DEG``): families fix the horizon, f tan(pitch), but not pitch
   and focal length apart, which the verticals do; an open car park or a plaza has no verticals
   but has square bays and paving. Held out (2026-12-05, 5. and 6.): 1.70 m pole 6.2 -> 5.8 cm
   (trk_test40), 6.3 -> 4.8 (trk_dev2); one test40 camera 22 -> 5 cm, one dev2 camera 54 -> 8.

With fewer than ``MIN_EDGES`` agreeing verticals and no family (a park at night) the heads stand
alone. Measured (docs/results.md, 2026-12-04 tenth session; ``python -m bench.camera_edges``):
on 40 held-out generator cameras pitch 2.4 -> 0.9 degrees off (median), roll 1.0 -> 0.5, focal
length 15 -> 6 %, horizon 4.0 -> 1.5 % of the image height, a 1.70 m pole measured with the
camera 16.3 -> 6.2 cm off; on Oxford Town Centre pitch 34.3 -> 20.5 degrees (true 20.0), roll
0.1 -> 1.3 (1.4), focal length 731 -> 1379 px (1348). Opt-in for a run's v2 heights
(``[height] vertical_edges``: held-out people 25 -> 18 cm, but Oxford 11.6 -> 24), the way to a
posed run through ``heightpipe calibrate --camera-height`` and a run told only the height
(``stages.contact_heights.read_scene``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from stages.calibration import horizon_line, vertical_vanishing_point
from stages.ground_contact import camera_from_angles

WORK_WIDTH = 640
"""Frames are sampled at most this wide: the median and the segment detector cost grows with
pixels (1920x1080: 0.4 s a fit), and 640 columns resolve an edge's direction well enough."""
SAMPLE_EVERY = 3
"""Every third frame is sampled: consecutive frames are nearly the same picture."""
SAMPLES = 9
"""The median of nine frames: a walker or a rain streak is in fewer than half of them."""
FIRST_FIT_SAMPLES = 5
"""The first fit waits for five samples (frame 13), so a median exists."""
FIRST_FIT_FRAME = SAMPLE_EVERY * (FIRST_FIT_SAMPLES - 1) + 1
"""The frame (counted from 1) of the first fit: fewer frames give the heads alone."""
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
GROUND_TOLERANCE_DEG = 1.5
"""A ground segment belongs to a family of parallel ground lines if it points within this angle
of the family's vanishing point."""
MIN_FAMILY = 8
"""A family of parallel ground lines needs this many segments: fewer are chance alignments of
tiles and markings (on the dev set, three-segment families tilted the horizon by tens of %)."""
FAMILY_CANDIDATES = 40
"""Family vanishing points are tried at the crossings of every pair of the longest 40 ground
segments (780 pairs: deterministic, and enough for a road's edges and markings)."""
ORTHOGONAL_GATE_DEG = 20.0
"""Two families whose directions on the ground (at the fitted camera) cross within this angle of
a right angle are taken to cross at exactly one: bays and lanes, crossings and paving are laid
out square. On generator cameras such pairs read 83-90 degrees at the fit, the others (two roads
meeting, a kerb split in two) 64 or less (docs/results.md, 2026-12-05)."""
ORTHOGONAL_STD = 0.02
"""... to this much of the cosine of the angle between them (about a degree): a residual of the
fit like a segment's, so a right angle that the lines contradict gives way (Cauchy loss)."""
BOUND_SIGMAS = 3.0
"""The fit may move each value at most this many of the prior's standard deviations."""
EDGE_NOISE = 1.0 / 240.0
"""An edge's endpoint misses the vanishing line by about this share of the image height (one
pixel at 240 lines): the scale of the robust (Cauchy) loss, and the noise the spread assumes
before the inliers' own scatter is measured."""


@dataclass(frozen=True)
class EdgeFit:
    """The camera the heads and the edges agree on: pitch, roll (radians), log focal length in
    image heights, their standard deviations, and how many segments agreed; the agreeing
    segments themselves (vertical ones, and each family of ground lines), to be drawn."""

    values: np.ndarray
    std: np.ndarray
    edges: int
    vertical: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    families: tuple[np.ndarray, ...] = ()
    square: bool = False
    """The two families were fitted crossing at right angles (``ORTHOGONAL_GATE_DEG``): an
    assumption a user should see, since a scene laid out otherwise would mislead it."""


def vanishing_point(values: np.ndarray, width: int, height: int) -> np.ndarray:
    """Homogeneous image point of the world's vertical for (pitch, roll, log focal), in pixels
    of a width x height image with square pixels (at infinity for a level camera)."""
    pitch, roll, log_focal = (float(v) for v in values)
    return vertical_vanishing_point(camera_from_angles(width, height, 1.0, pitch, roll, math.exp(log_focal) * height))


def horizon(values: np.ndarray, width: int, height: int) -> np.ndarray:
    """The horizon (a, b, c), a u + b v + c = 0 with a^2 + b^2 = 1, for (pitch, roll, log focal):
    every family of parallel ground lines meets on it."""
    pitch, roll, log_focal = (float(v) for v in values)
    return horizon_line(camera_from_angles(width, height, 1.0, pitch, roll, math.exp(log_focal) * height))


def point_on_horizon(line: np.ndarray, angle: float, width: int, height: int) -> np.ndarray:
    """Homogeneous point of ``line`` at ``angle`` (radians): 0 is the foot of the perpendicular
    from the image centre, +-pi/2 the line's points at infinity, tan(angle) image heights along
    it in between (an angle, so a family of lines nearly parallel in the image stays finite)."""
    a, b, c = line
    centre = np.array([(width - 1) / 2, (height - 1) / 2])
    foot = centre - (a * centre[0] + b * centre[1] + c) * np.array([a, b])
    along = np.array([-b, a])
    return math.cos(angle) * np.array([*foot, 1.0]) + math.sin(angle) * height * np.array([*along, 0.0])


def edge_residuals(point: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """How far (pixels) each segment's first end lies off the line from its middle to ``point``
    (homogeneous, so a vanishing point at infinity works): half its length times the sine of the
    angle by which it misses. ``point`` may be a stack (P x 1 x 3): then P x N misses."""
    ones = np.ones(len(segments))
    middle = np.column_stack([(segments[:, :2] + segments[:, 2:]) / 2, ones])
    lines = np.cross(middle, point)
    ends = np.column_stack([segments[:, :2], ones])
    with np.errstate(invalid="ignore", divide="ignore"):
        return (ends * lines).sum(axis=-1) / np.hypot(lines[..., 0], lines[..., 1])


def scene_segments(gray: np.ndarray, ground: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """N x 4 (x1, y1, x2, y2) straight segments of a grey image at least ``MIN_LENGTH`` of its
    height long: those whose middle lies off the ground (walls, poles: candidates for the
    verticals) and those on it (kerbs, markings: candidates for the horizon's families), by
    ``ground``, a boolean mask of the image's size (None: all off the ground)."""
    found = cv2.createLineSegmentDetector().detect(gray)[0]
    if found is None:
        return np.zeros((0, 4)), np.zeros((0, 4))
    segments = found.reshape(-1, 4).astype(np.float64)
    segments = segments[_segment_length(segments) >= MIN_LENGTH * gray.shape[0]]
    if ground is None or not len(segments):
        return segments, segments[:0]
    h, w = ground.shape
    middle = ((segments[:, :2] + segments[:, 2:]) / 2).astype(int)
    on_ground = ground[np.clip(middle[:, 1], 0, h - 1), np.clip(middle[:, 0], 0, w - 1)]
    return segments[~on_ground], segments[on_ground]


@dataclass(frozen=True)
class Family:
    """Parallel ground lines (a kerb, lane markings, parking bays): their segments and where
    on the horizon they meet (``point_on_horizon``'s angle)."""

    segments: np.ndarray
    angle: float


def _segment_length(segments: np.ndarray) -> np.ndarray:
    return np.hypot(segments[:, 2] - segments[:, 0], segments[:, 3] - segments[:, 1])


def _misses(point: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """Sine of the angle by which each segment misses pointing at ``point`` (or each of a stack)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.abs(edge_residuals(point, segments)) / (_segment_length(segments) / 2)


def _horizon_angle(line: np.ndarray, point: np.ndarray, width: int, height: int) -> float:
    """``point_on_horizon``'s angle of (the projection onto ``line`` of) a homogeneous point."""
    foot = point_on_horizon(line, 0.0, width, height)[:2]
    along = np.array([-line[1], line[0]])
    return math.atan2(float((point[:2] - point[2] * foot) @ along) / height, float(point[2]))


def ground_families(segments: np.ndarray, values: np.ndarray, covariance: np.ndarray, width: int,
                    height: int) -> list[Family]:
    """At most two families of parallel ground lines whose meeting point lies within the prior's
    reach of its horizon (two standard deviations of where the horizon crosses the image's middle
    column, at least 2 % of the image height), each of at least ``MIN_FAMILY`` segments; the
    family with the most length first."""
    if len(segments) < MIN_FAMILY:
        return []
    line = horizon(values, width, height)
    middle = (width - 1) / 2

    def centre_row(theta):
        a, b, c = horizon(theta, width, height)
        return -(a * middle + c) / b

    step = 1e-4
    gradient = np.array([(centre_row(values + step * e) - centre_row(values - step * e)) / (2 * step)
                         for e in np.eye(3)])
    band = max(2 * math.sqrt(max(float(gradient @ covariance @ gradient), 0.0)), 0.02 * height)
    length = _segment_length(segments)
    candidates = np.argsort(-length)[:FAMILY_CANDIDATES]
    first, second = np.triu_indices(len(candidates), k=1)
    first, second = candidates[first], candidates[second]
    ones = np.ones(len(segments))
    lines = np.cross(np.column_stack([segments[:, :2], ones]), np.column_stack([segments[:, 2:], ones]))
    points = np.cross(lines[first], lines[second])              # where each pair of segments meets
    scale = np.hypot(points[:, 0], points[:, 1])
    near = (scale > 0) & (np.abs(points @ line) <= band * np.abs(points[:, 2]) + 1e-9 * scale)
    first, second, points = first[near], second[near], points[near]
    # Every segment's miss of every candidate point (segments x points), and which agree with it;
    # NaN (a point on a segment's middle) agrees with nothing.
    agree = _misses(points[:, None, :], segments).T < math.sin(math.radians(GROUND_TOLERANCE_DEG))
    free = np.ones(len(segments), bool)
    families = []
    for _ in range(2):
        members = agree & free[:, None]
        usable = members.sum(axis=0) >= MIN_FAMILY
        usable &= free[first] & free[second]
        if not usable.any():
            break
        support = np.where(usable, length @ members, -1.0)
        best = int(np.argmax(support))                     # the first of equals: deterministic
        families.append(Family(segments[members[:, best]], _horizon_angle(line, points[best], width, height)))
        free &= ~members[:, best]
    return families


def fit_to_edges(values: np.ndarray, std: np.ndarray, correlation: np.ndarray, segments: np.ndarray,
                 width: int, height: int, ground_segments: np.ndarray | None = None) -> EdgeFit | None:
    """The heads' (pitch, roll, log focal) ``values`` refined by the vertical ``segments`` of a
    width x height image and by families of parallel lines among its ``ground_segments`` (which
    meet on the horizon); None when fewer than ``MIN_EDGES`` vertical segments agree and no
    family is found.

    ``std`` and ``correlation`` (3 x 3) make the prior's covariance; a quantity known exactly (a
    calibration file's focal length) gets a tiny std and stays put. The fit may move each value
    at most ``BOUND_SIGMAS`` of its standard deviations. Its spread is the posterior's, with the
    lines' noise measured from the agreeing segments' own scatter (never below ``EDGE_NOISE``).
    """
    values, std = np.asarray(values, np.float64), np.asarray(std, np.float64)
    if not (np.all(np.isfinite(values)) and np.all(np.isfinite(std))):
        return None
    covariance = np.diag(std) @ np.asarray(correlation, np.float64) @ np.diag(std)
    whiten = np.linalg.inv(np.linalg.cholesky(covariance))
    families = (ground_families(ground_segments, values, covariance, width, height)
                if ground_segments is not None else [])
    solution, used = _gated_fit(values, std, whiten, segments, families, width, height)
    if solution is not None and ground_segments is not None:
        # Families searched again around the fitted horizon: heads far off (200 px on one
        # held-out camera) put a second family outside the band drawn around theirs.
        found = ground_families(ground_segments, solution.x[:3], covariance, width, height)
        if _support(found) > _support(families):
            families = found
            solution, used = _gated_fit(values, std, whiten, segments, families, width, height, solution.x[:3])
    if solution is None:
        return None
    # Two families near a right angle: fitted again, crossing at one. Where no verticals agree,
    # this alone says the focal length (the families fix only the horizon, f tan pitch).
    square = len(families) == 2 and abs(_families_cosine(solution.x, width, height)) < math.sin(
        math.radians(ORTHOGONAL_GATE_DEG))
    if square:
        solution = _least_squares(values, whiten, used, families, width, height, solution.x,
                                  _bounds(values, std, families), orthogonal=True)
    groups = [used, *(f.segments for f in families)]     # their rows come in this order
    lines = sum(map(len, groups))
    rows = solution.fun[:lines]
    inliers = np.abs(rows) < 1.0
    vertical = int(inliers[:len(used)].sum())
    if vertical < MIN_EDGES and not families:
        return None
    # Posterior spread: the agreeing segments' Jacobian, their noise scaled to their own scatter.
    count = int(inliers.sum())
    scatter = max(1.0, float(np.sqrt(np.sum(rows[inliers] ** 2) / max(count - 2 - len(families), 1))))
    jacobian = np.vstack([solution.jac[:lines][inliers] / scatter, solution.jac[lines:]])
    posterior = np.linalg.pinv(jacobian.T @ jacobian)[:3, :3]
    ends = np.cumsum([len(group) for group in groups])
    agreeing = [group[inliers[end - len(group):end]] for group, end in zip(groups, ends)]
    return EdgeFit(solution.x[:3], np.sqrt(np.diag(posterior)), count, agreeing[0], tuple(agreeing[1:]), square)


def _support(families: list[Family]) -> tuple[int, int]:
    """How much a set of families says: how many, then how many segments in all."""
    return len(families), sum(len(f.segments) for f in families)


def _gated_fit(values: np.ndarray, std: np.ndarray, whiten: np.ndarray, segments: np.ndarray,
               families: list[Family], width: int, height: int, start: np.ndarray | None = None):
    """``_least_squares`` with the verticals gated around the current vanishing point, the gate
    drawn again around each fit (``GATE_ROUNDS``); from the prior ``values`` or ``start``. The
    solution (None when nothing took part) and the vertical segments that took part."""
    estimate = np.concatenate([values if start is None else start, [f.angle for f in families]])
    solution, used = None, segments[:0]
    for _ in range(GATE_ROUNDS):
        gated = segments[_misses(vanishing_point(estimate[:3], width, height), segments)
                         < math.sin(math.radians(GATE_DEG))]
        if len(gated) < MIN_EDGES:
            gated = segments[:0]
        if not len(gated) and not families:
            break
        if solution is not None and np.array_equal(gated, used):   # the gate settled
            break
        used = gated
        solution = _least_squares(values, whiten, used, families, width, height, estimate,
                                  _bounds(values, std, families))
        estimate = solution.x
    return solution, used


def _bounds(values: np.ndarray, std: np.ndarray, families: list[Family]) -> tuple[np.ndarray, np.ndarray]:
    """Each value at most ``BOUND_SIGMAS`` of the prior's spread from it; family angles free."""
    return (np.concatenate([values - BOUND_SIGMAS * std, np.full(len(families), -math.pi)]),
            np.concatenate([values + BOUND_SIGMAS * std, np.full(len(families), math.pi)]))


def _families_cosine(x: np.ndarray, width: int, height: int) -> float:
    """Cosine of the angle on the ground between the two families of a fit's (pitch, roll, log
    focal, angle, angle), 0 when they cross at right angles: each family's point on the horizon,
    back through the camera (K R)^-1, is its direction on the ground."""
    theta = x[:3]
    line = horizon(theta, width, height)
    pitch, roll, log_focal = (float(v) for v in theta)
    camera = camera_from_angles(width, height, 1.0, pitch, roll, math.exp(log_focal) * height)
    directions = [camera.R.T @ np.linalg.solve(camera.K, point_on_horizon(line, angle, width, height))
                  for angle in x[3:5]]
    first, second = (d[:2] / np.linalg.norm(d[:2]) for d in directions)
    return float(first @ second)


def _least_squares(prior: np.ndarray, whiten: np.ndarray, segments: np.ndarray, families: list[Family], width: int,
                   height: int, start: np.ndarray, bounds: tuple[np.ndarray, np.ndarray], orthogonal: bool = False):
    """The robust fit of (pitch, roll, log focal, one angle per family): each vertical
    segment's miss of the vanishing point and each family segment's miss of its point on the
    horizon (in ``EDGE_NOISE`` units, longer segments weighing more), with ``orthogonal`` the
    cosine of the two families' angle on the ground (in ``ORTHOGONAL_STD`` units), and the
    whitened distance from the prior, under a Cauchy loss."""
    from scipy.optimize import least_squares

    groups = [segments, *(f.segments for f in families)]
    weights = [np.sqrt(_segment_length(g) / _segment_length(g).mean()) / (EDGE_NOISE * height) if len(g) else g[:, 0]
               for g in groups]

    def residuals(x: np.ndarray) -> np.ndarray:
        theta = x[:3]
        line = horizon(theta, width, height)
        points = [vanishing_point(theta, width, height),
                  *(point_on_horizon(line, angle, width, height) for angle in x[3:])]
        # A segment whose middle is the point has no direction to miss by: 0, not NaN.
        misses = [np.nan_to_num(edge_residuals(point, group)) * weight
                  for point, group, weight in zip(points, groups, weights)]
        square = [_families_cosine(x, width, height) / ORTHOGONAL_STD] if orthogonal else []
        return np.concatenate([*misses, square, whiten @ (theta - prior)])

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

    def median(self) -> np.ndarray:
        """The samples' median (grey, at most ``WORK_WIDTH`` wide): the scene without what moves."""
        if any(g.shape != self._grey[-1].shape for g in self._grey):
            self._grey, self._ground = self._grey[-1:], self._ground[-1:]  # the frame size changed
        return np.median(np.stack(self._grey), axis=0).astype(np.uint8)

    def segments(self) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
        """Segments of the samples' median off and on the ground (``scene_segments``) and that
        image's (width, height)."""
        background = self.median()
        masks = [g for g in self._ground if g is not None and g.shape == background.shape]
        ground = np.mean(masks, axis=0) > 0.5 if masks else None
        return (*scene_segments(background, ground), (background.shape[1], background.shape[0]))
