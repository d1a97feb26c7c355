"""Multi-object tracking with a per-track height state.

``ObjectTracker`` is a plain class (no packets, no I/O): ``update(detections, matches)`` once
per frame returns every live track. ``TrackingStage`` wraps it for the pipeline.

One frame, in order:

1. Camera shake: the background's affine from the last frame moves every track's box state
   (and its last observation), never its height.
2. Predict every track (constant-velocity box, near-constant height). A detection holding the
   predicted boxes of two or more tracks seen a frame ago (walkers passing close: one blob) is
   cut into one piece per track (``merged_blobs``; never a box of the network's detection head);
   the pieces move boxes, not heights. The other way round, pieces of one blob side by side inside
   a vehicle track's prediction (the network's lumpy map on a bus cut it by height peaks) are
   joined into one detection for it (``vehicle_fragments``).
3. Associate (Hungarian) on a cost mixing IoU, matched-point votes, the Mahalanobis distance
   of the box, the height difference and how much the step from the track's last observed box
   goes against its motion (OC-SORT's momentum), and for the network head's boxes how far their
   colours lie from the track's (``stages.colour_signature``); pairs outside the motion gate, with
   neither overlap nor votes, or (for a track not seen last frame) with a box half or twice its
   height, are not allowed, nor are those beyond the colour gate (walkers side by side) unless
   the box lies on the prediction (IoU >= 0.7), nor those beyond the height gate unless the box
   lies on the prediction (IoU >= 0.5: then the height is a measurement gone wrong, e.g. an
   occluder's edge in the blob, and only the height filter's outlier gate skips it; the track
   keeps its object).
4. Second chance (OC-SORT's observation-centric recovery): tracks left over are matched on
   the IoU of their *last observed* box, which does not drift while the object is hidden, or
   of their predicted box grown by a buffer that widens with every frame missed (C-BIoU).
   Third (ByteTrack): confirmed tracks seen last frame and still left over take a weak box of
   the network's head (``Detection.continues_only``) lying on their prediction; weak boxes never
   start a track.
5. A track seen again after a gap is re-updated along a straight virtual path from its last
   observation (OC-SORT's observation-centric re-update), so the velocity that drifted while
   it was hidden does not carry on.
6. Height: each detection carries its height measurements by channel (``Detection.heights``).
   The network's single-frame height and, where the camera is calibrated, the geometry
   height (a person's foot and crown; a vehicle track's box fitted to its outline, if the box
   lies along the way it drives), and any channel another stage added, are fused into the
   height filter (for walkers the network's heights go through the upper quantile of a short
   window: stature, not the gait's mean dip nor a blob that lost its feet or head for a
   frame); a network height below the geometry's
   lower bound (feet cut off) is raised to it; outliers beyond ``height_gate_sigma`` are
   skipped, and a channel whose run of rejections outweighs the state restarts it. The height
   state carries each channel's bias on this object beside the height (``HeightFilter``): where
   two measure, the height settles between them by their bias priors (with the shipped network:
   nearly the geometry), and its std never falls below what those biases allow.
7. Tracks are confirmed after ``min_hits`` hits in a row (and ``confirm_s`` seconds of them)
   and dropped after ``max_misses`` frames without a hit (and ``max_miss_s`` seconds): durations,
   so that a 25 fps camera and a 10 fps one behave alike. A tentative track is dropped at its
   first miss, a coasting one when it leaves the view; of two tracks covering one object, the
   younger is dropped.
"""

from __future__ import annotations

import dataclasses
from collections import Counter, deque
from dataclasses import dataclass, field

import numpy as np

from core.config import TrackingConfig
from core.packets import BOX, GEOMETRY, NETWORK, Detection, FeatureMatches, FramePacket, Measurement, Track
from stages.association import Region, assign, direction_mismatch, feature_votes, iou_matrix
from stages.colour_signature import colour_signature, signature_distances
from stages.kalman import FilterFactory, HeightFilter, MotionFilter, MotionSnapshot, StatureWindow
from stages.merged_blobs import split_by_predictions
from stages.vehicle_fragments import join_fragments


@dataclass(frozen=True)
class TrackerConstants:
    """The tracker's fixed numbers: properties of the method, not of a camera or a scene
    (those are in ``[tracking]``; the rule is in docs/design.md, Configuration)."""

    # Cost weights next to IoU (weight 1): the motion term is the Mahalanobis distance as a share
    # of the gate, the height term the squared height difference in units of the gate.
    motion_weight: float = 0.3
    height_weight: float = 0.5
    # Weight of a step straight against the track's motion (OC-SORT's momentum term): two walkers
    # crossing while one blob swapped ids on box overlap alone (generator occlusion set).
    direction_weight: float = 0.5
    # A height filter is trusted to reject outliers only after this many measurements; a run of at
    # least this many rejections of one channel restarts it, if the run outweighs it (``_outweighs``).
    height_gate_after: int = 5
    height_restart_after: int = 8
    # A detection whose top edge lies this share of the box height below the predicted top has
    # lost its top (occluded head, merged blob split): its height is trusted this much less.
    top_lost_share: float = 0.15
    top_lost_noise_factor: float = 3.0
    # A box overlapping a track's prediction at least this much (the MOT metrics' match) is that
    # track's object whatever height it reads: the height gate does not refuse it, the height
    # filter's outlier gate skips the height. Refused, the object got a second track (generator
    # occlusion scene: a bus behind a building's corner read 4.7 m for its last 20 frames).
    height_free_iou: float = 0.5
    # A weak box (``Detection.continues_only``) carries on a track whose prediction it overlaps
    # at least this much (ByteTrack's low-score round uses 0.5).
    weak_min_iou: float = 0.5
    # Tracks overlapping more than this are one object counted twice (ByteTrack uses 0.85).
    duplicate_iou: float = 0.8
    # A box overlapping a track's prediction at least this much is that track's object whatever its
    # colours (``[tracking] colour_gate``): a walker stepping into shade, a lamp's glow on a coat.
    colour_free_iou: float = 0.7
    # A track's colour signature is a running mean: each detection's weighs this much (DeepSORT-style
    # trackers keep 0.9 of the old): one frame's odd colours (a passer-by's arm in the box) fade.
    colour_update: float = 0.1
    # The stature window (gait correction) applies to these classes: a walker's head dips with every
    # step; a cyclist's and a vehicle's heights do not.
    walker_classes: tuple[str, ...] = ("person",)
    # A track not seen this frame whose predicted box has less than this share inside the image has
    # left the view: it is dropped instead of coasting on outside the frame.
    min_share_in_view: float = 0.25
    # Second-chance association on the predicted box: a buffer of this share of the box per frame
    # the track was missed, at most this share (C-BIoU uses 0.3 and 0.5 buffers), for boxes whose
    # heights differ by less than this factor (Oxford: a coasting track took half a walker 60 px off).
    recovery_buffer_per_miss: float = 0.05
    recovery_max_buffer: float = 0.5
    recovery_max_size_ratio: float = 1.5
    # A track not seen last frame, or left over for the second round, may take a box at most this
    # much taller or shorter than its own.
    coasting_max_size_ratio: float = 2.0
    # Tracks seen within this many frames may claim their share of a merged blob (their prediction
    # is still good).
    merge_max_misses: int = 1
    # A vehicle's heading: from its last this many ground points, once they span this far. A box
    # fitted to its outline must lie along it within this angle (a bicycle seen from the side fits an
    # end-on car's box lying across its way).
    heading_points: int = 10
    heading_min_travel_m: float = 1.0
    heading_max_angle_deg: float = 30.0
    # Classes measured by the vehicle geometry (a box fitted to the outline, channel "box") instead of
    # foot and top; their foot/top height only stands in when nothing else measures them.
    box_geometry_classes: tuple[str, ...] = ("vehicle",)


CONSTANTS = TrackerConstants()


@dataclass
class _TrackState:
    """Everything the tracker keeps about one object between frames."""

    track_id: int
    motion: MotionFilter
    height: HeightFilter | None
    stature: StatureWindow
    """Recent network heights of a walker (see ``StatureWindow``)."""
    hits: int = 1
    hit_streak: int = 1
    misses: int = 0
    age: int = 1
    confirmed: bool = False
    class_votes: Counter = field(default_factory=Counter)
    ground_xy_m: tuple[float, float] | None = None
    ground_path: deque = field(default_factory=lambda: deque(maxlen=CONSTANTS.heading_points))
    """The last few ground points of the object's foot, for its heading (see ``_box_agrees``)."""
    updated: bool = True
    last_observation: tuple[float, float, float, float] | None = None
    """Box of the last associated detection, in the current frame's coordinates."""
    snapshot: MotionSnapshot | None = None
    """Motion state right after the last observation (current frame's coordinates)."""
    last_region: Region | None = None
    """Where the object was in the previous frame, for matched-point votes."""
    height_geometry_trusted: bool = True
    """Whether the class at the last height update let the foot/top geometry in (see ``_update_height``)."""
    height_rejections: dict[str, list[tuple[float, float]]] = field(default_factory=dict)
    """Per channel: (height, noise) of the measurements the height gate rejected in a row."""
    colour: np.ndarray | None = None
    """Running mean of its detections' colour signatures (``CONSTANTS.colour_update``)."""
    camera_share: float = 0.0
    """The last detection's ``camera_share``: the camera's error on the height, added to its std."""

    @property
    def cls(self) -> str:
        return self.class_votes.most_common(1)[0][0] if self.class_votes else "other"

    def to_track(self) -> Track:
        has_height = self.height is not None
        return Track(
            track_id=self.track_id,
            box=self.motion.box,
            cls=self.cls,
            height_m=self.height.height_m if has_height else float("nan"),
            height_std_m=(float(np.hypot(self.height.std_m, self.camera_share * self.height.height_m))
                          if has_height else float("inf")),
            confirmed=self.confirmed,
            ground_xy_m=self.ground_xy_m,
            height_source=self.height.source if has_height else "none",
            hits=self.hits,
            age=self.age,
            updated=self.updated,
            detected_box=self.last_observation if self.updated else None,
        )


class ObjectTracker:
    """Tracker whose tracks also carry a Kalman-filtered object height.

    Parameters
    ----------
    config : TrackingConfig
        Gates, cost weights, track life (``min_hits``, ``max_misses``) and height settings.
    filters : FilterFactory, optional
        Builds each track's motion and height filters (default: filterpy-based).
    """

    def __init__(self, config: TrackingConfig, filters: FilterFactory | None = None):
        self.config = config
        self.filters = filters or FilterFactory(config)
        self.tracks: list[_TrackState] = []
        self._next_id = 1
        self.required_hits = config.min_hits
        self.allowed_misses = config.max_misses
        self.idle_weak: list[int] = []
        """Indices into the last ``update``'s detections of the weak boxes (``continues_only``)
        that carried on no track: no object this frame."""

    def update(self, detections: list[Detection], matches: FeatureMatches | None = None,
               frame_size: tuple[int, int] | None = None, frame_interval_s: float | None = None) -> list[Track]:
        """Advance every track by one frame and fold in this frame's detections.

        ``frame_size`` (width, height): tracks that coast out of the image are dropped.
        ``frame_interval_s``: source time between processed frames; turns ``confirm_s`` and
        ``max_miss_s`` into frame counts (without it: ``min_hits`` and ``max_misses``).
        """
        if frame_interval_s is not None and frame_interval_s > 0:
            self.required_hits = max(self.config.min_hits, round(self.config.confirm_s / frame_interval_s))
            self.allowed_misses = max(self.config.max_misses, round(self.config.max_miss_s / frame_interval_s))
        if matches is not None:
            self._compensate_camera_motion(np.asarray(matches.camera_motion, dtype=float))
        for track in self.tracks:
            track.motion.predict()
            if track.height is not None:
                track.height.predict()
            track.age += 1

        weak = [i for i, d in enumerate(detections) if d.continues_only]
        weak_detections = [detections[i] for i in weak]
        detections = [d for d in detections if not d.continues_only]
        claimants = [t for t in self.tracks if t.confirmed and t.misses <= CONSTANTS.merge_max_misses]
        boxes, classes = [t.motion.box for t in claimants], [t.cls for t in claimants]
        detections = split_by_predictions(detections, boxes, classes)
        detections = join_fragments(detections, boxes, classes)
        cost, allowed = self._association_cost(detections, matches)
        result = assign(cost, allowed)
        matched = list(result.matches)
        leftover_tracks, leftover_detections = self._recover(result.unmatched_tracks,
                                                             result.unmatched_detections, detections)
        matched += [(r, c) for r, c in zip(leftover_tracks[0], leftover_detections[0])]
        carried, missed = self._carry_on(leftover_tracks[1], weak_detections)
        used = {c for _, c in carried}
        self.idle_weak = [index for c, index in enumerate(weak) if c not in used]

        for row, col in matched:
            self._apply_detection(self.tracks[row], detections[col])
        for row, col in carried:
            self._apply_detection(self.tracks[row], weak_detections[col])
        for row in missed:
            self._miss(self.tracks[row])
        self.tracks = [t for t in self.tracks if self._alive(t) and not _left_the_view(t, frame_size)]
        for col in leftover_detections[1]:
            self._start_track(detections[col])
        self._remove_duplicates()
        return [_in_view(t.to_track(), frame_size) for t in self.tracks]

    def _remove_duplicates(self) -> None:
        """Two tracks on one object (a blob that split and merged again): the younger one goes.

        As ByteTrack does, tracks whose boxes overlap by more than ``CONSTANTS.duplicate_iou`` are one
        object; the one with fewer hits is the copy.
        """
        if len(self.tracks) < 2:
            return
        iou = iou_matrix([t.motion.box for t in self.tracks], [t.motion.box for t in self.tracks])
        np.fill_diagonal(iou, 0.0)
        drop = set()
        for a, b in zip(*np.nonzero(np.triu(iou) > CONSTANTS.duplicate_iou)):
            if a in drop or b in drop:
                continue
            drop.add(b if self.tracks[a].hits >= self.tracks[b].hits else a)
        self.tracks = [t for i, t in enumerate(self.tracks) if i not in drop]

    # -- association -----------------------------------------------------------------------

    def _compensate_camera_motion(self, camera_motion: np.ndarray) -> None:
        if np.allclose(camera_motion, np.eye(2, 3), atol=1e-4):
            return
        for track in self.tracks:
            track.motion.warp(camera_motion)
            if track.last_observation is not None:
                track.last_observation = _warp_box(track.last_observation, camera_motion)
            if track.snapshot is not None:
                saved = self.filters.create_motion_filter((0.0, 0.0, 1.0, 1.0))
                saved.restore(track.snapshot)
                saved.warp(camera_motion)
                track.snapshot = saved.snapshot()

    def _association_cost(self, detections: list[Detection],
                          matches: FeatureMatches | None) -> tuple[np.ndarray, np.ndarray]:
        """Cost and allowed-pair matrices, tracks x detections."""
        n_tracks, n_detections = len(self.tracks), len(detections)
        if n_tracks == 0 or n_detections == 0:
            return np.zeros((n_tracks, n_detections)), np.zeros((n_tracks, n_detections), bool)
        iou = iou_matrix([t.motion.box for t in self.tracks], [d.box for d in detections])
        votes = self._votes(detections, matches)
        gate = self.config.motion_gate_chi2
        boxes = [d.box for d in detections]
        distance = np.array([t.motion.mahalanobis_sq(boxes) for t in self.tracks])
        height_gap = self._height_gaps(detections)
        allowed = ((iou >= self.config.iou_gate) | (votes >= self.config.min_vote_share)) & (distance <= gate)
        allowed &= (height_gap <= 1.0) | (iou >= CONSTANTS.height_free_iou)
        # A coasting track's box grows uncertain in size too; an object seen again is not half or
        # twice as tall (Oxford: a walker cut by the top edge, coasting, took the legs of another).
        box_heights = np.array([b[3] for b in boxes], dtype=float)
        for row, track in enumerate(self.tracks):
            if track.misses > 0:
                allowed[row] &= _alike_in_size(track.motion.box[3], box_heights, CONSTANTS.coasting_max_size_ratio)
        # Colours in this round only: a track found again in the second round has been hidden, and
        # an object coming out from behind another is seen in part, its colours not its own
        # (gated in the later rounds too, on the dev set: HOTA 0.454 -> 0.446, ID switches 181 -> 308).
        colour = np.nan_to_num(signature_distances([t.colour for t in self.tracks], [d.colour for d in detections]),
                               nan=0.0)
        allowed &= (colour <= self.config.colour_gate) | (iou >= CONSTANTS.colour_free_iou)
        cost = ((1.0 - iou) + self.config.vote_weight * (1.0 - votes) + self.config.colour_weight * colour
                + CONSTANTS.motion_weight * np.minimum(distance / gate, 1.0)
                + CONSTANTS.height_weight * np.minimum(height_gap, 1.0)
                + CONSTANTS.direction_weight * self._direction_mismatch(range(n_tracks), boxes))
        return cost, allowed

    def _direction_mismatch(self, rows, boxes) -> np.ndarray:
        """``direction_mismatch`` of these tracks (from their last observation) to these boxes."""
        tracks = [self.tracks[r] for r in rows]
        return direction_mismatch(np.array([t.motion.velocity for t in tracks]).reshape(-1, 2),
                                  [t.last_observation or t.motion.box for t in tracks], boxes)

    def _votes(self, detections: list[Detection], matches: FeatureMatches | None) -> np.ndarray:
        """Share of each track's matched points from the last frame that land on each detection."""
        if matches is None or len(matches.prev_pts) == 0:
            return np.zeros((len(self.tracks), len(detections)))
        on_object = np.asarray(matches.on_object, dtype=bool)
        previous = [t.last_region or Region(t.motion.box) for t in self.tracks]
        current = [Region(d.box, d.mask) for d in detections]
        return feature_votes(matches.prev_pts[on_object], matches.curr_pts[on_object], previous, current)

    def _height_gaps(self, detections: list[Detection]) -> np.ndarray:
        """Height difference over the gate width (1 = at the gate); 0 where a height is unknown.

        Only settled tracks (enough height measurements) are compared: a fresh track's height
        is too uncertain to veto anything.
        """
        gaps = np.zeros((len(self.tracks), len(detections)))
        for row, track in enumerate(self.tracks):
            if track.height is None or sum(track.height.updates.values()) < CONSTANTS.height_gate_after:
                continue
            for col, detection in enumerate(detections):
                network = detection.heights.get(NETWORK)
                if network is not None and network.usable:
                    residual = track.height.normalized_residual(network.value_m, network.noise_m, NETWORK)
                    gaps[row, col] = (residual / self.config.height_gate_sigma) ** 2
        return gaps

    def _recover(self, track_rows: list[int], detection_cols: list[int],
                 detections: list[Detection]) -> tuple[tuple[list[int], list[int]], tuple[list[int], list[int]]]:
        """Second round on the last observed boxes. Returns ((matched rows, unmatched rows),
        (matched cols, unmatched cols)), matched lists aligned pair by pair."""
        candidates = [r for r in track_rows if self.tracks[r].last_observation is not None
                      and self.tracks[r].confirmed]
        if not candidates or not detection_cols:
            return ([], track_rows), ([], detection_cols)
        boxes = [detections[c].box for c in detection_cols]
        box_heights = np.array([b[3] for b in boxes], dtype=float)
        iou = iou_matrix([self.tracks[r].last_observation for r in candidates], boxes)
        same_size = np.array([_alike_in_size(self.tracks[r].motion.box[3], box_heights,
                                             CONSTANTS.coasting_max_size_ratio) for r in candidates])
        iou = np.where(same_size, iou, 0.0)
        # Or where the prediction went, with a buffer that grows while the object stays hidden
        # (C-BIoU): a walker's speed estimate is a few per cent off, and over a 2 s occlusion
        # that put the prediction most of a box width away from where the walker came out.
        # A buffer forgives position, not size: the box must stand about as tall as the track's.
        for i, r in enumerate(candidates):
            track = self.tracks[r]
            buffer = min(CONSTANTS.recovery_buffer_per_miss * track.misses, CONSTANTS.recovery_max_buffer)
            if buffer > 0:
                buffered = iou_matrix([_buffered(track.motion.box, buffer)], [_buffered(b, buffer) for b in boxes])[0]
                alike = _alike_in_size(track.motion.box[3], box_heights, CONSTANTS.recovery_max_size_ratio)
                iou[i] = np.maximum(iou[i], np.where(alike, buffered, 0.0))
        gaps = self._height_gaps([detections[c] for c in detection_cols])[candidates]
        allowed = (iou >= self.config.iou_gate) & (gaps <= 1.0)
        cost = (1.0 - iou + CONSTANTS.height_weight * np.minimum(gaps, 1.0)
                + CONSTANTS.direction_weight * self._direction_mismatch(candidates, boxes))
        result = assign(cost, allowed)
        rows = [candidates[r] for r, _ in result.matches]
        cols = [detection_cols[c] for _, c in result.matches]
        return ((rows, [r for r in track_rows if r not in rows]),
                (cols, [c for c in detection_cols if c not in cols]))

    def _carry_on(self, track_rows: list[int],
                  weak: list[Detection]) -> tuple[list[tuple[int, int]], list[int]]:
        """Third round (ByteTrack's low-score boxes): confirmed tracks still left over that were seen
        last frame take a weak box lying on their prediction (IoU >= ``CONSTANTS.weak_min_iou``,
        within the height gate); a track already coasting is not carried on by one (ByteTrack
        offers them to tracked tracks only; on the dev set, tracks missed up to 2 frames or any
        number gave the same HOTA with more false positives). Returns the (row, weak index)
        pairs and the rows still unmatched."""
        candidates = [r for r in track_rows if self.tracks[r].confirmed and self.tracks[r].misses == 0]
        if not candidates or not weak:
            return [], track_rows
        iou = iou_matrix([self.tracks[r].motion.box for r in candidates], [d.box for d in weak])
        gaps = self._height_gaps(weak)[candidates]
        allowed = (iou >= CONSTANTS.weak_min_iou) & (gaps <= 1.0)
        result = assign(1.0 - iou + CONSTANTS.height_weight * np.minimum(gaps, 1.0), allowed)
        pairs = [(candidates[r], c) for r, c in result.matches]
        taken = {r for r, _ in pairs}
        return pairs, [r for r in track_rows if r not in taken]

    # -- track life ------------------------------------------------------------------------

    def _alive(self, track: _TrackState) -> bool:
        if not track.confirmed:
            return track.misses == 0
        return track.misses <= self.allowed_misses

    def _miss(self, track: _TrackState) -> None:
        track.motion.hold_size()
        track.misses += 1
        track.hit_streak = 0
        track.updated = False
        track.last_region = Region(track.motion.box)

    def _apply_detection(self, track: _TrackState, detection: Detection) -> None:
        predicted_box = track.motion.box
        gap = track.misses + 1                     # frames since the last observation
        if gap > 1 and track.snapshot is not None and track.last_observation is not None:
            self._reupdate_along_virtual_path(track, detection.box, gap)
        else:
            track.motion.update(detection.box)
        track.snapshot = track.motion.snapshot()
        track.last_observation = detection.box
        track.last_region = Region(detection.box, detection.mask)
        track.hits += 1
        track.hit_streak += 1
        track.misses = 0
        track.updated = True
        track.class_votes[detection.cls] += 1
        if detection.colour is not None:
            track.colour = (detection.colour if track.colour is None else
                            (1.0 - CONSTANTS.colour_update) * track.colour + CONSTANTS.colour_update * detection.colour)
        if detection.ground_xy_m is not None:
            track.ground_xy_m = detection.ground_xy_m
            track.ground_path.append(detection.ground_xy_m)
        self._update_height(track, detection, _top_lost(predicted_box, detection.box))
        if track.hit_streak >= self.required_hits:
            track.confirmed = True

    def _reupdate_along_virtual_path(self, track: _TrackState, box, gap: int) -> None:
        """OC-SORT re-update: replay the hidden frames with observations on a straight line."""
        start = np.asarray(track.last_observation, dtype=float)
        end = np.asarray(box, dtype=float)
        track.motion.restore(track.snapshot)
        for step in range(1, gap):
            virtual = start + (end - start) * step / gap
            track.motion.predict()
            track.motion.update(tuple(virtual))
        track.motion.predict()
        track.motion.update(box)

    def _update_height(self, track: _TrackState, detection: Detection, top_lost: bool) -> None:
        """Fold this frame's height measurements into the track's filter, one after the other."""
        boxed = track.cls in CONSTANTS.box_geometry_classes
        if (boxed and track.height_geometry_trusted and track.height is not None
                and track.height.updates.get(GEOMETRY, 0) > 0):
            # Foot/top geometry went in while the track passed for a person or cyclist; as a vehicle
            # its foot/top height is the far roof edge's: start again from this frame's measurements.
            track.height = None
            track.height_rejections.clear()
        track.height_geometry_trusted = not boxed
        if detection.camera_share > 0:
            track.camera_share = detection.camera_share
        for channel, measurement in _channels_to_fuse(track, detection, boxed, self.config.ignore_channels):
            height, noise = measurement.value_m, measurement.noise_m
            if top_lost:
                noise *= CONSTANTS.top_lost_noise_factor
            if channel == NETWORK:
                if not boxed and detection.min_height_m is not None:
                    height = max(height, detection.min_height_m)   # the foot is cut: a bound
                # Only the network's heights go through the stature window: box points wobble ~20 px
                # (Oxford, against labels) under a stated 2 px, so a window's upper quantile picks the
                # boxes that overshoot, not the top of the gait (Oxford: mean 1.81 -> 1.80 m, median
                # error 4.5 -> 3.8 cm without).
                if self.config.stature_window > 0 and track.cls in CONSTANTS.walker_classes:
                    height = track.stature.add(height, noise)
            self._fuse(track, channel, height, noise, measurement.bias_m)

    def _fuse(self, track: _TrackState, channel: str, height: float, noise: float, bias_std: float | None) -> None:
        """One measurement into the track's height filter, behind the outlier gate."""
        if track.height is None:
            track.height = self.filters.create_height_filter(height, noise, channel, bias_std)
            return
        settled = sum(track.height.updates.values()) >= CONSTANTS.height_gate_after
        if settled and (track.height.normalized_residual(height, noise, channel)
                        > self.config.height_gate_sigma):
            rejected = track.height_rejections.setdefault(channel, [])
            rejected.append((height, noise))
            if self._outweighs(rejected, track.height, channel):
                track.height = self._height_from(rejected, channel)
                track.height_rejections.clear()
            return
        track.height_rejections.pop(channel, None)
        track.height.update(height, noise, channel, bias_std)

    def _outweighs(self, rejected: list[tuple[float, float]], height: HeightFilter, channel: str) -> bool:
        """A run of rejections that says more than the state: the state was built on outliers.

        Counted per channel (a network accepted every frame must not hide a geometry channel
        rejected every frame: a walker born as a 3 m "vehicle" blob), and weighed by information
        (sum of 1/noise^2 against 1/variance of what the state expects this channel to read; the
        channel's own bias is common to both, so it does not count): eight frames of a box
        overshooting do not undo forty frames of a settled height, nor does a noisy network undo
        a geometry-made one.
        """
        information = sum(1.0 / noise ** 2 for _, noise in rejected)
        return (len(rejected) >= CONSTANTS.height_restart_after
                and information > 1.0 / height.expected_std_m(channel) ** 2)

    def _height_from(self, measurements: list[tuple[float, float]], channel: str) -> HeightFilter:
        """A fresh height filter made of these measurements of one channel."""
        (first, first_noise), rest = measurements[0], measurements[1:]
        height = self.filters.create_height_filter(first, first_noise, channel)
        for value, noise in rest:
            height.update(value, noise, channel)
        return height

    def _start_track(self, detection: Detection) -> None:
        track = _TrackState(
            track_id=self._next_id,
            motion=self.filters.create_motion_filter(detection.box),
            height=None,
            stature=StatureWindow(self.config.stature_window, self.config.stature_quantile),
            class_votes=Counter({detection.cls: 1}),
            ground_xy_m=detection.ground_xy_m,
            last_observation=detection.box,
            last_region=Region(detection.box, detection.mask),
            colour=detection.colour,
        )
        track.snapshot = track.motion.snapshot()
        self._update_height(track, detection, top_lost=False)
        track.confirmed = self.required_hits <= 1
        self._next_id += 1
        self.tracks.append(track)


def _channels_to_fuse(track: _TrackState, detection: Detection, boxed: bool,
                      ignored: list[str] = ()) -> list[tuple[str, Measurement]]:
    """The detection's usable height measurements that measure this track, in the order they are
    fused (``ignored``: channels the configuration leaves out).

    The network's first. Then, for a vehicle track, the box fitted to its outline where the box
    lies along the way the track drives; for any other track the foot/top geometry, which stands in
    for a vehicle only when nothing else measures it (its foot/top height is the far roof edge's:
    ~0.8 m high on generator data). Then every other channel a stage added, as it is.
    """
    usable = {channel: m for channel, m in detection.heights.items() if m.usable and channel not in ignored}
    chosen = [(NETWORK, usable[NETWORK])] if NETWORK in usable else []
    if boxed and BOX in usable and _box_agrees(track, detection):
        chosen.append((BOX, usable[BOX]))
    elif (not boxed or not chosen) and GEOMETRY in usable:
        chosen.append((GEOMETRY, usable[GEOMETRY]))
    return chosen + [(channel, m) for channel, m in usable.items() if channel not in (NETWORK, GEOMETRY, BOX)]


def _in_view(track: Track, frame_size: tuple[int, int] | None) -> Track:
    """The track with its box cut to the image: what it reports is the part of the object in view.

    The filter keeps the whole box (an object leaving keeps its size and speed, and one coming
    back in is met where it is expected); a box reported past the image edge (a car driving out
    at the right, 114 px over on the traffic clip) is no place in the picture. One cut at the
    bottom says so (``Track.foot_in_view``): its bottom is the frame's edge, not the object's foot.
    """
    if frame_size is None:
        return track
    visible = _part_in_view(track.box, frame_size)
    if visible == tuple(track.box):
        return track
    foot_in_view = track.box[1] + track.box[3] <= frame_size[1]
    return dataclasses.replace(track, box=visible, foot_in_view=foot_in_view)


def _left_the_view(track: _TrackState, frame_size: tuple[int, int] | None) -> bool:
    """Not seen this frame, and its predicted box lies mostly outside the image."""
    if track.updated or frame_size is None:
        return False
    _x, _y, w, h = track.motion.box
    if w <= 0 or h <= 0:
        return True
    _x, _y, inside_w, inside_h = _part_in_view(track.motion.box, frame_size)
    return inside_w * inside_h / (w * h) < CONSTANTS.min_share_in_view


def _part_in_view(box, frame_size: tuple[int, int]) -> tuple[float, float, float, float]:
    """The part of a box (x, y, w, h) inside the image (0 wide or high where none is)."""
    x, y, w, h = box
    x0, y0 = min(max(x, 0.0), frame_size[0]), min(max(y, 0.0), frame_size[1])
    x1, y1 = max(min(x + w, frame_size[0]), x0), max(min(y + h, frame_size[1]), y0)
    return x0, y0, x1 - x0, y1 - y0


def _box_agrees(track: _TrackState, detection: Detection) -> bool:
    """Whether the box fitted to the outline lies along the way the track moves.

    A box whose length was seen stands unless the heading says otherwise; one whose length was
    assumed (only an end seen) needs the heading to confirm it.
    """
    axis = detection.vehicle_axis_xy
    if axis is None or len(track.ground_path) < 2:
        return not detection.vehicle_length_assumed
    travel = np.subtract(track.ground_path[-1], track.ground_path[0])
    distance = float(np.hypot(*travel))
    if distance < CONSTANTS.heading_min_travel_m:
        return not detection.vehicle_length_assumed
    return abs(float(np.dot(travel, axis))) / distance >= np.cos(np.deg2rad(CONSTANTS.heading_max_angle_deg))


def _top_lost(predicted_box, box) -> bool:
    """The detection's top edge is well below the predicted one: its top is hidden or cut."""
    return box[1] - predicted_box[1] > CONSTANTS.top_lost_share * predicted_box[3]


def _alike_in_size(height_px: float, heights_px: np.ndarray, max_ratio: float) -> np.ndarray:
    """Where a box stands within ``max_ratio`` of ``height_px`` tall (either way): a bool mask."""
    ratio = heights_px / max(height_px, 1e-9)
    return (ratio >= 1 / max_ratio) & (ratio <= max_ratio)


def _buffered(box, scale: float) -> tuple[float, float, float, float]:
    """The box grown by ``scale`` times its width and height on every side."""
    x, y, w, h = box
    return (x - scale * w, y - scale * h, w * (1 + 2 * scale), h * (1 + 2 * scale))


def _warp_box(box, affine: np.ndarray):
    x, y, w, h = box
    linear, shift = affine[:, :2], affine[:, 2]
    centre = linear @ np.array([x + w / 2.0, y + h / 2.0]) + shift
    scale = float(np.sqrt(abs(np.linalg.det(linear))))
    w, h = w * scale, h * scale
    return (float(centre[0] - w / 2.0), float(centre[1] - h / 2.0), float(w), float(h))


class TrackingStage:
    """Pipeline stage: ``packet.detections`` (+ ``packet.matches``) -> ``packet.tracks``."""

    def __init__(self, config: TrackingConfig):
        self.tracker = ObjectTracker(config)
        self._last_time_s: float | None = None
        self._intervals: deque[float] = deque(maxlen=25)

    def process(self, packet: FramePacket) -> FramePacket:
        height, width = packet.frame.image.shape[:2]
        detections = packet.detections
        if self.tracker.config.colour_gate < 1.0 or self.tracker.config.colour_weight > 0.0:
            for detection in detections:
                detection.colour = None if not _one_object(detection, packet) else colour_signature(
                    packet.frame.image, detection.box, detection.mask)
        if packet.frame.damage or packet.network_reused:
            detections = [without_heights(detection) for detection in detections]
        packet.tracks = self.tracker.update(detections, packet.matches, frame_size=(width, height),
                                            frame_interval_s=self._frame_interval(packet.frame.time_s))
        if self.tracker.idle_weak:
            idle = set(self.tracker.idle_weak)
            packet.detections = [d for i, d in enumerate(packet.detections) if i not in idle]
        return packet

    def close(self) -> None:
        """Nothing to release (the Stage contract, core/stage.py)."""

    def _frame_interval(self, time_s: float) -> float | None:
        """Median source time between the recent processed frames (stride included; None at first)."""
        if self._last_time_s is not None and time_s > self._last_time_s:
            self._intervals.append(time_s - self._last_time_s)
        self._last_time_s = time_s
        return float(np.median(self._intervals)) if self._intervals else None


def _one_object(detection: Detection, packet: FramePacket) -> bool:
    """Whether the detection's colours are one object's, to compare with its track's.

    Not a blob's (``Detection.blob``): its box holds whatever moved together this frame, two
    walkers merged or half of one, and with blobs the cue cost held-out HOTA (trk_val20 0.392 ->
    0.389, trk_test40 0.407 -> 0.405, more objects missed; docs/results.md, 2026-12-06). Not on a
    damaged frame: concealed pixels are no object's colours."""
    return detection.blob is None and not packet.frame.damage


def without_heights(detection: Detection) -> Detection:
    """The detection with its height measurements withheld (every channel, and the lower bound): on
    a frame decoded with errors, or one given the previous frame's network outputs, the boxes still
    carry the tracks along, but no height measured on concealed pixels or a stale map is fused."""
    return dataclasses.replace(detection, heights={}, min_height_m=None)
