"""A confirmed track's tentative frames, reported once it is confirmed.

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
at the time), marked confirmed: no box or height is invented.
"""

from __future__ import annotations

from collections import deque
from typing import Callable, Generic, Iterable, Iterator, TypeVar

from core.packets import FramePacket

Item = TypeVar("Item")


class TrackBackfill(Generic[Item]):
    """Delays items (packets, or anything that carries one) until their tentative tracks are settled.

    ``push`` returns the items that can go out now, oldest first; ``drain`` returns the rest
    at the end of a run (or when it is stopped: their tentative tracks stay unconfirmed).
    Not ``enabled`` (``tracking.backfill = false``), every item goes out as it comes.
    """

    def __init__(self, packet_of: Callable[[Item], FramePacket] = lambda item: item, max_held: int = 50,
                 enabled: bool = True):
        self.packet_of = packet_of
        self.max_held = max(1, max_held)
        self.enabled = enabled
        self._held: deque[Item] = deque()

    def push(self, item: Item) -> list[Item]:
        if not self.enabled:
            return [item]
        newest = self.packet_of(item)
        self._held.append(item)
        confirmed = {t.track_id for t in newest.tracks if t.confirmed}
        tentative = {t.track_id for t in newest.tracks if not t.confirmed}
        for held in self._held:
            for track in self.packet_of(held).tracks:
                if not track.confirmed and track.track_id in confirmed:
                    track.confirmed = True
        ready = []
        while self._held and (len(self._held) > self.max_held
                              or not _waits_on(self.packet_of(self._held[0]), tentative)):
            ready.append(self._held.popleft())
        return ready

    def drain(self) -> list[Item]:
        ready = list(self._held)
        self._held.clear()
        return ready


def _waits_on(packet: FramePacket, tentative: set[int]) -> bool:
    """Whether one of this packet's tentative tracks is still tentative (and alive) now."""
    return any(not t.confirmed and t.track_id in tentative for t in packet.tracks)


def backfilled(items: Iterable[Item], packet_of: Callable[[Item], FramePacket] = lambda item: item,
               enabled: bool = True) -> Iterator[Item]:
    """``items`` in order, each once its tentative tracks are settled (all of them at the end)."""
    backfill = TrackBackfill(packet_of, enabled=enabled)
    for item in items:
        yield from backfill.push(item)
    yield from backfill.drain()
