"""ObjectTracker on hand-made detections: ids, births and deaths, and height convergence."""

from __future__ import annotations

import numpy as np
import pytest

from core.config import TrackingConfig
from core.packets import BOX, GEOMETRY, NETWORK, CameraInfo, Detection, FeatureMatches, Frame, FramePacket, Measurement
from stages.association import assign, iou_matrix
from stages.tracking import ObjectTracker, TrackingStage


def _detection(x: float, y: float, height_m: float, w: float = 30, h: float = 80,
               noise_m: float = 0.15, cls: str = "person") -> Detection:
    return Detection(box=(x, y, w, h), heights={NETWORK: Measurement(height_m, noise_m, "test")}, cls=cls)


def _best_track(tracks, box):
    ious = iou_matrix([t.box for t in tracks], [box])[:, 0]
    return tracks[int(np.argmax(ious))] if len(tracks) and ious.max() > 0.3 else None


def test_iou_matrix_and_assignment():
    iou = iou_matrix([(0, 0, 10, 10), (100, 100, 10, 10)], [(5, 0, 10, 10), (0, 0, 10, 10)])
    assert iou[0, 1] == pytest.approx(1.0)
    assert iou[0, 0] == pytest.approx(50 / 150)
    assert iou[1].max() == 0.0
    result = assign(1.0 - iou, iou >= 0.1)
    assert result.matches == [(0, 1)]
    assert result.unmatched_tracks == [1] and result.unmatched_detections == [0]


def test_moving_object_gives_one_track_whose_height_converges():
    rng = np.random.default_rng(0)
    # White measurement noise only (no per-object network bias): the pure averaging case.
    tracker = ObjectTracker(TrackingConfig(network_bias_share=0.0))
    true_height, stds, ids = 1.75, [], set()
    for frame in range(80):
        measured = true_height + rng.normal(0.0, 0.15)
        tracks = tracker.update([_detection(50 + 4 * frame, 100 + frame, measured)])
        assert len(tracks) == 1
        ids.add(tracks[0].track_id)
        stds.append(tracks[0].height_std_m)
    track = tracks[0]
    assert ids == {track.track_id}
    assert track.confirmed and track.cls == "person"
    assert abs(track.height_m - true_height) < 0.05
    # Every frame is one more measurement of the same number: the std shrinks like 1/sqrt(n).
    assert stds[-1] < stds[0] / 4
    assert all(later <= earlier + 1e-9 for earlier, later in zip(stds, stds[1:]))


def test_crossing_objects_keep_their_ids_and_heights():
    rng = np.random.default_rng(1)
    tracker = ObjectTracker(TrackingConfig())
    ids_a, ids_b = [], []
    for frame in range(60):
        box_a = (20 + 5 * frame, 100.0)             # walks right
        box_b = (320 - 5 * frame, 125.0)            # walks left, crossing around frame 30
        detections = [_detection(*box_a, 1.60 + rng.normal(0, 0.05)),
                      _detection(*box_b, 1.90 + rng.normal(0, 0.05))]
        tracks = tracker.update(detections)
        track_a = _best_track(tracks, detections[0].box)
        track_b = _best_track(tracks, detections[1].box)
        ids_a.append(track_a.track_id)
        ids_b.append(track_b.track_id)
    assert len(set(ids_a)) == 1 and len(set(ids_b)) == 1 and ids_a[0] != ids_b[0]
    final = {t.track_id: t.height_m for t in tracks}
    assert final[ids_a[0]] == pytest.approx(1.60, abs=0.05)
    assert final[ids_b[0]] == pytest.approx(1.90, abs=0.05)


def test_births_after_min_hits_and_deaths_after_max_misses():
    config = TrackingConfig(min_hits=3, max_misses=5)
    tracker = ObjectTracker(config)
    confirmed_counts, live_counts = [], []
    for frame in range(20):
        detections = [_detection(100 + 2 * frame, 50, 1.7)] if 2 <= frame < 10 else []
        if frame == 4:
            detections.append(_detection(400, 300, 1.2))      # a one-frame false positive
        tracks = tracker.update(detections)
        live_counts.append(len(tracks))
        confirmed_counts.append(sum(t.confirmed for t in tracks))
    # Seen from frame 2: tentative at 2 and 3, confirmed from frame 4 on (third hit).
    assert confirmed_counts[:4] == [0, 0, 0, 0] and confirmed_counts[4] == 1
    # The false positive lives one frame as a tentative track and is never confirmed.
    assert live_counts[4] == 2 and live_counts[5] == 1
    # Last detection at frame 9: predicted through 5 misses (frames 10-14), gone at frame 15.
    assert confirmed_counts[14] == 1 and live_counts[15] == 0


def test_a_track_that_walks_out_of_the_frame_is_dropped_not_coasted():
    tracker = ObjectTracker(TrackingConfig(min_hits=3, max_misses=30))
    frame_size = (320, 240)
    # Walks right at 10 px/frame, last seen with its box at x 290..320 (the right edge).
    for frame in range(10):
        tracks = tracker.update([_detection(200 + 10 * frame, 100, 1.7)], frame_size=frame_size)
    assert len(tracks) == 1 and tracks[0].confirmed
    lives = [len(tracker.update([], frame_size=frame_size)) for _ in range(5)]
    assert lives[0] == 1          # predicted box still mostly inside: kept for a re-detection
    assert lives[-1] == 0         # predicted outside the image: gone long before max_misses
    # Without a frame size (the old behaviour) the same track coasts on.
    blind = ObjectTracker(TrackingConfig(min_hits=3, max_misses=30))
    for frame in range(10):
        blind.update([_detection(200 + 10 * frame, 100, 1.7)])
    assert [len(blind.update([])) for _ in range(5)] == [1] * 5


def test_a_box_reaching_past_the_image_is_reported_cut_to_it_while_the_filter_keeps_it_whole():
    tracker = ObjectTracker(TrackingConfig(min_hits=3, max_misses=30))
    frame_size = (320, 240)
    # Walks right at 10 px/frame; its last box, x 290..320, touches the right edge.
    for frame in range(10):
        tracker.update([_detection(200 + 10 * frame, 100, 1.7)], frame_size=frame_size)
    (track,) = tracker.update([], frame_size=frame_size)  # predicted at x 300..330
    x, y, w, h = track.box
    assert x == pytest.approx(300, abs=3) and x + w == 320 and (y, h) == pytest.approx((100, 80), abs=3)
    filtered = tracker.tracks[0].motion.box
    assert filtered[0] + filtered[2] > 325 and filtered[2] == pytest.approx(30, abs=3)
    assert track.foot_in_view, "cut at the right, its bottom is still where it stands"
    # Inside the image a box is reported as the filter has it.
    inside = ObjectTracker(TrackingConfig(min_hits=3))
    for frame in range(5):
        (track,) = inside.update([_detection(100 + 5 * frame, 50, 1.7)], frame_size=frame_size)
    assert track.box == tuple(inside.tracks[0].motion.box) and track.foot_in_view


def test_a_box_cut_by_the_bottom_edge_says_its_foot_is_out_of_view():
    tracker = ObjectTracker(TrackingConfig(min_hits=3, max_misses=30))
    frame_size = (320, 240)
    # Walks down at 8 px/frame; boxes 80 px tall, the last one ending at y 232.
    for frame in range(10):
        tracker.update([_detection(100, 80 + 8 * frame, 1.7)], frame_size=frame_size)
    (track,) = tracker.update([], frame_size=frame_size)  # predicted to end at ~y 240
    for _ in range(2):
        (track,) = tracker.update([], frame_size=frame_size)  # ... then past the bottom
    x, y, w, h = track.box
    assert y + h == 240 and not track.foot_in_view


def test_confirmation_and_coasting_are_durations_not_frame_counts():
    """0.2 s to confirm, 3 s of coasting: 2 and 30 frames at 10 fps, 5 and 75 at 25 fps."""
    config = TrackingConfig(min_hits=2, confirm_s=0.2, max_misses=30, max_miss_s=3.0)
    for fps, hits, misses in ((10.0, 2, 30), (25.0, 5, 75)):
        tracker = ObjectTracker(config)
        confirmed_at = None
        for frame in range(8):
            tracks = tracker.update([_detection(100 + frame, 50, 1.7)], frame_interval_s=1.0 / fps)
            if confirmed_at is None and tracks[0].confirmed:
                confirmed_at = frame + 1
        assert confirmed_at == hits
        # A 2 s full occlusion: 50 frames at 25 fps, beyond max_misses (30) but within 3 s.
        for _ in range(int(2.0 * fps)):
            tracks = tracker.update([], frame_interval_s=1.0 / fps)
        assert len(tracks) == 1
        assert tracker.allowed_misses == misses


def test_tracking_stage_measures_the_frame_interval_from_source_times():
    stage = TrackingStage(TrackingConfig(min_hits=2, confirm_s=0.2))
    camera = CameraInfo(640, 480)
    for index in range(4):                       # 25 fps: 0.04 s apart
        stage.process(FramePacket(Frame(index, 0.04 * index, np.zeros((480, 640, 3), np.uint8)), camera))
    assert stage.tracker.required_hits == 5
    strided = TrackingStage(TrackingConfig(min_hits=2, confirm_s=0.2))
    for index in range(4):                       # the same video with stride 5: 0.2 s apart
        strided.process(FramePacket(Frame(5 * index, 0.2 * index, np.zeros((480, 640, 3), np.uint8)), camera))
    assert strided.tracker.required_hits == 2    # never fewer than min_hits


def test_a_coasting_box_keeps_its_size():
    """Seen while its box narrowed by 3 px a frame; unseen, it keeps the last size."""
    tracker = ObjectTracker(TrackingConfig(min_hits=2))
    for frame in range(8):
        tracker.update([_detection(100 + 4 * frame, 50, 1.7, w=60 - 3 * frame, h=80 + 2 * frame)])
    last_w, last_h = tracker.tracks[0].motion.box[2:]
    for _ in range(20):
        tracks = tracker.update([])
    assert tracks[0].box[2] == pytest.approx(last_w, abs=4) and tracks[0].box[3] == pytest.approx(last_h, abs=4)


def test_a_track_reports_the_box_of_the_detection_that_updated_it_beside_the_filters():
    tracker = ObjectTracker(TrackingConfig(min_hits=2))
    for frame in range(5):
        box = (100.0 + 6 * frame + (3.0 if frame == 4 else 0.0), 50.0, 30.0, 80.0)
        tracks = tracker.update([_detection(*box[:2], 1.7)])
    assert tracks[0].detected_box == box
    assert tracks[0].box != box                     # the filter weighs the jump against its prediction
    tracks = tracker.update([])
    assert not tracks[0].updated and tracks[0].detected_box is None


def test_missing_heights_do_not_crash_or_poison_the_state():
    tracker = ObjectTracker(TrackingConfig())
    tracks = tracker.update([_detection(10, 10, float("nan"), noise_m=float("inf"))])
    assert np.isnan(tracks[0].height_m)
    for frame in range(1, 5):
        tracks = tracker.update([_detection(10 + frame, 10, 1.5)])
    assert tracks[0].height_m == pytest.approx(1.5)


def test_camera_motion_moves_the_prediction_not_the_height():
    tracker = ObjectTracker(TrackingConfig(min_hits=1))
    for _ in range(5):
        tracks = tracker.update([_detection(100, 100, 1.8)])
    shake = np.array([[1.0, 0.0, 12.0], [0.0, 1.0, -7.0]], dtype=np.float32)
    empty = np.zeros((0, 2), np.float32)
    matches = FeatureMatches(empty, empty, np.zeros(0, bool), camera_motion=shake)
    tracks = tracker.update([], matches)
    x, y, w, h = tracks[0].box
    assert (x, y) == pytest.approx((112.0, 93.0), abs=0.5)
    assert (w, h) == pytest.approx((30.0, 80.0), abs=0.5)
    assert tracks[0].height_m == pytest.approx(1.8) and not tracks[0].updated


def test_tracking_stage_fills_packet_tracks():
    stage = TrackingStage(TrackingConfig(min_hits=1))
    image = np.zeros((240, 320, 3), np.uint8)
    packet = FramePacket(Frame(0, 0.0, image), CameraInfo(320, 240),
                         detections=[_detection(10, 10, 1.7)])
    packet = stage.process(packet)
    assert len(packet.tracks) == 1 and packet.tracks[0].confirmed


def test_two_second_full_occlusion_keeps_id_and_height():
    """Hidden for 20 frames (2 s at 10 fps), seen again further on: same id, same height."""
    rng = np.random.default_rng(2)
    tracker = ObjectTracker(TrackingConfig())
    ids = []
    for frame in range(60):
        hidden = 20 <= frame < 40
        detections = [] if hidden else [_detection(20 + 4 * frame, 100, 1.72 + rng.normal(0, 0.05))]
        tracks = tracker.update(detections)
        if not hidden:
            ids.append(tracks[0].track_id)
        if frame == 19:
            height_before = tracks[0].height_m
    assert len(tracks) == 1 and set(ids) == {tracks[0].track_id}
    assert tracks[0].height_m == pytest.approx(height_before, abs=0.02)
    assert tracks[0].box[0] == pytest.approx(20 + 4 * 59, abs=3)


def test_a_walker_who_slowed_down_while_hidden_is_found_again():
    """Its prediction ran on at the old speed, most of a box width ahead of where it came out:
    neither it nor the last observed box overlaps the walker; the buffered prediction does."""
    tracker = ObjectTracker(TrackingConfig())
    x, ids = 20.0, []
    for frame in range(70):
        x += 4.0 if frame < 20 else 2.5                 # slows down behind the occluder
        hidden = 20 <= frame < 45
        tracks = tracker.update([] if hidden else [_detection(x, 100, 1.72)])
        if not hidden:
            ids.append(tracks[0].track_id)
    assert len(set(ids)) == 1


def test_reupdate_after_gap_resets_drifted_velocity():
    """OC-SORT re-update: after a gap the velocity comes from the observations around it."""
    tracker = ObjectTracker(TrackingConfig(max_misses=50))
    for frame in range(10):
        tracker.update([_detection(100 + 5 * frame, 100, 1.7)])        # moving right, 5 px/frame
    for _ in range(10):
        tracker.update([])                                              # hidden
    tracker.update([_detection(150, 100, 1.7)])                         # it had stopped at 150
    # Re-updated along 145 -> 150 over 11 frames, the velocity is ~0.5 px/frame, not 5.
    assert abs(tracker.tracks[0].motion.velocity[0]) < 1.5


def test_walker_reports_stature_not_mean_of_gait():
    rng = np.random.default_rng(3)
    tracker = ObjectTracker(TrackingConfig())
    stature = 1.80
    for frame in range(80):
        dip = 0.04 * np.sin(np.pi * frame / 5.0) ** 2                    # hip drop, mean 2 cm
        tracks = tracker.update([_detection(20 + 3 * frame, 100, stature - dip + rng.normal(0, 0.01),
                                            noise_m=0.01)])
    with_window = tracks[0].height_m
    plain = ObjectTracker(TrackingConfig(stature_window=0))
    rng = np.random.default_rng(3)
    for frame in range(80):
        dip = 0.04 * np.sin(np.pi * frame / 5.0) ** 2
        tracks = plain.update([_detection(20 + 3 * frame, 100, stature - dip + rng.normal(0, 0.01),
                                          noise_m=0.01)])
    assert tracks[0].height_m == pytest.approx(stature - 0.02, abs=0.01)    # the mean dip
    # At 10 fps only one frame in five is near the top of the gait: the window recovers part of
    # the dip (measured: 2.5 cm error -> 1.7 cm) without chasing noise (first test: σ = 15 cm).
    assert stature - with_window < stature - tracks[0].height_m - 0.004
    assert with_window < stature + 0.005


def test_geometry_is_a_second_height_channel():
    tracker = ObjectTracker(TrackingConfig(min_hits=1))
    for frame in range(30):
        detection = _detection(10 + 2 * frame, 10, 1.70, noise_m=0.10)
        detection.add_height(GEOMETRY, Measurement(1.80, 0.10, "test"))
        detection.ground_xy_m = (1.0 + 0.1 * frame, 2.0)
        tracks = tracker.update([detection])
    # The channels disagree by 10 cm in every frame: a bias of one or both. The height settles
    # between them by their bias priors (network 0.2 x 1.7 = 34 cm, geometry 1 x its 10 cm noise):
    # nearly the geometry, and no surer than those biases allow, however many frames agree.
    prior_n, prior_g = 0.2 * 1.70, 0.10
    expected = (prior_n ** 2 * 1.80 + prior_g ** 2 * 1.70) / (prior_n ** 2 + prior_g ** 2)
    assert tracks[0].height_source == "fused"
    assert tracks[0].height_m == pytest.approx(expected, abs=0.005)
    floor = 1 / np.sqrt(1 / prior_n ** 2 + 1 / prior_g ** 2)
    assert floor <= tracks[0].height_std_m < 1.05 * floor
    assert tracks[0].ground_xy_m == pytest.approx((3.9, 2.0))
    # Without bias states the two channels are simply averaged; with the network taken as
    # unbiased (true height maps), the height is the network's.
    for network_share, geometry_factor, height in ((0.0, 0.0, 1.75), (0.0, 1.0, 1.70)):
        tracker = ObjectTracker(TrackingConfig(min_hits=1, network_bias_share=network_share,
                                               geometry_bias_factor=geometry_factor))
        for frame in range(30):
            detection = _detection(10 + 2 * frame, 10, 1.70, noise_m=0.10)
            detection.add_height(GEOMETRY, Measurement(1.80, 0.10, "test"))
            tracks = tracker.update([detection])
        assert tracks[0].height_m == pytest.approx(height, abs=0.01)
    only_geometry = ObjectTracker(TrackingConfig(min_hits=1))
    detection = _detection(10, 10, float("nan"), noise_m=float("inf"))
    detection.add_height(GEOMETRY, Measurement(1.8, 0.1, "test"))
    assert only_geometry.update([detection])[0].height_source == "geometry"


def test_a_network_bias_is_not_averaged_away_and_the_geometry_learns_it():
    rng = np.random.default_rng(3)
    network_only = ObjectTracker(TrackingConfig(min_hits=1))
    for frame in range(60):
        tracks = network_only.update([_detection(10 + 2 * frame, 10, 1.50 + rng.normal(0, 0.05), noise_m=0.05)])
    # Sixty frames of the same network reading do not make it surer than the network's bias.
    assert tracks[0].height_m == pytest.approx(1.50, abs=0.03)
    assert tracks[0].height_std_m > 0.15 * 1.50
    # With geometry for 30 frames, the difference (-0.25 m) is learnt, nearly all of it as the
    # network's bias (its prior 0.3 m against the geometry's 0.05 m): frames where only the network
    # measures (feet cut off) keep the height instead of pulling it to 1.50, and its std stays
    # at what the biases allow (sqrt(1 / (1/0.3^2 + 1/0.05^2)) = 4.9 cm).
    tracker = ObjectTracker(TrackingConfig(min_hits=1))
    for frame in range(60):
        detection = _detection(10 + 2 * frame, 10, 1.50 + rng.normal(0, 0.05), noise_m=0.05)
        if frame < 30:
            detection.add_height(GEOMETRY, Measurement(1.75 + rng.normal(0, 0.05), 0.05, "test"))
        tracks = tracker.update([detection])
    assert tracks[0].height_m == pytest.approx(1.75, abs=0.03)
    assert tracks[0].height_std_m < 0.055


def test_one_wild_height_does_not_move_a_settled_track():
    tracker = ObjectTracker(TrackingConfig())
    for frame in range(20):
        tracks = tracker.update([_detection(10 + 2 * frame, 10, 1.70, noise_m=0.05)])
    settled = tracks[0].height_m
    tracks = tracker.update([_detection(50, 10, 3.5, noise_m=0.05)])   # merged with a bus
    assert tracks[0].height_m == pytest.approx(settled, abs=1e-6)


def test_a_box_on_the_prediction_keeps_its_track_whatever_height_it_reads():
    """A settled 3.4 m vehicle drives behind a building's corner, whose edge joins its blob:
    five frames read 4.7 m. The box still lies on the prediction, so the track keeps its id
    (refused by the height gate, the vehicle got a second track); the heights are skipped."""
    tracker = ObjectTracker(TrackingConfig(stature_window=0))
    for frame in range(20):
        tracks = tracker.update([_detection(10 + 4 * frame, 50, 3.4, w=120, h=45, noise_m=0.1, cls="vehicle")])
    (track,) = tracks
    for frame in range(20, 25):
        tracks = tracker.update([_detection(10 + 4 * frame, 50, 4.7, w=120, h=45, noise_m=0.1, cls="vehicle")])
    assert [t.track_id for t in tracks] == [track.track_id] and tracks[0].updated
    assert tracks[0].height_m == pytest.approx(track.height_m, abs=0.01)
    # A box off the prediction (a vehicle beside it) is still kept apart by its height.
    tracks = tracker.update([_detection(10 + 4 * 25 + 70, 50, 4.7, w=120, h=45, noise_m=0.1, cls="vehicle")])
    assert track.track_id not in [t.track_id for t in tracks if t.updated]


def test_a_geometry_channel_rejected_every_frame_restarts_a_height_born_wrong():
    """Born from a merged blob the network reads 3.0 m (no geometry: feet hidden), then the
    network reads 2.5 m and the geometry 1.8 m.

    The network is accepted every frame; the geometry, rejected every frame, must still win:
    rejections are counted per channel (Oxford: a walker held 2.4 m against 1.8 m geometry).
    """
    tracker = ObjectTracker(TrackingConfig(min_hits=1, stature_window=0))
    for frame in range(6):
        tracks = tracker.update([_detection(10 + frame, 10, 3.0, noise_m=0.2)])
    for frame in range(6, 40):
        detection = _detection(10 + frame, 10, 2.5, noise_m=0.2)
        detection.add_height(GEOMETRY, Measurement(1.80, 0.04, "test"))
        tracks = tracker.update([detection])
    assert len(tracks) == 1 and tracks[0].height_source == "fused"
    assert tracks[0].height_m == pytest.approx(1.80, abs=0.1)


def test_a_settled_height_outweighs_a_short_run_of_overshooting_boxes():
    """Forty frames at 1.80 m, then ten whose boxes overshoot (2.10 m, rejected by the gate):
    the run says less than the state, so the height stays (a count alone restarted it)."""
    tracker = ObjectTracker(TrackingConfig(min_hits=1, stature_window=0))
    for frame in range(50):
        detection = _detection(10 + frame, 10, float("nan"), noise_m=float("inf"))
        detection.add_height(GEOMETRY, Measurement(1.80 if frame < 40 else 2.10, 0.04, "test"))
        tracks = tracker.update([detection])
    assert tracks[0].height_m == pytest.approx(1.80, abs=0.02)


def test_a_network_height_below_the_geometry_bound_is_raised_to_it():
    """Feet out of the frame: the network reads 1.4 m, the geometry says at least 1.7 m."""
    tracker = ObjectTracker(TrackingConfig(min_hits=1, stature_window=0))
    for frame in range(20):
        detection = _detection(10 + frame, 10, 1.40, noise_m=0.1)
        detection.min_height_m = 1.70
        tracks = tracker.update([detection])
    assert tracks[0].height_m == pytest.approx(1.70, abs=0.01)
    vehicle = ObjectTracker(TrackingConfig(min_hits=1, stature_window=0))
    for frame in range(20):                 # a vehicle's top is its far roof edge: no bound
        detection = _detection(10 + frame, 10, 1.40, w=120, h=60, noise_m=0.1, cls="vehicle")
        detection.min_height_m = 1.70
        tracks = vehicle.update([detection])
    assert tracks[0].height_m == pytest.approx(1.40, abs=0.01)


def test_a_walkers_geometry_heights_are_averaged_not_windowed():
    """Box-based geometry heights wobble with the box (here 1.7 / 1.9 m), far more than their
    stated noise: an upper quantile would pick the overshooting boxes (1.87 m), not the stature."""
    tracker = ObjectTracker(TrackingConfig(min_hits=1))
    for frame in range(40):
        detection = _detection(10 + 2 * frame, 10, float("nan"), noise_m=float("inf"))
        detection.add_height(GEOMETRY, Measurement(1.70 if frame % 2 else 1.90, 0.04, "test"))
        tracks = tracker.update([detection])
    assert tracks[0].cls == "person" and tracks[0].height_m == pytest.approx(1.80, abs=0.02)


def test_a_track_that_turns_out_a_vehicle_drops_the_geometry_it_took_as_a_cyclist():
    """A car first boxed like a cyclist: its geometry (the far roof edge, 3.1 m) went in; once the
    votes make it a vehicle its height starts again from the network (1.5 m)."""
    tracker = ObjectTracker(TrackingConfig(min_hits=1, stature_window=0))
    for frame in range(30):
        cls = "cyclist" if frame < 6 else "vehicle"
        detection = _detection(10 + 2 * frame, 10, 1.50, w=60, h=50, noise_m=0.6, cls=cls)
        detection.add_height(GEOMETRY, Measurement(3.10, 0.14, "test"))
        tracks = tracker.update([detection])
    assert tracks[0].cls == "vehicle"
    assert tracks[0].height_m == pytest.approx(1.50, abs=0.1)


def test_a_vehicle_track_is_measured_by_its_box_not_by_foot_and_top():
    """A van read 1.3 m by a network that reads big objects low, 3.0 m by foot and top (the far
    roof edge) and 2.2 m by the box fitted to its outline. The foot/top height stays out; the
    height settles between network and box by their per-object bias priors (the network's 20 %
    of 1.3 m against the box's 0.2 m): nearer the box."""
    tracker = ObjectTracker(TrackingConfig(min_hits=1, stature_window=0))
    for frame in range(30):
        detection = _detection(10 + 2 * frame, 10, 1.30, w=80, h=50, noise_m=0.5, cls="vehicle")
        detection.add_height(GEOMETRY, Measurement(3.0, 0.1, "test", bias_m=0.05))
        detection.add_height(BOX, Measurement(2.2, 0.3, "test", bias_m=0.2))
        tracks = tracker.update([detection])
    assert tracks[0].cls == "vehicle"
    assert tracks[0].height_source == "fused"
    assert 1.75 < tracks[0].height_m < 2.2
    # Its std is what the two biases leave, not the frames' averaged-away noise.
    assert 0.1 < tracks[0].height_std_m < 0.3


@pytest.mark.parametrize("axis, used", [((0.0, 1.0), True), ((1.0, 0.0), False)])
def test_a_box_whose_length_was_assumed_must_lie_along_the_tracks_way(axis, used):
    """Only an end seen: a car coming towards the camera, or a bicycle crossing its view side-on."""
    tracker = ObjectTracker(TrackingConfig(min_hits=1, stature_window=0))
    for frame in range(20):
        detection = _detection(100, 10 + 3 * frame, 1.0, w=60, h=50, noise_m=0.5, cls="vehicle")
        detection.ground_xy_m = (0.0, 10.0 + 0.5 * frame)               # it moves along y
        detection.add_height(BOX, Measurement(1.5, 0.4, "test", bias_m=0.35))
        detection.vehicle_axis_xy, detection.vehicle_length_assumed = axis, True
        tracks = tracker.update([detection])
    assert (tracks[0].height_source == "fused") == used


def test_a_box_reading_does_not_measure_a_walker():
    tracker = ObjectTracker(TrackingConfig(min_hits=1, stature_window=0))
    for frame in range(20):
        detection = _detection(10 + 2 * frame, 10, 1.75, noise_m=0.1)
        detection.add_height(BOX, Measurement(1.0, 0.3, "test", bias_m=0.2))
        tracks = tracker.update([detection])
    assert tracks[0].height_source == "network"
    assert tracks[0].height_m == pytest.approx(1.75, abs=0.02)


def test_matched_points_vote_for_the_blob_that_continues_a_track():
    """Two candidate blobs overlap the prediction equally; the matched points decide."""
    tracker = ObjectTracker(TrackingConfig(min_hits=1))
    tracker.update([_detection(100, 100, 1.7, w=40, h=80)])
    left, right = _detection(80, 100, 1.7, w=40, h=80), _detection(120, 100, 1.7, w=40, h=80)
    prev = np.array([[110.0 + i, 120.0 + 3 * i] for i in range(10)], np.float32)
    curr = prev + np.float32([20.0, 0.0])                     # the object's texture moved right
    matches = FeatureMatches(prev, curr, np.ones(10, bool))
    tracks = tracker.update([left, right], matches)
    continued = [t for t in tracks if t.track_id == 1][0]
    assert continued.box[0] > 105


def test_two_tracks_on_one_object_become_one():
    """One object detected twice (nested blobs) must not become two tracks; the older one stays."""
    tracker = ObjectTracker(TrackingConfig(min_hits=1))
    for i in range(5):
        tracks = tracker.update([_detection(100 + 2 * i, 100, 1.7)])
    for i in range(5, 9):
        tracks = tracker.update([_detection(100 + 2 * i, 100, 1.7), _detection(101 + 2 * i, 101, 1.7)])
        assert [t.track_id for t in tracks] == [1]


def test_a_coasting_track_does_not_take_a_box_half_its_size():
    """Oxford: a walker cut by the top edge coasted, then took the legs of someone passing below
    it (a box half as tall, overlapping its lower part) and got their 0.87 m. The walker's own
    box, seen again, is still taken."""
    tracker = ObjectTracker(TrackingConfig(min_hits=1))
    cut = dict(height_m=float("nan"), noise_m=float("inf"), w=30, h=90)   # top cut: no height
    for frame in range(10):
        tracker.update([_detection(100, 0, **cut)])
    for frame in range(4):
        tracker.update([])
    legs = _detection(100, 60, 0.87, w=30, h=42)           # overlaps the lower third of the box
    walker = [t for t in tracker.update([legs]) if t.track_id == 1][0]
    assert not walker.updated and np.isnan(walker.height_m)
    assert [t for t in tracker.update([_detection(100, 0, **cut)]) if t.track_id == 1][0].updated


def test_the_geometry_bias_prior_is_its_per_object_part_not_the_shared_camera_height():
    """A self-calibrated camera's height is unsure (the same for every object): the geometry's
    noise says so, its bias prior does not, so the height still follows the geometry."""
    tracker = ObjectTracker(TrackingConfig(min_hits=1))
    for frame in range(30):
        detection = _detection(10 + 2 * frame, 10, 1.50, noise_m=0.10)
        detection.add_height(GEOMETRY, Measurement(1.80, 0.30, "test", bias_m=0.05))
        tracks = tracker.update([detection])
    prior_n, prior_g = 0.2 * 1.50, 0.05
    expected = (prior_n ** 2 * 1.80 + prior_g ** 2 * 1.50) / (prior_n ** 2 + prior_g ** 2)
    assert tracks[0].height_m == pytest.approx(expected, abs=0.01)


def test_the_cameras_share_of_the_height_widens_the_reported_std_not_the_height():
    """A self-calibrated pose errs the same way on every frame: the std a track reports keeps that
    share of its height (frames do not average it away), the height itself is the same."""
    def run(share: float):
        tracker = ObjectTracker(TrackingConfig(min_hits=1))
        for frame in range(30):
            detection = _detection(10 + 2 * frame, 10, 1.70, noise_m=0.10)
            detection.add_height(GEOMETRY, Measurement(1.80, 0.10, "test"))
            detection.camera_share = share
            tracks = tracker.update([detection])
        return tracks[0]

    exact, unsure = run(0.0), run(0.05)
    assert unsure.height_m == exact.height_m
    assert unsure.height_std_m == pytest.approx(np.hypot(exact.height_std_m, 0.05 * exact.height_m))


@pytest.mark.parametrize("why", ["damaged", "network reused"])
def test_damaged_or_stale_map_frames_carry_the_track_but_fuse_no_height(why):
    stage = TrackingStage(TrackingConfig(min_hits=1))
    image = np.zeros((240, 320, 3), np.uint8)
    heights = []
    for i in range(20):
        bad = i >= 10
        damage = "decoder flags it corrupt" if bad and why == "damaged" else ""
        detection = _detection(10 + 3 * i, 10, 3.0 if bad else 1.7)   # concealment, a stale map: a wild height
        detection.add_height(GEOMETRY, Measurement(detection.height(), 0.1, "test"))
        packet = stage.process(FramePacket(Frame(i, i / 10, image, damage=damage), CameraInfo(320, 240),
                                           detections=[detection], network_reused=bad and why == "network reused"))
        assert len(packet.tracks) == 1
        heights.append(packet.tracks[0].height_m)
    assert heights[10:] == [heights[9]] * 10            # no height fused on those frames
    assert packet.tracks[0].box[0] > 60                 # while the box still follows the object


def _weak(detection: Detection) -> Detection:
    detection.continues_only = True
    return detection


@pytest.mark.parametrize("gap, shift, carried", [
    (0, 0.0, True),      # a walker whose score dipped this frame: the track goes on
    (0, 20.0, False),    # a weak box beside the prediction (IoU < 0.5) carries nothing
    (1, 0.0, False),     # a track already coasting is not carried on by a weak box
])
def test_a_weak_box_carries_on_a_track_seen_last_frame_and_never_starts_one(gap, shift, carried):
    stage = TrackingStage(TrackingConfig(min_hits=3))
    image = np.zeros((240, 320, 3), np.uint8)

    def step(index: int, detections: list[Detection]) -> FramePacket:
        packet = FramePacket(Frame(index, index / 10, image), CameraInfo(320, 240), detections=detections)
        return stage.process(packet)

    for frame in range(5):
        step(frame, [_detection(50 + 4 * frame, 100, 1.7)])
    for frame in range(5, 5 + gap):
        step(frame, [])
    frame = 5 + gap
    packet = step(frame, [_weak(_detection(50 + 4 * frame + shift, 100, 1.7)),
                          _weak(_detection(250, 20, 1.7))])          # a weak box on nothing
    (track,) = packet.tracks
    assert (track.track_id, track.updated) == (1, carried)
    # The weak box on nothing is no object this frame; the one that carried the track is.
    assert [d.box[1] for d in packet.detections] == ([100] if carried else [])


@pytest.mark.parametrize("colours, taken", [(True, "red"), (False, "blue")])
def test_a_box_in_another_objects_colours_does_not_carry_on_a_track(colours, taken):
    """A red walker's track; then a blue walker's box lies nearer its prediction than the red
    walker's own (a second walker stepping alongside: Oxford's side-by-side pairs)."""
    red_colour, blue_colour = np.eye(128)[5], np.eye(128)[90]         # signatures of one bin each
    config = TrackingConfig(min_hits=1) if colours else TrackingConfig(min_hits=1, colour_gate=1.0, colour_weight=0.0)
    tracker = ObjectTracker(config)
    for i in range(10):
        walker = _detection(100 + 4 * i, 60, 1.75)
        walker.colour = red_colour
        tracker.update([walker])
    (track,) = tracker.tracks
    red, blue = _detection(132, 60, 1.75), _detection(146, 60, 1.75)      # the prediction is at x = 140
    red.colour, blue.colour = red_colour, blue_colour
    tracker.update([blue, red])
    assert track.last_observation == {"red": red.box, "blue": blue.box}[taken]


def test_the_tracking_stage_reads_each_boxs_colours_from_the_frame():
    stage = TrackingStage(TrackingConfig(min_hits=1))
    image = np.full((240, 320, 3), 128, np.uint8)
    image[60:140, 100:130] = (30, 30, 200)
    red, street, blob = _detection(100, 60, 1.75), _detection(200, 60, 1.75), _detection(250, 60, 1.75)
    blob.blob = 1                       # a blob's box holds whatever moved together: no colours
    stage.process(FramePacket(Frame(0, 0.0, image), CameraInfo(320, 240), detections=[red, street, blob]))
    assert red.colour.argmax() != street.colour.argmax()
    assert red.colour.max() == street.colour.max() == pytest.approx(1.0)
    assert blob.colour is None


def test_damaged_frames_give_their_boxes_no_colours():
    stage = TrackingStage(TrackingConfig(min_hits=1))
    image = np.full((240, 320, 3), 128, np.uint8)
    for damage, expected in (("", False), ("decoder flags it corrupt", True)):
        detection = _detection(10, 10, 1.7)
        stage.process(FramePacket(Frame(0, 0.0, image, damage=damage), CameraInfo(320, 240), detections=[detection]))
        assert (detection.colour is None) == expected
