"""What later frames tell about earlier ones: a track's tentative frames, reported once it is
confirmed; its short gaps, filled once it is found again; its boxes, smoothed with the frames
after them.

The tracker reports a track only after ``min_hits`` / ``confirm_s`` detections in a row (at 25
frames/s, five): a single false blob must not become an object. Every person therefore went
missing from the outputs for the first four frames of his track, although those frames held
his detections (Oxford Town Centre, 2026-12-05: the first 4 frames of every labelled person
were uncovered). ``TrackBackfill`` holds a packet back while one of its tentative tracks may
still be confirmed, and marks that track confirmed in every held packet when it is. A tentative
track ends at its first miss, so nothing is held longer than the confirmation takes (a frame
with no tentative track passes at once); ``max_held`` bounds memory if a tracker ever keeps one
longer. Outputs then lag a live source by at most the confirmation time (0.2 s by default).
What is filled in is what the tracker said in those frames (its box, class and height estimate
at the time), marked confirmed.

The same holding fills a confirmed track's short gaps (``fill_gaps_s``): a frame in which the
track coasts (no detection; its box is the filter's prediction) waits while the track may still
be found again within ``fill_gaps_s`` of its last detection. If it is, the coasting frames'
boxes are interpolated between the two detections' boxes, in time, and marked ``filled``: both ends
were seen, and the prediction from one end only lags a walker who turned or slowed (dev2: 599
of 1,061 interpolated boxes on a truth object at IoU >= 0.5, 495 of the predicted ones). Heights
stay the tracker's. A track that is not found again in time keeps its predicted boxes, and the
frames go out.

And it smooths (``smooth_s``): the tracker's box in a frame with a detection is its motion
filter's, which has seen only the frames before; a frame waits ``smooth_s`` for the frames after
it, and its box becomes the value at its time of a straight line fitted to the track's boxes
within ``smooth_s`` either side (at least three). The line goes through the detections' boxes
(``Track.detected_box``), as measured: not the filter's, which lag what the frames on both
sides say (dev2 HOTA 0.486 -> 0.488, trk_test40 0.545 -> 0.548), and never smoothed ones. Box
jitter from frame to frame is what it takes out, not a box's steady offset.
"""

from __future__ import annotations

from collections import deque
from typing import Callable, Generic, Iterable, Iterator, TypeVar

import numpy as np

from core.packets import FramePacket, Track

Item = TypeVar("Item")

TIME_EPSILON_S = 1e-6
"""Frame times are float seconds: a gap of exactly ``fill_gaps_s`` is filled."""


class TrackBackfill(Generic[Item]):
    """Delays items (packets, or anything that carries one) until their tentative tracks are settled,
    their coasting tracks' gaps can no longer be filled and the frames their boxes are smoothed
    with have come.

    ``push`` returns the items that can go out now, oldest first; ``drain`` returns the rest
    at the end of a run (or when it is stopped: their tentative tracks stay unconfirmed, their
    coasting boxes predicted, their boxes smoothed with the frames there are). Not ``enabled``
    (``tracking.backfill = false``), no ``fill_gaps_s`` and no ``smooth_s``, every item goes out
    as it comes.
    """

    def __init__(self, packet_of: Callable[[Item], FramePacket] = lambda item: item, max_held: int = 50,
                 enabled: bool = True, fill_gaps_s: float = 0.0, smooth_s: float = 0.0):
        self.packet_of = packet_of
        self.max_held = max(1, max_held)
        self.enabled = enabled
        self.fill_gaps_s = max(0.0, fill_gaps_s)
        self.smooth_s = max(0.0, smooth_s)
        self._held: deque[Item] = deque()
        self._detections: dict[int, deque[tuple[float, tuple[float, float, float, float]]]] = {}
        """Each track's detected boxes (``Track.detected_box``), (frame time, box):
        its last one (where a gap starts) and those a held frame may still be smoothed with."""

    def push(self, item: Item) -> list[Item]:
        if not self.enabled and not self.fill_gaps_s and not self.smooth_s:
            return [item]
        newest = self.packet_of(item)
        self._held.append(item)
        if self.enabled:
            self._confirm(newest)
        if self.fill_gaps_s or self.smooth_s:
            self._record_detections(newest)
        undecided = self._undecided(newest)
        now = newest.frame.time_s
        ready = []
        while self._held and (len(self._held) > self.max_held
                              or not (_waits_on(self.packet_of(self._held[0]), undecided)
                                      or self._waits_for_later_boxes(self.packet_of(self._held[0]), now))):
            ready.append(self._release(self._held.popleft()))
        return ready

    def drain(self) -> list[Item]:
        ready = [self._release(item) for item in self._held]
        self._held.clear()
        return ready

    def _confirm(self, newest: FramePacket) -> None:
        """Marks confirmed, in every held packet, the tracks the newest packet confirms."""
        confirmed = {t.track_id for t in newest.tracks if t.confirmed}
        for held in self._held:
            for track in self.packet_of(held).tracks:
                if not track.confirmed and track.track_id in confirmed:
                    track.confirmed = True

    def _record_detections(self, newest: FramePacket) -> None:
        """Adds the newest packet's detected boxes, first interpolating the held coasting boxes of
        each track it finds again within ``fill_gaps_s``; forgets the boxes no frame needs."""
        now = newest.frame.time_s
        for track in newest.tracks:
            if not track.updated:
                continue
            boxes = self._detections.setdefault(track.track_id, deque())
            # The detection's box, not the filter's: the filter has seen only the frames before,
            # and lags what the line through the frames on both sides finds.
            box = track.detected_box or track.box
            if self.fill_gaps_s and boxes and now - boxes[-1][0] <= self.fill_gaps_s + TIME_EPSILON_S:
                self._interpolate(track.track_id, boxes[-1], (now, box))
            boxes.append((now, box))
        alive = {t.track_id for t in newest.tracks}
        oldest = self.packet_of(self._held[0]).frame.time_s - self.smooth_s - TIME_EPSILON_S
        for track_id in list(self._detections):
            boxes = self._detections[track_id]
            while len(boxes) > 1 and boxes[0][0] < oldest:
                boxes.popleft()
            if track_id not in alive and boxes[-1][0] < oldest:
                del self._detections[track_id]

    def _interpolate(self, track_id: int, start: tuple[float, tuple], end: tuple[float, tuple]) -> None:
        (t0, box0), (t1, box1) = start, end
        for held in self._held:
            packet = self.packet_of(held)
            if not t0 < packet.frame.time_s < t1:
                continue
            share = (packet.frame.time_s - t0) / (t1 - t0)
            for track in packet.tracks:
                if track.track_id == track_id and not track.updated:
                    track.box = tuple(float(a + share * (b - a)) for a, b in zip(box0, box1))
                    track.filled = True

    def _undecided(self, newest: FramePacket) -> set[int]:
        """The tracks whose held frames may still change: tentative ones still tentative, and
        coasting ones still coasting within ``fill_gaps_s`` of their last detection."""
        now = newest.frame.time_s
        return ({t.track_id for t in newest.tracks if self.enabled and not t.confirmed}
                | {t.track_id for t in newest.tracks if self.fill_gaps_s and _coasting(t)
                   and t.track_id in self._detections
                   and now - self._detections[t.track_id][-1][0] < self.fill_gaps_s - TIME_EPSILON_S})

    def _waits_for_later_boxes(self, packet: FramePacket, now: float) -> bool:
        """Whether a frame with a detected box waits for frames ``smooth_s`` after it."""
        return bool(self.smooth_s) and now < packet.frame.time_s + self.smooth_s - TIME_EPSILON_S \
            and any(t.updated for t in packet.tracks)

    def _release(self, item: Item) -> Item:
        if self.smooth_s:
            self._smooth(self.packet_of(item))
        return item

    def _smooth(self, packet: FramePacket) -> None:
        """Each detected box becomes the value at its frame's time of a straight line fitted to
        the track's boxes within ``smooth_s`` either side (at least three of them)."""
        time_s = packet.frame.time_s
        for track in packet.tracks:
            if not track.updated:
                continue
            near = [(t, box) for t, box in self._detections.get(track.track_id, ())
                    if abs(t - time_s) <= self.smooth_s + TIME_EPSILON_S]
            if len(near) < 3:
                continue
            # The least-squares line's value at dt = 0, in closed form (np.linalg.lstsq took twice as long).
            dt = np.array([t - time_s for t, _ in near])
            boxes = np.array([box for _, box in near])
            n, s_t, s_tt = len(near), dt.sum(), dt @ dt
            at_zero = (s_tt * boxes.sum(axis=0) - s_t * (dt @ boxes)) / (n * s_tt - s_t * s_t)
            track.box = tuple(float(v) for v in at_zero)


def _waits_on(packet: FramePacket, undecided: set[int]) -> bool:
    """Whether one of this packet's tracks is one whose frames may still change: tentative, or
    coasting, in this packet too."""
    return any(t.track_id in undecided and (not t.confirmed or _coasting(t)) for t in packet.tracks)


def _coasting(track: Track) -> bool:
    return track.confirmed and not track.updated and not track.filled


def backfilled(items: Iterable[Item], packet_of: Callable[[Item], FramePacket] = lambda item: item,
               enabled: bool = True, fill_gaps_s: float = 0.0, smooth_s: float = 0.0) -> Iterator[Item]:
    """``items`` in order, each once its tracks are settled (all of them at the end)."""
    backfill = TrackBackfill(packet_of, enabled=enabled, fill_gaps_s=fill_gaps_s, smooth_s=smooth_s)
    for item in items:
        yield from backfill.push(item)
    yield from backfill.drain()
