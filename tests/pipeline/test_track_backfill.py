"""A confirmed track's tentative frames are reported once it is confirmed; nothing else changes."""

import numpy as np
import pytest

from core.packets import CameraInfo, Frame, FramePacket, Track
from pipeline.track_backfill import TrackBackfill, backfilled

CAMERA = CameraInfo(width=64, height=48)


def packet(index: int, tracks: dict[int, bool]) -> FramePacket:
    """Frame ``index`` with tracks {id: confirmed}."""
    frame = Frame(index, index / 25, np.zeros((48, 64, 3), np.uint8))
    return FramePacket(frame=frame, camera=CAMERA, tracks=[
        Track(track_id, (0.0, 0.0, 4.0, 8.0), "person", 1.7, 0.1, confirmed=confirmed)
        for track_id, confirmed in tracks.items()])


def confirmed_ids(packets):
    return [sorted(t.track_id for t in p.tracks if t.confirmed) for p in packets]


@pytest.mark.parametrize("frames, expected", [
    # track 1 tentative for two frames, confirmed on the third: all three report it
    ([{1: False}, {1: False}, {1: True}, {1: True}], [[1], [1], [1], [1]]),
    # track 2 lost while tentative: its frames stay unconfirmed
    ([{2: False}, {2: False}, {}, {}], [[], [], [], []]),
    # a confirmed track beside one that starts and is confirmed later
    ([{1: True}, {1: True, 3: False}, {1: True, 3: True}], [[1], [1, 3], [1, 3]]),
    # a track tentative until the run ends (drained as it was)
    ([{1: True}, {1: True, 4: False}, {1: True, 4: False}], [[1], [1], [1]]),
])
def test_tentative_frames_of_confirmed_tracks_are_confirmed(frames, expected):
    packets = [packet(i, tracks) for i, tracks in enumerate(frames)]
    out = list(backfilled(packets))
    assert [p.frame.index for p in out] == list(range(len(frames)))
    assert confirmed_ids(out) == expected


def test_backfill_off_passes_packets_unchanged():
    packets = [packet(0, {1: False}), packet(1, {1: True})]
    assert confirmed_ids(backfilled(packets, enabled=False)) == [[], [1]]


def test_a_frame_waits_only_while_its_tentative_tracks_are_undecided():
    backfill = TrackBackfill()
    assert [p.frame.index for p in backfill.push(packet(0, {1: True}))] == [0]     # nothing tentative
    assert backfill.push(packet(1, {1: True, 2: False})) == []                       # 2 undecided
    assert backfill.push(packet(2, {1: True, 2: False})) == []
    ready = backfill.push(packet(3, {1: True}))                                      # 2 lost
    assert [p.frame.index for p in ready] == [1, 2, 3]
    assert confirmed_ids(ready) == [[1], [1], [1]]
    assert backfill.drain() == []


def test_held_frames_are_bounded():
    backfill = TrackBackfill(max_held=3)
    released = [p.frame.index for i in range(6) for p in backfill.push(packet(i, {7: False}))]
    assert released == [0, 1, 2]
    assert [p.frame.index for p in backfill.drain()] == [3, 4, 5]


def test_items_carrying_packets_are_delayed_together():
    pairs = [("truth 0", packet(0, {1: False})), ("truth 1", packet(1, {1: True}))]
    out = list(backfilled(pairs, packet_of=lambda pair: pair[1]))
    assert [truth for truth, _ in out] == ["truth 0", "truth 1"]
    assert confirmed_ids(p for _, p in out) == [[1], [1]]
