"""Objects from the height network's detection head (``objects.source = "network"``).

The network's boxes are the objects: each box scoring at least its class's threshold
(``objects.score_<class>``) becomes a ``Detection`` of the network's class, whether it moves or
not, so a person standing still (whom a primed background model holds, and blobs never find) is
found. Motion is a cue, never the gate: a weaker box (down to ``objects.score_motion``) is kept
only while it moves, i.e. at least ``objects.moving_share`` of its pixels above the ground are
foreground, ``objects.motion_contrast`` more than of the ring around it (``_moving``), or while it
stays put: a box of its class lay where it lies in every frame of the last ``objects.still_s``
seconds (``_still``: a person standing still, whom no motion confirms). A box
weaker still, or one that does not move, down to ``objects.continue_score``, is passed on as
``continues_only``: the tracker lets it carry on a track it lies on, never start one. A motion
blob that no network box covers is no object unless it is big (``big_blob_share`` of the
frame's height: a network without a big-object head misses most objects that big; with one, no
blob is) or ``objects.keep_motion_blobs`` says so (``uncovered_blobs``). A box lying mostly inside
a stronger kept box is that object's fragment (``fragment_share``), not a second object.

Each box is measured like a blob (``stages.object_measurements``): its own pixels are the box's
pixels above the ground, its single-frame height the robust top of the height map on them. Scenery
seen past the object inside the box does not raise it when the camera is above the object: a ray
through the box passes the object's vertical no higher than its top (the box's rows run from
the crown down) and descends from there, so what it meets behind stands lower. The geometry's
foot and top are the box's bottom and top centres (the network's sub-pixel box, not the pixels
it covers), moved out to where the object's motion ends with ``objects.motion_ends``
(``motion_ends``). Heights outside ``objects.min_object_height_m`` ..
``max_object_height_m`` are no measurement (the height map failed on the object; it stays an
object); a box whose top or bottom centre reaches the image's edge is cut there, as a blob is.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.config import NETWORK_OBJECTS_KEYS, ObjectsConfig
from core.errors import ConfigError
from core.packets import NETWORK, Detection, Measurement, NetworkDetections
from stages.centre_detections import box_iou
from stages.object_measurements import foot_above_ground, height_noise, robust_top

SOURCES = ("blobs", "network")
CLASS_PREFIX = "score_"
"""A class's threshold is the ``[objects]`` key ``score_<class>``."""


@dataclass(frozen=True)
class NetworkObjectConstants:
    """Fixed numbers of turning network boxes into detections (the rule is in docs/design.md,
    Configuration)."""

    # A motion blob is one of the network's objects when at least this share of its pixels lies in
    # the kept boxes: a box drawn round a walker covers most of the walker's blob, and a blob of two
    # walkers is covered by their two boxes together.
    blob_covered_share: float = 0.5
    # A moving blob no kept box covers is an object anyway when at least this share of the frame
    # tall: the head (v2 at 500,000 images) misses most objects that big (a car or a truck near
    # the camera: boxes 80-160 px in 320x240 frames found 24 % of the time on the dev set).
    big_blob_share: float = 0.25
    # A box lying at least this share inside a stronger kept box is a fragment of that object
    # (the head's second peak on a car's cab or a walker's legs), not an object of its own.
    fragment_share: float = 0.5
    # Motion ends (``objects.motion_ends``): a row past the box's end is the object's while at least
    # this share of the box's middle half of columns is foreground there ...
    ends_row_share: float = 0.2
    # ... for at most this share of the box's height below its bottom and above its top.
    ends_reach_below: float = 0.5
    ends_reach_above: float = 0.25
    # Still boxes (``objects.still_s``): a box lies where another lay at this IoU or more.
    still_iou: float = 0.5


CONSTANTS = NetworkObjectConstants()


def class_thresholds(config: ObjectsConfig) -> dict[str, float]:
    """Each class's score threshold from the ``score_<class>`` keys of ``[objects]``."""
    return {key[len(CLASS_PREFIX):]: getattr(config, key) for key in NETWORK_OBJECTS_KEYS
            if key.startswith(CLASS_PREFIX) and key != "score_motion"}


def min_score(config: ObjectsConfig) -> float:
    """The weakest score any box is kept at: the network need not decode weaker peaks."""
    return min(config.score_motion, config.continue_score, *class_thresholds(config).values())


def check_config(config: ObjectsConfig) -> None:
    """ConfigError for a source, a score or a height percentile that cannot work (both modes: the
    extractor checks its whole section)."""
    if config.source not in SOURCES:
        raise ConfigError(f"objects.source must be one of {', '.join(SOURCES)}, got {config.source!r}")
    for key in [*(CLASS_PREFIX + cls for cls in class_thresholds(config)), "score_motion", "moving_share",
                "motion_contrast", "continue_score"]:
        if not 0.0 <= getattr(config, key) <= 1.0:
            raise ConfigError(f"objects.{key} must be between 0 and 1, got {getattr(config, key)}")
    if not config.still_s >= 0.0:
        raise ConfigError(f"objects.still_s must be 0 (off) or more seconds, got {config.still_s}")
    for key in ("height_percentile", "vehicle_height_percentile"):
        if not 0.0 < getattr(config, key) <= 100.0:
            raise ConfigError(f"objects.{key} must be above 0 and at most 100, got {getattr(config, key)}")


def check_classes(config: ObjectsConfig, classes: tuple[str, ...] | list[str], model: str) -> None:
    """ConfigError when the model detects a class that has no threshold key."""
    missing = [cls for cls in classes if cls not in class_thresholds(config)]
    if missing:
        raise ConfigError(f"{model} detects {', '.join(missing)}, for which [objects] has no "
                          f"{', '.join(CLASS_PREFIX + cls for cls in missing)} threshold")


def network_objects(found: NetworkDetections | None, config: ObjectsConfig, height_threshold_m: float,
                    height_map: np.ndarray | None, ground_mask: np.ndarray | None,
                    foreground: np.ndarray | None, edge: np.ndarray,
                    earlier: list[list[tuple[np.ndarray, str]]] = ()) -> list[Detection]:
    """The network's boxes that are objects this frame, measured.

    Parameters
    ----------
    found : NetworkDetections or None
        The network's detections in frame pixels (None: the model has no detection head).
    config : ObjectsConfig
        Thresholds (``score_*``, ``moving_share``) and the height measurement's keys.
    height_threshold_m : float
        Pixels lower than this are ground (``[ground]``).
    height_map, ground_mask, foreground : ndarray or None
        The frame's maps at source size (None where the run has none).
    edge : ndarray
        Source-size bool: pixels where the image may end (frame border, undistortion's black).
    earlier : list
        The ``still_candidates`` of every frame of the last ``still_s`` seconds (none: the run has
        not seen that long yet, or ``still_s`` is off).
    """
    if found is None or len(found) == 0:
        return []
    thresholds = class_thresholds(config)
    frame_h, frame_w = edge.shape
    detections = []
    for box, cls, score in zip(found.boxes, found.classes, found.scores):
        limit = thresholds.get(cls)
        if limit is None or score < min(limit, config.score_motion, config.continue_score):
            continue
        clipped = np.clip(np.asarray(box, float), 0.0, [frame_w, frame_h, frame_w, frame_h])
        # The pixels the box covers: its edges to the nearest pixel edge, as the truth's boxes
        # are pixel extents (rounded outward, every box grew by a pixel in each direction on
        # average: held-out HOTA 0.548 against 0.550, and with the box refiner dev2 0.507 against
        # 0.514; docs/results.md, 2026-12-08).
        x0, y0 = int(np.rint(clipped[0])), int(np.rint(clipped[1]))
        x1, y1 = int(np.rint(clipped[2])), int(np.rint(clipped[3]))
        if x1 <= x0 or y1 <= y0:
            continue
        own = _own_pixels((x0, y0, x1, y1), height_map, ground_mask, height_threshold_m)
        weak = score < limit and not (score >= config.score_motion and (_moving(
            foreground, (x0, y0, x1, y1), own, config.moving_share, config.motion_contrast)
            or _still(clipped, cls, earlier)))
        if weak and score < config.continue_score:
            continue
        # A weak box is no fragment-maker: a box that is an object is measured against objects only.
        stronger = [kept for kept, other in detections if weak or not other.continues_only]
        if _inside_any(clipped, stronger) >= CONSTANTS.fragment_share:
            continue
        ends = clipped[[1, 3]]
        if config.motion_ends and foreground is not None:
            ends = motion_ends(foreground, clipped)[[1, 3]]
        percentile = config.vehicle_height_percentile if cls == "vehicle" else config.height_percentile
        detection = _measure_box(clipped, (x0, y0, x1, y1), ends, own, height_map, edge, config, percentile)
        detection.score = float(score)
        detection.continues_only = weak
        detection.classify(cls, NETWORK)
        detections.append((clipped, detection))
    return [detection for _, detection in detections]


def still_candidates(found: NetworkDetections | None, config: ObjectsConfig,
                     frame_size: tuple[int, int]) -> list[tuple[np.ndarray, str]]:
    """This frame's boxes (x0, y0, x1, y1, clipped to the frame) scoring at least ``score_motion``,
    with their classes: what a later frame's ``_still`` looks back at."""
    if found is None or config.still_s <= 0:
        return []
    width, height = frame_size
    return [(np.clip(np.asarray(box, float), 0.0, [width, height, width, height]), cls)
            for box, cls, score in zip(found.boxes, found.classes, found.scores) if score >= config.score_motion]


def _still(box: np.ndarray, cls: str, earlier: list[list[tuple[np.ndarray, str]]]) -> bool:
    """Whether a box of class ``cls`` lay where ``box`` lies (IoU >= ``CONSTANTS.still_iou``) in
    each of the ``earlier`` frames (none: no).

    Why: the head scores a person standing still as weakly as a walker (dev set: 33 % of standing
    people's best box at 0.35-0.5, 23 % at 0.5 or more), and a weak box counts only while it moves.
    A box that stays put frame after frame is the head seeing the same thing again, not one
    frame's noise."""
    if not earlier:
        return False
    for boxes in earlier:
        same = [other for other, other_cls in boxes if other_cls == cls]
        if not same or box_iou(box[None], np.asarray(same))[0].max() < CONSTANTS.still_iou:
            return False
    return True


def _inside_any(box: np.ndarray, others: list[np.ndarray]) -> float:
    """The largest share of ``box``'s area (x0, y0, x1, y1) that lies inside one of ``others``."""
    if not others:
        return 0.0
    others = np.asarray(others)
    width = np.clip(np.minimum(box[2], others[:, 2]) - np.maximum(box[0], others[:, 0]), 0, None)
    height = np.clip(np.minimum(box[3], others[:, 3]) - np.maximum(box[1], others[:, 1]), 0, None)
    area = max(float((box[2] - box[0]) * (box[3] - box[1])), 1e-9)
    return float((width * height).max() / area)


def motion_blob_floor(config: ObjectsConfig, frame_height: int, found: NetworkDetections | None = None) -> float:
    """Height (frame pixels) from which a moving blob no kept box covers is an object: any with
    ``keep_motion_blobs``; none (infinity) when the network has a big-object head (``found``'s
    ``big_objects``: it boxes the near, big objects itself); else only those a head without one is
    known to miss (``big_blob_share``)."""
    if config.keep_motion_blobs:
        return 0.0
    if found is not None and found.big_objects:
        return float("inf")
    return CONSTANTS.big_blob_share * frame_height


def uncovered_blobs(blobs: list[Detection], boxes: list[Detection], min_height_px: float = 0.0) -> list[Detection]:
    """The blob detections at least ``min_height_px`` tall that the network's kept boxes do not
    cover (``blob_covered_share``)."""
    kept = []
    for blob in blobs:
        if blob.box[3] < min_height_px:
            continue
        x, y, w, h = (int(round(v)) for v in blob.box)
        pixels = np.ones((h, w), bool) if blob.mask is None or blob.mask.shape != (h, w) else blob.mask
        covered = np.zeros((h, w), bool)
        for box in boxes:
            bx, by, bw, bh = box.box
            c0, r0 = max(int(np.floor(bx)) - x, 0), max(int(np.floor(by)) - y, 0)
            c1, r1 = min(int(np.ceil(bx + bw)) - x, w), min(int(np.ceil(by + bh)) - y, h)
            if c1 > c0 and r1 > r0:
                covered[r0:r1, c0:c1] = True
        if not pixels.any() or (covered & pixels).sum() < CONSTANTS.blob_covered_share * pixels.sum():
            kept.append(blob)
    return kept


def motion_ends(foreground: np.ndarray, box: np.ndarray) -> np.ndarray:
    """The box (x0, y0, x1, y1) with its bottom and top moved out to where the object's foreground
    stops: rows past each end are followed while at least ``ends_row_share`` of the box's middle
    half of columns is foreground, up to ``ends_reach_below`` / ``ends_reach_above`` of its height.

    Why: the head's boxes end short of people's soles and under their crowns (Oxford's near
    walkers: up to 60 px short of the feet), and the geometry reads heights from those ends; a
    walker's moving pixels run on to his soles and crown. Measured (docs/results.md, 2026-12-04
    eighth session): tracked people 17.2 -> 12.5 cm on the dev set and Oxford's calibrated heights
    27.6 -> 24.1 cm, but 8.7 -> 10.5 cm on held-out trk_val20, hence off by default. Only
    the geometry points move, not the box the tracker matches (taller boxes lost detections).
    Only outward: a still object has no motion to cut it by, and nothing is followed where the
    row next to the end does not move (a person in front, below the box, is not reached across
    a gap).
    """
    height, width = foreground.shape
    x0, y0, x1, y1 = (float(v) for v in box)
    box_h = y1 - y0
    quarter = (x1 - x0) / 4.0
    c0 = min(max(int(round(x0 + quarter)), 0), width - 1)
    c1 = max(min(int(round(x1 - quarter)), width), c0 + 1)
    middle = foreground[:, c0:c1]

    def run(rows: np.ndarray) -> int:
        """How many of ``rows`` (in order, from the box's end out) move, without a gap."""
        if rows.size == 0:
            return 0
        moving = middle[rows].mean(axis=1) >= CONSTANTS.ends_row_share
        return int(moving.size if moving.all() else np.argmin(moving))

    bottom, top = int(np.ceil(y1)), int(np.floor(y0))
    below = np.arange(bottom, min(bottom + int(CONSTANTS.ends_reach_below * box_h), height))
    above = np.arange(top - 1, max(top - 1 - int(CONSTANTS.ends_reach_above * box_h), -1), -1)
    down, up = run(below), run(above)
    return np.array([x0, top - up if up else y0, x1, bottom + down if down else y1])


def _own_pixels(corners: tuple[int, int, int, int], height_map: np.ndarray | None,
                ground_mask: np.ndarray | None, height_threshold_m: float) -> np.ndarray:
    """Box-sized bool: the box's pixels above the ground (all of them without a height map)."""
    x0, y0, x1, y1 = corners
    if height_map is None:
        return np.ones((y1 - y0, x1 - x0), bool)
    own = np.nan_to_num(height_map[y0:y1, x0:x1], nan=0.0) > height_threshold_m
    if ground_mask is not None:
        own &= ~ground_mask[y0:y1, x0:x1]
    return own


def _moving(foreground: np.ndarray | None, corners: tuple[int, int, int, int], own: np.ndarray,
            share: float, contrast: float) -> bool:
    """Whether at least ``share`` of the object's own pixels (the whole box if it has none) move,
    and ``contrast`` more of them than of the ring around the box (half the box's width each
    side, a quarter of its height above and below).

    Why the ring: in rain, in a dusk frame's sensor noise or over swaying grass the foreground is
    everywhere, and the head's weak person boxes there moved as much as a walker (dev set,
    docs/results.md 2026-12-04); a walker moves against still ground around it."""
    if foreground is None:
        return False
    x0, y0, x1, y1 = corners
    moving = foreground[y0:y1, x0:x1]
    pixels = moving[own] if own.any() else moving
    if not pixels.size:
        return False
    inside = float(pixels.mean())
    if inside < share:
        return False
    if contrast <= 0.0:
        return True
    height, width = foreground.shape
    dx, dy = (x1 - x0) // 2 + 1, (y1 - y0) // 4 + 1
    X0, Y0, X1, Y1 = max(x0 - dx, 0), max(y0 - dy, 0), min(x1 + dx, width), min(y1 + dy, height)
    ring_area = (X1 - X0) * (Y1 - Y0) - moving.size
    if ring_area <= 0:
        return True
    ring = (np.count_nonzero(foreground[Y0:Y1, X0:X1]) - np.count_nonzero(moving)) / ring_area
    return inside - ring >= contrast


def _measure_box(box: np.ndarray, corners: tuple[int, int, int, int], ends: np.ndarray, own: np.ndarray,
                 height_map: np.ndarray | None, edge: np.ndarray, config: ObjectsConfig,
                 percentile: float) -> Detection:
    """The detection of one kept box: the pixels it covers, its cuts, its height (``percentile``
    of its own pixels, ``robust_top``), and its geometry points at the rows ``ends`` (top, bottom:
    the box's own, or where its motion ends)."""
    x0, y0, x1, y1 = corners
    centre_x = float(box[0] + box[2]) / 2.0
    at_edge = edge[y0:y1, x0:x1]
    touches_border = bool(at_edge.any())
    # The ends are the top and bottom centres: cut where the image may end there (a box at the
    # frame's side touches it, but its top and foot are still in view).
    column = min(max(int(centre_x), x0), x1 - 1)
    frame_h = edge.shape[0]
    top_row = min(max(int(np.floor(ends[0])), 0), frame_h - 1)
    foot_row = min(max(int(np.ceil(ends[1])) - 1, 0), frame_h - 1)
    top_cut, foot_cut = bool(edge[top_row, column]), bool(edge[foot_row, column])
    measured = {}
    if height_map is not None:
        heights = height_map[y0:y1, x0:x1]
        height_m = robust_top(heights, own, percentile)
        if config.min_object_height_m <= height_m <= config.max_object_height_m:
            noise_m = height_noise(config.height_measurement_noise_m, height_m, float(y1 - y0), touches_border)
            foot_cut = foot_cut or foot_above_ground(heights, own, np.flatnonzero(own.any(axis=1)), height_m)
            if top_cut:
                noise_m = float("inf")    # top cut off by the frame: a lower bound, not a height
            measured[NETWORK] = Measurement(height_m, noise_m, source="objects")
    return Detection(
        box=(float(x0), float(y0), float(x1 - x0), float(y1 - y0)),
        heights=measured,
        foot_xy=(centre_x, float(ends[1])),
        top_xy=(centre_x, float(ends[0])),
        touches_border=touches_border,
        foot_cut=foot_cut,
        top_cut=top_cut,
        # No outline (no vehicle box, channel BOX): a box's pixels above the ground are not the
        # object's silhouette, they hold whatever stands in the box beside it; fused, the box fitted
        # to them put v2's tracked vehicles' median bias 19-25 cm higher (docs/results.md,
        # 2026-12-05 twenty-first session). Blobs keep theirs: a foreground silhouette.
        mask=own,
    )
