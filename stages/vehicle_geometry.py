"""Vehicle height from its outline through the calibrated camera: a box on the ground, roof above.

The foot/top geometry (``stages.geometry``) assumes the object's top stands above its foot. A
vehicle seen from a mast breaks that: the top of its outline is the far edge of its roof, metres
behind the front bumper, and the foot/top height comes out ~1 m high (generator dev set). Its
outline still holds the answer once the vehicle is a box standing on the ground:

1. The lower outline (per column, the lowest pixel) runs along the near bottom edges of the body.
   Its convex hull from below bridges the wheel arches; hull segments steeper than
   ``CONSTANTS.max_bottom_slope`` are the box's vertical edges and are left out.
2. Those points, a little above the road (``CONSTANTS.body_clearance_m``), span the footprint: the
   rectangle whose sides they hug (an L where two sides are seen). A side seen
   edge-on spans a line, narrower than any vehicle: it is widened away from the camera to a
   typical width (road vehicles are 1.7-2.55 m wide). An end seen alone hides the length, and
   with it the roof's far edge: it gets a car's length (``CONSTANTS.end_on_length_m``), flagged as assumed.
3. Each column's top pixel sees the roof somewhere inside the box; where its ray leaves the roof
   on the far side, the roof is at least that high (exactly that high on a box-shaped van, bus or
   truck body). A car's roof is its cabin's, a share of its body (``CONSTANTS.car_roof_share``). The height
   is a high percentile over columns.

Generator data, whole vehicles (visible > 90 %) on held-out sequences (data/trk_val20), median
error / median |error| of one outline: on true masks -7 / 9 cm for cars, -11 / 13 cm for vans;
on the shipped model's masks -8 / 20 cm and +3 / 7 cm; the foot/top geometry reads ~1 m high.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from core.packets import CameraInfo
from stages.calibration import camera_centre, pixel_rays, pixel_to_ground


@dataclass(frozen=True)
class VehicleGeometryConstants:
    """The vehicle box's fixed numbers: road vehicles' shapes and how their outlines read
    (the rule is in docs/design.md, Configuration)."""

    # The lower outline's points are taken this high above the road: its ends are the bumpers' lower
    # edges (~0.3 m up), but seen from the side it runs under the wheels (0 m). On the road plane the
    # footprint came out ~0.2 m long at each end and the heights 0.1-0.25 m low; held-out generator
    # sequences with the shipped model's masks, median |error| per detection: 0 m 17 cm, 0.15 m 14,
    # 0.2 m 13, 0.3 m 16 (true masks: best at 0.3 m, 8 cm; both before ends seen alone got a box).
    # A side view reads ~0.15 m high.
    body_clearance_m: float = 0.2
    # Lower-outline hull segments steeper than this (rows per column, ~72 degrees) are the box's
    # vertical edges, not its bottom: a bottom edge seen from a mast slopes far less.
    max_bottom_slope: float = 3.0
    # A footprint narrower than this is one side seen edge-on (road vehicles are 1.7-2.55 m wide);
    # it is widened to the typical width.
    min_width_m: float = 1.6
    # A footprint shorter than this is no vehicle seen from the side (a bicycle is under 2 m long):
    # it is an end (a car's front is 1.7-1.9 m wide) whose length, and so the roof's far edge, is
    # hidden; the box takes a car's length for it. Or it is a bicycle seen from the side: the tracker
    # tells the two apart by the way the object moves (along ``VehicleBox.axis_xy`` or across it).
    min_length_m: float = 2.6
    end_on_length_m: float = 4.4
    # Typical widths: a car's or a van's, and a bus's or a truck's (those longer than
    # ``long_vehicle_m``); none is wider than ``max_width_m`` (the legal 2.55 m and mirrors' slack).
    typical_width_m: dict[str, float] = field(default_factory=lambda: {"short": 1.85, "long": 2.5})
    max_width_m: float = 2.6
    long_vehicle_m: float = 6.0
    # Footprints shorter than this are cars, whose roof covers this share of their length and width.
    car_max_length_m: float = 5.0
    car_roof_share: tuple[float, float] = (0.55, 0.9)
    # Share of the outline's columns whose roof lies lower than the reported height: high, as each
    # column's reading is a lower bound, but not the maximum, which one ragged column would set.
    top_percentile: float = 90.0
    # Columns needed on the top outline inside the footprint: fewer are no outline to fit.
    min_columns: int = 3


CONSTANTS = VehicleGeometryConstants()


@dataclass
class VehicleBox:
    """The box fitted to one outline (world metres)."""

    height_m: float
    pixel_noise_m: float
    """The height's std from the top outline's pixel noise."""
    length_m: float
    width_m: float
    centre_xy_m: tuple[float, float]
    axis_xy: tuple[float, float]
    """Unit vector along the box's length on the ground (its sign means nothing)."""
    length_assumed: bool = False
    """Only an end was seen: the length is ``CONSTANTS.end_on_length_m``, a guess (see ``_footprint``)."""


def vehicle_box(camera: CameraInfo, outline: np.ndarray, origin: tuple[float, float],
                top_noise_px: float = 0.0, heading: np.ndarray | None = None) -> VehicleBox | None:
    """Box under ``outline`` (bool, origin = its top-left pixel corner in undistorted pixels).

    ``top_noise_px``: std of the top outline's rows; the height's share of it comes back as
    ``pixel_noise_m``. ``heading`` (a ground direction) replaces the footprint's fitted one.
    None when the outline has too few columns on the ground or under the horizon.
    """
    cols = np.flatnonzero(outline.any(axis=0))
    if cols.size < CONSTANTS.min_columns:
        return None
    x0, y0 = origin
    top = np.argmax(outline[:, cols], axis=0).astype(float)
    bottom = (outline.shape[0] - np.argmax(outline[::-1, cols], axis=0)).astype(float)

    footprint = _footprint(camera, _lower_hull_points(x0 + cols, y0 + bottom), heading)
    if footprint is None:
        return None
    centre, axes, half, length_assumed = footprint
    # A car's roof is its cabin's, about half its length and a little narrower than its body: the
    # top outline's rays graze the cabin's far edge, not the body's.
    roof = half * np.asarray(CONSTANTS.car_roof_share) if 2 * half[0] < CONSTANTS.car_max_length_m else half
    heights = [_roof_height(camera, np.column_stack([x0 + cols + 0.5, y0 + top + shift]), centre, axes, roof)
               for shift in (0.0, top_noise_px, -top_noise_px)]
    if any(h is None for h in heights):
        return None
    return VehicleBox(height_m=heights[0], pixel_noise_m=abs(heights[1] - heights[2]) / 2.0,
                      length_m=float(2 * half[0]), width_m=float(2 * half[1]),
                      centre_xy_m=(float(centre[0]), float(centre[1])),
                      axis_xy=(float(axes[0, 0]), float(axes[0, 1])), length_assumed=bool(length_assumed))


def _roof_height(camera: CameraInfo, top_px: np.ndarray, centre: np.ndarray, axes: np.ndarray,
                 roof_half: np.ndarray) -> float | None:
    """Where the top pixels' rays leave the roof's prism on the far side: its height (percentile)."""
    rays = pixel_rays(camera, top_px)
    eye = camera_centre(camera)
    # The ray's ground track eye + s * ray, in the footprint's frame.
    position = (eye[:2] - centre) @ axes.T
    direction = rays[:, :2] @ axes.T
    with np.errstate(divide="ignore", invalid="ignore"):
        near = (-roof_half - position) / direction
        far = (roof_half - position) / direction
    enter = np.max(np.minimum(near, far), axis=1)
    leave = np.min(np.maximum(near, far), axis=1)
    inside = np.isfinite(enter) & np.isfinite(leave) & (leave > enter) & (leave > 0)
    if inside.sum() < CONSTANTS.min_columns:
        return None
    return float(np.percentile(eye[2] + leave[inside] * rays[inside, 2], CONSTANTS.top_percentile))


def _lower_hull_points(columns: np.ndarray, bottoms: np.ndarray) -> np.ndarray:
    """Points along the lower outline's hull from below (pixel corners), vertical edges left out."""
    xs = np.concatenate([columns, columns + 1.0]).astype(float)
    ys = np.concatenate([bottoms, bottoms])
    order = np.lexsort((ys, xs))
    hull: list[tuple[float, float]] = []
    for point in zip(xs[order], ys[order]):
        # Keep the chain concave in image rows (y grows downwards): it bounds the outline from below.
        while len(hull) >= 2 and _cross(hull[-2], hull[-1], point) >= 0:
            hull.pop()
        hull.append(point)
    pieces = []
    for (xa, ya), (xb, yb) in zip(hull[:-1], hull[1:]):
        if xb - xa <= 0 or abs(yb - ya) > CONSTANTS.max_bottom_slope * (xb - xa):
            continue
        t = np.linspace(0.0, 1.0, max(2, int(np.ceil(xb - xa)) + 1))
        pieces.append(np.column_stack([xa + t * (xb - xa), ya + t * (yb - ya)]))
    return np.vstack(pieces) if pieces else np.zeros((0, 2))


def _cross(o: tuple[float, float], a: tuple[float, float], b: tuple[float, float]) -> float:
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


def _l_shape_frame(points: np.ndarray):
    """Axes (unit vectors) and bounds of the rectangle whose sides the points hug best.

    The near sides of a footprint seen from one place form an L. The minimum-area rectangle of
    an L is ambiguous (one along the L's diagonal has the same area), so the heading is the one,
    in 1-degree steps, that brings the points closest to their bounding rectangle's sides
    (the "closeness" criterion of L-shape fitting in lidar vehicle detection).
    """
    angles = np.deg2rad(np.arange(0.0, 90.0, 1.0))
    coords_along = points @ np.array([np.cos(angles), np.sin(angles)])
    coords_across = points @ np.array([-np.sin(angles), np.cos(angles)])
    def to_sides(coords):
        return np.minimum(coords - coords.min(axis=0), coords.max(axis=0) - coords)
    cost = np.minimum(to_sides(coords_along), to_sides(coords_across)).sum(axis=0)
    best = int(np.argmin(cost))
    along = np.array([np.cos(angles[best]), np.sin(angles[best])])
    across = np.array([-along[1], along[0]])
    lo = np.array([coords_along[:, best].min(), coords_across[:, best].min()])
    hi = np.array([coords_along[:, best].max(), coords_across[:, best].max()])
    return along, across, lo, hi


def _footprint(camera: CameraInfo, bottom_px: np.ndarray, heading: np.ndarray | None = None):
    """(centre, 2x2 axes (rows: length, width), half extents, length assumed?) on the ground, or None."""
    if len(bottom_px) < CONSTANTS.min_columns:
        return None
    ground = pixel_to_ground(camera, bottom_px, CONSTANTS.body_clearance_m)
    ground = ground[np.all(np.isfinite(ground), axis=1)]
    if len(ground) < CONSTANTS.min_columns:
        return None
    if heading is None:
        along, across, lo, hi = _l_shape_frame(ground)
    else:
        along = np.asarray(heading, float) / np.hypot(*heading)
        across = np.array([-along[1], along[0]])
        coords = ground @ np.array([along, across]).T
        lo, hi = coords.min(axis=0), coords.max(axis=0)
    centre = (lo[0] + hi[0]) / 2.0 * along + (lo[1] + hi[1]) / 2.0 * across
    length, width = hi - lo
    if length < width:
        along, across, length, width = across, -along, width, length
    assumed = length < CONSTANTS.min_length_m
    if assumed:
        if length < CONSTANTS.min_width_m:
            return None           # narrower than any vehicle's end: a bicycle, a person
        # Only an end is seen (a vehicle driving towards or away from the camera): what was taken
        # for its length is its width, and its length runs away from the camera, hidden.
        along, across, length, width = across, along, CONSTANTS.end_on_length_m, length
    away = across if across @ (centre - camera_centre(camera)[:2]) > 0 else -across
    if assumed:
        ahead = along if along @ (centre - camera_centre(camera)[:2]) > 0 else -along
        visible = float(np.ptp(ground @ ahead))
        centre = centre + ahead * (CONSTANTS.end_on_length_m - visible) / 2.0
    if width < CONSTANTS.min_width_m:
        # One side seen edge-on: the rest of the vehicle lies behind it, away from the camera.
        typical = CONSTANTS.typical_width_m["long" if length > CONSTANTS.long_vehicle_m else "short"]
        centre = centre + away * (typical - width) / 2.0
        width = typical
    elif width > CONSTANTS.max_width_m:
        # The near side is seen; the far one came out too far (the front's lower edge stands above
        # the road, a blurred mask rounds the corner): no road vehicle is wider.
        centre = centre - away * (width - CONSTANTS.max_width_m) / 2.0
        width = CONSTANTS.max_width_m
    return centre, np.array([along, across]), np.array([length / 2.0, width / 2.0]), assumed
