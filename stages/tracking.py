"""Multi-object tracking with a per-track height state.

``ObjectTracker`` is a plain class (no packets, no I/O): ``update(detections, matches)`` once
per frame returns every live track. ``TrackingStage`` wraps it for the pipeline.

Per frame: warp predictions by the camera shake, predict, associate (Hungarian on IoU with a
gate), update matched tracks (box and height filters), age the others, start tentative tracks
from leftover detections. A track is confirmed after ``min_hits`` hits in a row and dropped
after ``max_misses`` frames without one; a tentative track is dropped at its first miss.
"""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from pipeline.config import TrackingConfig
from pipeline.packets import Detection, FeatureMatches, FramePacket, Track
from stages.association import assign, iou_matrix
from stages.kalman import FilterFactory, HeightFilter, MotionFilter


@dataclass
class _TrackState:
    """Everything the tracker keeps about one object between frames."""

    track_id: int
    motion: MotionFilter
    height: HeightFilter | None
    hits: int = 1
    hit_streak: int = 1
    misses: int = 0
    age: int = 1
    confirmed: bool = False
    class_votes: Counter = field(default_factory=Counter)
    ground_xy_m: tuple[float, float] | None = None
    updated: bool = True

    @property
    def cls(self) -> str:
        return self.class_votes.most_common(1)[0][0] if self.class_votes else "other"

    def to_track(self) -> Track:
        height_m = self.height.height_m if self.height is not None else float("nan")
        height_std_m = self.height.std_m if self.height is not None else float("inf")
        return Track(
            track_id=self.track_id,
            box=self.motion.box,
            cls=self.cls,
            height_m=height_m,
            height_std_m=height_std_m,
            confirmed=self.confirmed,
            ground_xy_m=self.ground_xy_m,
            height_source="network",
            hits=self.hits,
            age=self.age,
            updated=self.updated,
        )


class ObjectTracker:
    """SORT-like tracker whose tracks also carry a Kalman-filtered object height.

    Parameters
    ----------
    config : TrackingConfig
        ``min_hits``, ``max_misses``, ``iou_gate`` and the height noise settings.
    filters : FilterFactory, optional
        Builds each track's motion and height filters (default: filterpy-based).
    """

    def __init__(self, config: TrackingConfig, filters: FilterFactory | None = None):
        self.config = config
        self.filters = filters or FilterFactory(config)
        self.tracks: list[_TrackState] = []
        self._next_id = 1

    def update(self, detections: list[Detection], matches: FeatureMatches | None = None) -> list[Track]:
        """Advance every track by one frame and fold in this frame's detections."""
        if matches is not None:
            camera_motion = np.asarray(matches.camera_motion, dtype=float)
            if not np.allclose(camera_motion, np.eye(2, 3)):
                for track in self.tracks:
                    track.motion.warp(camera_motion)
        for track in self.tracks:
            track.motion.predict()
            if track.height is not None:
                track.height.predict()
            track.age += 1

        predicted = [t.motion.box for t in self.tracks]
        iou = iou_matrix(predicted, [d.box for d in detections])
        result = assign(1.0 - iou, iou >= self.config.iou_gate)

        for row, col in result.matches:
            self._apply_detection(self.tracks[row], detections[col])
        for row in result.unmatched_tracks:
            track = self.tracks[row]
            track.misses += 1
            track.hit_streak = 0
            track.updated = False
        self.tracks = [t for t in self.tracks if self._alive(t)]
        for col in result.unmatched_detections:
            self._start_track(detections[col])
        return [t.to_track() for t in self.tracks]

    def _alive(self, track: _TrackState) -> bool:
        if not track.confirmed:
            return track.misses == 0
        return track.misses <= self.config.max_misses

    def _apply_detection(self, track: _TrackState, detection: Detection) -> None:
        track.motion.update(detection.box)
        self._update_height(track, detection)
        track.hits += 1
        track.hit_streak += 1
        track.misses = 0
        track.updated = True
        track.class_votes[detection.cls] += 1
        if detection.ground_xy_m is not None:
            track.ground_xy_m = detection.ground_xy_m
        if track.hit_streak >= self.config.min_hits:
            track.confirmed = True

    def _update_height(self, track: _TrackState, detection: Detection) -> None:
        if not _usable(detection.height_m, detection.height_noise_m):
            return
        if track.height is None:
            track.height = self.filters.create_height_filter(detection.height_m, detection.height_noise_m)
        else:
            track.height.update(detection.height_m, detection.height_noise_m)

    def _start_track(self, detection: Detection) -> None:
        height = None
        if _usable(detection.height_m, detection.height_noise_m):
            height = self.filters.create_height_filter(detection.height_m, detection.height_noise_m)
        track = _TrackState(
            track_id=self._next_id,
            motion=self.filters.create_motion_filter(detection.box),
            height=height,
            class_votes=Counter({detection.cls: 1}),
            ground_xy_m=detection.ground_xy_m,
        )
        track.confirmed = self.config.min_hits <= 1
        self._next_id += 1
        self.tracks.append(track)


def _usable(height_m: float | None, noise_m: float | None) -> bool:
    return (height_m is not None and noise_m is not None
            and np.isfinite(height_m) and np.isfinite(noise_m) and noise_m > 0)


class TrackingStage:
    """Pipeline stage: ``packet.detections`` (+ ``packet.matches``) -> ``packet.tracks``."""

    def __init__(self, config: TrackingConfig):
        self.tracker = ObjectTracker(config)

    def process(self, packet: FramePacket) -> FramePacket:
        start = time.perf_counter()
        packet.tracks = self.tracker.update(packet.detections, packet.matches)
        packet.timings_ms["tracking"] = (time.perf_counter() - start) * 1000
        return packet
