"""A confirmed track's tentative frames are reported once it is confirmed; its short gaps are
filled once it is found again; nothing else changes."""

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


def seen(index: int, boxes: dict[int, tuple[float, float, float, float] | None], fps: float = 10.0) -> FramePacket:
    """Frame ``index`` with confirmed tracks {id: box}, None where the track coasts (a predicted box)."""
    frame = Frame(index, index / fps, np.zeros((48, 64, 3), np.uint8))
    return FramePacket(frame=frame, camera=CAMERA, tracks=[
        Track(track_id, box if box is not None else (99.0, 99.0, 1.0, 1.0), "person", 1.7, 0.1,
              confirmed=True, updated=box is not None)
        for track_id, box in boxes.items()])


def boxes_of(packets, track_id=1):
    return [next(((t.box, t.filled) for t in p.tracks if t.track_id == track_id), None) for p in packets]


def test_a_gap_closed_in_time_gets_boxes_interpolated_between_its_detections():
    frames = [{1: (0.0, 0.0, 4.0, 8.0)}, {1: None}, {1: None}, {1: None}, {1: (8.0, 4.0, 8.0, 8.0)}]
    out = list(backfilled([seen(i, f) for i, f in enumerate(frames)], fill_gaps_s=0.6))
    got = boxes_of(out)
    assert [filled for _, filled in got] == [False, True, True, True, False]
    np.testing.assert_allclose([box for box, _ in got], [(0.0, 0.0, 4.0, 8.0), (2.0, 1.0, 5.0, 8.0),
                                                         (4.0, 2.0, 6.0, 8.0), (6.0, 3.0, 7.0, 8.0),
                                                         (8.0, 4.0, 8.0, 8.0)])
    assert all(not t.updated for p in out[1:4] for t in p.tracks)        # still no detection there


@pytest.mark.parametrize("frames, fill_gaps_s", [
    # found again 0.7 s after its last detection: longer than the gaps filled
    ([{1: (0.0, 0.0, 4.0, 8.0)}] + [{1: None}] * 6 + [{1: (8.0, 4.0, 8.0, 8.0)}], 0.6),
    # never found again (dropped): the predictions stay
    ([{1: (0.0, 0.0, 4.0, 8.0)}, {1: None}, {1: None}, {}], 0.6),
    # gap filling off
    ([{1: (0.0, 0.0, 4.0, 8.0)}, {1: None}, {1: (8.0, 4.0, 8.0, 8.0)}], 0.0),
])
def test_coasting_boxes_stay_predicted_unless_the_track_is_found_again_in_time(frames, fill_gaps_s):
    out = list(backfilled([seen(i, f) for i, f in enumerate(frames)], fill_gaps_s=fill_gaps_s))
    coasting = [b for b in boxes_of(out) if b is not None and b[0] == (99.0, 99.0, 1.0, 1.0)]
    assert coasting and all(not filled for _, filled in coasting)
    assert sum(len(f) > 0 and None in f.values() for f in frames) == len(coasting)


def test_a_coasting_frame_waits_only_while_its_gap_may_still_close():
    backfill = TrackBackfill(enabled=False, fill_gaps_s=0.25)
    assert [p.frame.index for p in backfill.push(seen(0, {1: (0.0, 0.0, 4.0, 8.0)}))] == [0]
    assert backfill.push(seen(1, {1: None})) == []                        # 0.1 s since the detection
    assert backfill.push(seen(2, {1: None, 2: (9.0, 9.0, 2.0, 4.0)})) == []   # 0.2 s: a frame may still close it
    ready = backfill.push(seen(3, {1: None, 2: (9.0, 9.0, 2.0, 4.0)}))   # 0.3 s: too late
    assert [p.frame.index for p in ready] == [1, 2, 3]
    assert backfill.drain() == []


def test_gaps_are_filled_per_track_and_across_frame_rates():
    frames = [{1: (0.0, 0.0, 4.0, 8.0), 2: (10.0, 0.0, 4.0, 8.0)},
              {1: None, 2: (12.0, 0.0, 4.0, 8.0)},
              {1: (4.0, 0.0, 4.0, 8.0), 2: None},
              {1: (6.0, 0.0, 4.0, 8.0), 2: (18.0, 0.0, 4.0, 8.0)}]
    out = list(backfilled([seen(i, f, fps=25.0) for i, f in enumerate(frames)], fill_gaps_s=0.1))
    (box_1, filled_1), (box_2, filled_2) = boxes_of(out, 1)[1], boxes_of(out, 2)[2]
    assert filled_1 and filled_2
    np.testing.assert_allclose([box_1, box_2], [(2.0, 0.0, 4.0, 8.0), (15.0, 0.0, 4.0, 8.0)])


def test_detected_boxes_are_smoothed_with_the_frames_on_both_sides():
    # A track moving 2 px a frame with its boxes jittering +-1 px: the straight line through them.
    jitter = [0.0, 1.0, -1.0, 1.0, -1.0, 0.0]
    frames = [{1: (2.0 * i + jitter[i], 10.0, 4.0, 8.0)} for i in range(6)]
    out = list(backfilled([seen(i, f) for i, f in enumerate(frames)], smooth_s=0.1))
    xs = [box[0] for box, _ in boxes_of(out)]
    assert xs[0] == 0.0 and xs[-1] == 10.0                 # an end has one side only: kept
    np.testing.assert_allclose(xs[1:5], [2.0, 13 / 3, 17 / 3, 8.0])   # boxes 0, 3, 3, 7, 7, 10
    assert max(abs(x - 2.0 * i) for i, x in enumerate(xs)) < max(abs(j) for j in jitter)


def test_smoothing_fits_the_boxes_the_tracker_gave_not_smoothed_ones_nor_predictions():
    xs = [0.0, 3.0, 0.0, 3.0, None, 0.0]
    frames = [{1: None if x is None else (x, 0.0, 4.0, 8.0)} for x in xs]
    out = list(backfilled([seen(i, f) for i, f in enumerate(frames)], smooth_s=0.1))
    got = [box[0] for box, _ in boxes_of(out)]
    # frame 2 from frames 1-3 as given (3, 0, 3), not frame 1 smoothed (1, 0, 3: 1.33); frame 3 has
    # one detected neighbour (frame 4 coasts): kept; the coasting frame keeps its prediction.
    np.testing.assert_allclose(got, [0.0, 1.0, 2.0, 3.0, 99.0, 0.0])


def test_the_line_and_the_gaps_go_through_the_detections_boxes_not_the_filters():
    # The filter's box lags each detection by 3 px; the detections move 2 px a frame.
    def frame(index, x):
        packet = seen(index, {1: None if x is None else (x - 3.0, 0.0, 4.0, 8.0)})
        if x is not None:
            packet.tracks[0].detected_box = (x, 0.0, 4.0, 8.0)
        return packet

    xs = [0.0, 2.0, 4.0, None, 8.0, 10.0]
    out = list(backfilled([frame(i, x) for i, x in enumerate(xs)], fill_gaps_s=0.6, smooth_s=0.1))
    got = [box[0] for box, _ in boxes_of(out)]
    # Frame 1 has three detections within 0.1 s: the line through them (2.0); the others have two
    # and keep the filter's box; the gap at frame 3 is filled between the detections 4 and 8.
    np.testing.assert_allclose(got, [-3.0, 2.0, 1.0, 6.0, 5.0, 7.0])


def test_a_frame_with_a_detected_box_waits_for_the_frames_after_it():
    backfill = TrackBackfill(enabled=False, smooth_s=0.2)
    box = (0.0, 0.0, 4.0, 8.0)
    assert backfill.push(seen(0, {1: box})) == []
    assert backfill.push(seen(1, {1: box})) == []
    assert [p.frame.index for p in backfill.push(seen(2, {1: box}))] == [0]
    assert [p.frame.index for p in backfill.push(seen(3, {}))] == [1]
    assert [p.frame.index for p in backfill.push(seen(4, {}))] == [2, 3, 4]   # 3, 4: no box to smooth
