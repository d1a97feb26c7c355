"""Measuring one detected object: its class, its ends (crown and soles), its robust top height.

Pure functions on masks and height maps, used by ``ObjectExtractor`` for every piece a blob
becomes; the robust top, the hidden-foot test and the noise also for every network box
(``stages.network_objects``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.packets import Detection


@dataclass(frozen=True)
class ObjectMeasurementConstants:
    """Fixed numbers of measuring one object (the rule is in docs/design.md, Configuration)."""

    # A blob whose bottom tenth stands higher than this share of its top has no visible foot
    # (Oxford, step-4,400 model: whole people 0.16-0.28, blobs missing their legs 0.22-0.49).
    foot_max_share: float = 0.4


CONSTANTS = ObjectMeasurementConstants()


def coarse_class(height_m: float, box_w_px: float, box_h_px: float) -> str:
    """Person / cyclist / vehicle / other from the object's height and its image shape.

    The metric width is estimated as box width times the metres per pixel implied by the
    height (exact for a side view, an underestimate when the camera looks down on a long
    footprint). Crude on purpose: the tracker votes over many frames.
    """
    if not np.isfinite(height_m) or box_h_px <= 0:
        return "other"
    width_m = box_w_px * height_m / box_h_px
    aspect = box_w_px / box_h_px
    if height_m > 2.4:
        return "vehicle"              # buses, trucks, vans
    if width_m > 2.6:
        return "vehicle"              # cars seen from the side
    if 1.0 <= height_m <= 2.2 and aspect < 0.75:
        return "person"
    if 1.3 <= height_m <= 2.2 and width_m <= 2.6:
        return "cyclist" if width_m >= 1.0 and aspect < 1.6 else "vehicle"
    if height_m >= 1.0:
        return "vehicle"
    return "other"


def moving_beyond_ends(part: np.ndarray, offset: tuple[int, int], grown: np.ndarray,
                       edge: np.ndarray) -> tuple[bool, bool]:
    """Whether the moving region goes on from the part's top (foot) to the image edge.

    The height map can end before the object does: near the frame's top the network marked a
    walker's white shirt as ground (Oxford), leaving a blob of legs whose top is no head. When
    the grown foreground above the blob runs without a gap to the image edge in most of the
    blob's top columns, the object may go on outside the frame: its top is not measured (and
    likewise its foot, below).
    """
    rows = np.flatnonzero(part.any(axis=1))
    if rows.size == 0:
        return False, False
    x, y = offset
    top, bottom = y + rows[0], y + rows[-1]
    top_cols = x + np.flatnonzero(part[rows[0]:rows[0] + 2].any(axis=0))
    foot_cols = x + np.flatnonzero(part[max(rows[-1] - 1, 0):rows[-1] + 1].any(axis=0))
    up = _runs_to_edge(grown[:top, top_cols][::-1], edge[:top, top_cols][::-1])
    down = _runs_to_edge(grown[bottom + 1:, foot_cols], edge[bottom + 1:, foot_cols])
    return up, down


def foreground_ends(part: np.ndarray, offset: tuple[int, int], changed: np.ndarray, moving: np.ndarray,
                    reach: int) -> tuple[int, int]:
    """Top and bottom rows (work pixels) of the object's geometry points: its crown and its soles.

    The part is the grown foreground cut to the height map. Its top overshoots the head by up to
    the growth wherever the height map is blurred (generator people: the box top 3 px over the
    crown, geometry heights +13 cm), so the crown is the part's first row that the background
    model saw change at all: moving, or marked as shadow (KNN calls dark hair over a light
    street a shadow: on Oxford Town Centre the moving pixels alone put the crown 8 px low, with
    the shadow mark 3 px, the grown box 13 px off either way). Its bottom ends where the height
    map drops under the ground threshold, above the soles: where moving pixels reach the part's
    last row they are followed down, at most ``reach`` rows (not through shadow marks: a cast
    shadow lies on the ground beside the feet).
    """
    rows = np.flatnonzero(part.any(axis=1))
    if rows.size == 0:
        return offset[1], offset[1]
    x, y = offset
    window = (slice(y, y + part.shape[0]), slice(x, x + part.shape[1]))
    seen = np.flatnonzero((part & changed[window]).any(axis=1))
    top = y + int(seen[0] if seen.size else rows[0])
    bottom = y + int(rows[-1])
    cols = x + np.flatnonzero(part[rows[-1]] & moving[window][rows[-1]])
    if cols.size:
        below = moving[bottom + 1:bottom + 1 + reach, cols].any(axis=1)
        bottom += int(below.size if below.all() else np.argmin(below))
    return top, bottom


def fit_box_to_ends(detection: Detection) -> None:
    """The detection's box (with its mask and outline) from its crown row down to its soles.

    The box is the grown foreground cut to the height map: its top overshoots the crown by the
    growth and its bottom ends where the height map drops under the ground threshold, above the
    soles (trk_val20, people: box top 1.3 px high, bottom 1.6 px short of the truth, median IoU
    0.65). Tracking scores and the track's box should be the object's, so the box takes the
    geometry's ends: rows above the crown are cropped, rows down to the soles added (empty).
    """
    x, y, w, h = detection.box
    top, bottom = int(round(detection.top_xy[1])), int(round(detection.foot_xy[1]))
    # A top that the frame cuts is not the crown: the box keeps the frame's edge (Oxford: a walker
    # leaving at the top, cropped to where it changed, was taken over by a 0.86 m fragment).
    if detection.top_cut:
        top = int(y)
    top = min(max(top, int(y)), int(y + h) - 1)
    bottom = max(bottom, top + 1)
    if top == int(y) and bottom == int(y + h):
        return

    def reframed(mask: np.ndarray | None) -> np.ndarray | None:
        if mask is None:
            return None
        out = np.zeros((bottom - top, mask.shape[1]), dtype=bool)
        keep = mask[top - int(y):bottom - int(y)]
        out[:keep.shape[0]] = keep
        return out

    detection.mask, detection.outline = reframed(detection.mask), reframed(detection.outline)
    detection.box = (x, float(top), w, float(bottom - top))


def seen_outline(part: np.ndarray, offset: tuple[int, int], changed: np.ndarray) -> np.ndarray:
    """The part from each column's first row that the background model saw change, down.

    The part's top overshoots the object by the foreground's growth wherever the height map is
    blurred (as at the crown, see ``foreground_ends``); a vehicle's outline top is its far roof
    edge, which the vehicle geometry reads column by column. Columns with no change keep the part.
    """
    x, y = offset
    seen = part & changed[y:y + part.shape[0], x:x + part.shape[1]]
    first = np.where(seen.any(axis=0), np.argmax(seen, axis=0), 0)
    return part & (np.arange(part.shape[0])[:, None] >= first[None, :])


def _runs_to_edge(moving: np.ndarray, edge: np.ndarray) -> bool:
    """Columns walked from row 0 on: in at least half, the moving run reaches the edge (or the end)."""
    if moving.shape[1] == 0:
        return False
    length = moving.shape[0]
    if length == 0:
        return True               # the part ends on the frame's own border
    first_gap = np.where((~moving).any(axis=0), np.argmax(~moving, axis=0), length)
    first_edge = np.where(edge.any(axis=0), np.argmax(edge, axis=0), length)
    return bool(np.mean(first_edge <= first_gap) >= 0.5)


def foot_above_ground(heights: np.ndarray, mask: np.ndarray, rows: np.ndarray, top_m: float) -> bool:
    """The blob's bottom stands well above the ground: its feet are hidden or not foreground.

    A blob of only a head and shoulders (a dark coat the background model missed, a person
    behind a bench) ends where the object does not touch the ground; its lowest point is no
    foot for the geometry. Checked on the height map: the bottom tenth of the blob must be
    lower than ``CONSTANTS.foot_max_share`` of the object's top.
    """
    if rows.size == 0 or not np.isfinite(top_m) or top_m <= 0:
        return False
    band = mask.copy()
    band[:max(rows[-1] + 1 - max(1, int(0.1 * (rows[-1] - rows[0] + 1))), 0)] = False
    values = heights[band]
    values = values[np.isfinite(values)]
    return bool(values.size and np.median(values) > CONSTANTS.foot_max_share * top_m)


def height_noise(base_m: float, height_m: float, box_h_px: float, touches_border: bool) -> float:
    """One frame's height noise: the base noise, plus the size of one pixel at the object, times 3
    when the object touches the image's border (its top or foot may be outside the image)."""
    metres_per_px = height_m / max(box_h_px, 1.0)
    noise = float(np.hypot(base_m, 2.0 * metres_per_px))
    if touches_border:
        noise *= 3.0
    return noise


def robust_top(heights: np.ndarray, mask: np.ndarray, percentile: float) -> float:
    """The object's top height from its pixels: a high percentile, then a half-row correction.

    The percentile (below 100) ignores single-pixel spikes of a noisy height map. A pixel sees
    the surface at its centre, so the topmost pixel on a round top (a head) lies below the
    apex by up to half a row: where the top row is higher than the row under it, half that
    step is added. A flat top (a roof) has no step and gets nothing.
    """
    masked = np.where(mask, heights, np.nan)
    values = masked[np.isfinite(masked)]
    if values.size == 0:
        return float("nan")
    if percentile >= 100:
        top = float(values.max())
    else:
        k = max(1, int(round(values.size * (1 - percentile / 100.0))))
        top = float(np.partition(values, values.size - k)[values.size - k])
    with np.errstate(all="ignore"):
        row_top = np.nanmax(np.where(np.isfinite(masked), masked, -np.inf), axis=1)
    reaching = np.flatnonzero(row_top >= top)
    if reaching.size and reaching[0] + 1 < len(row_top) and np.isfinite(row_top[reaching[0] + 1]):
        step = row_top[reaching[0]] - row_top[reaching[0] + 1]
        top += 0.5 * float(np.clip(step, 0.0, None))
    return top
