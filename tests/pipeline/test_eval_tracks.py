"""eval-tracks metrics and reports on hand-made sequences (no generator needed), and against trackeval."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.eval_metrics import (_trackeval_metrics, evaluate, miss_breakdown, mot_data, mot_metrics,
                                   occlusion_events)
from pipeline.eval_reports import format_report, objects_followed, plot_height_series
from pipeline.eval_sequences import DetectionBox, FrameRecord, OutputBox, SequenceRun, TruthBox
from synth.dataset import PARKED_VEHICLE_ID


def _truth(object_id, x, visibility=1.0, height=1.75, cls="person"):
    return TruthBox(object_id, cls, (x, 50.0, 20.0, 60.0), visibility, height)


def _out(track_id, x, height=1.75, updated=True):
    return OutputBox(track_id, (x, 50.0, 20.0, 60.0), height, 0.02, "person", "network", updated)


def _run(frames, name="seq"):
    return SequenceRun(name, 5.0, "clear", "day", 10.0, frames)


def test_perfect_tracking_scores_one():
    frames = [FrameRecord([_truth(1, 10 + 3 * i), _truth(2, 200 - 3 * i)],
                          [_out(7, 10 + 3 * i), _out(9, 200 - 3 * i)], []) for i in range(20)]
    for engine in (False, None):
        mot = mot_metrics([mot_data(_run(frames), 0.3)], use_trackeval=engine)
        assert mot["HOTA"] == pytest.approx(1.0) and mot["MOTA"] == pytest.approx(1.0)
        assert mot["IDF1"] == pytest.approx(1.0) and mot["IDSW"] == 0


def test_loose_boxes_keep_detection_at_a_low_iou_threshold_and_lose_it_at_a_high_one():
    # Every box found, every box 4 px to the side of its 20 px wide truth: IoU 16 x 60 / (24 x 60) = 0.67.
    frames = [FrameRecord([_truth(1, 10 + 2 * i)], [_out(5, 14 + 2 * i)], []) for i in range(10)]
    report = evaluate([_run(frames)], use_trackeval=False)
    mot = report["mot"]
    shown = mot["by_iou"]
    assert list(shown) == ["0.05", "0.25", "0.50", "0.75", "0.95"]
    assert shown["0.05"]["DetA"] == pytest.approx(1.0) and shown["0.50"]["DetA"] == pytest.approx(1.0)
    assert shown["0.75"]["DetA"] == 0.0 and shown["0.95"]["DetA"] == 0.0
    assert mot["DetA"] == pytest.approx(sum(alpha <= 2 / 3 for alpha in np.arange(0.05, 0.99, 0.05)) / 19)
    assert "at IoU threshold 0.05: DetA 1.00 AssA 1.00" in format_report(report)


def test_an_id_switch_is_counted_and_costs_idf1():
    frames = [FrameRecord([_truth(1, 10 + 3 * i)], [_out(7 if i < 10 else 8, 10 + 3 * i)], [])
              for i in range(20)]
    mot = mot_metrics([mot_data(_run(frames), 0.3)], use_trackeval=False)
    assert mot["IDSW"] == 1
    assert mot["MOTA"] == pytest.approx(1 - 1 / 20)
    assert mot["IDF1"] == pytest.approx(2 * 10 / 40)


def test_hidden_truth_is_dont_care():
    """A track box on a hidden object is no false positive; a missed hidden object no miss."""
    frames = [FrameRecord([_truth(1, 10, visibility=0.05)], [_out(7, 10)], []),
              FrameRecord([_truth(1, 10, visibility=0.05)], [], [])]
    data = mot_data(_run(frames), 0.3)
    assert data["num_gt_dets"] == 0 and data["num_tracker_dets"] == 0


def test_a_box_on_a_parked_vehicle_is_dont_care_unless_an_object_claims_it():
    """Parked vehicles have no truth box; a track or detection lying mostly on one is neither
    true nor false, but one that matches a required object still counts."""
    from pipeline.eval_metrics import frame_detection_counts
    from pipeline.eval_sequences import dont_care_region

    semantic = np.zeros((240, 320), np.uint8)
    semantic[50:110, 100:130] = PARKED_VEHICLE_ID   # a parked car at x 100-130, the box of _out(.., 100)
    region = dont_care_region(semantic)
    assert dont_care_region(np.zeros_like(semantic)) is None
    frames = [FrameRecord([_truth(1, 10)], [_out(7, 10), _out(8, 100), _out(9, 200)], [], region)]
    data = mot_data(_run(frames), 0.3)
    assert data["num_gt_dets"] == 1 and data["num_tracker_dets"] == 2   # 8 left out, 9 a false positive
    counts = frame_detection_counts([_truth(1, 100)], [DetectionBox((100.0, 50.0, 20.0, 60.0), 1.75, "person")],
                                    0.3, 0.0, region)
    assert counts["all"]["detections"] == 1 and counts["all"]["correct"] == 1   # a walker in front of it


def test_builtin_metrics_agree_with_trackeval():
    if _trackeval_metrics() is None:
        pytest.skip("trackeval (optional eval extra) not installed")
    rng = np.random.default_rng(0)
    runs = []
    for s in range(3):
        frames = []
        for i in range(30):
            truth = [_truth(k, 30 * k + 2 * i) for k in range(4) if rng.random() > 0.1]
            outs = [_out(10 * k + (i > 15 and k == 1) + (rng.random() < 0.05),
                         30 * k + 2 * i + rng.normal(0, 4)) for k in range(4) if rng.random() > 0.15]
            outs.append(_out(99, 400 + rng.normal(0, 30)))
            frames.append(FrameRecord(truth, outs, []))
        runs.append(_run(frames, f"s{s}"))
    datas = [mot_data(r, 0.3) for r in runs]
    ours, theirs = mot_metrics(datas, use_trackeval=False), mot_metrics(datas, use_trackeval=True)
    assert theirs["engine"] == "trackeval"
    for key in ("HOTA", "DetA", "AssA", "MOTA", "IDF1", "IDSW"):
        assert ours[key] == pytest.approx(theirs[key], abs=1e-9), key


def test_height_errors_tracked_vs_single_frame_and_occlusion():
    rng = np.random.default_rng(1)
    frames = []
    for i in range(40):
        hidden = 15 <= i < 25
        truth = [_truth(1, 10 + 2 * i, visibility=0.0 if hidden else 1.0, height=1.80)]
        outs = [] if hidden else [_out(5, 10 + 2 * i, height=1.80 + 0.3 / (i + 1))]
        dets = [] if hidden else [DetectionBox((10 + 2 * i, 50.0, 20.0, 60.0), 1.80 + rng.normal(0, 0.1))]
        frames.append(FrameRecord(truth, outs, dets))
    report = evaluate([_run(frames)], use_trackeval=False)
    summary = report["height_by_class"]["person"]
    assert summary["objects"] == 1
    assert summary["tracked_median_error_m"] == pytest.approx(0.3 / 40)
    assert 0.03 < summary["single_frame_median_error_m"] < 0.15
    assert report["occlusions"] == occlusion_events(_run(frames), 0.3, 5)
    (event,) = report["occlusions"]
    assert event["kept_id"] and event["hidden_frames"] == 10


def test_tracking_is_scored_per_camera_height_weather_and_time_of_day():
    tracked = [FrameRecord([_truth(1, 10 + 3 * i)], [_out(7, 10 + 3 * i)], []) for i in range(20)]
    missed = [FrameRecord([_truth(1, 10 + 3 * i)], [], []) for i in range(20)]
    runs = [_run(tracked, "dry"), SequenceRun("wet", 5.0, "rain", "night", 10.0, missed)]
    report = evaluate(runs, use_trackeval=False)
    groups = report["mot_by_group"]
    assert set(groups) == {"camera at 5.0 m", "weather clear", "weather rain", "day", "night"}
    assert groups["weather clear"]["HOTA"] == pytest.approx(1.0) and groups["day"]["sequences"] == 1
    assert groups["weather rain"]["HOTA"] == pytest.approx(0.0) and groups["night"]["IDF1"] == 0.0
    assert groups["camera at 5.0 m"]["HOTA"] == pytest.approx(report["mot"]["HOTA"])
    assert groups["camera at 5.0 m"]["sequences"] == 2
    assert "weather rain                           0.000" in format_report(report)


def test_an_occlusion_re_found_late_by_a_new_track_counts_as_lost():
    """Seen again but not re-found at once, then picked up by a new track: a lost id, not no event
    (the count used to restart at the first visible frame and missed exactly these)."""
    frames = []
    for i in range(40):
        visibility = 0.0 if 10 <= i < 30 else (0.2 if i == 30 else 1.0)
        outs = [_out(5, 10 + 2 * i)] if i < 10 else ([_out(6, 10 + 2 * i)] if i >= 33 else [])
        frames.append(FrameRecord([_truth(1, 10 + 2 * i, visibility=visibility)], outs, []))
    (event,) = occlusion_events(_run(frames), 0.3, 5)
    assert not event["kept_id"] and (event["id_before"], event["id_after"]) == (5, 6)
    assert event["hidden_frames"] == 20


def test_objects_too_small_to_be_required_give_no_occlusion_events():
    frames = [FrameRecord([_truth(1, 10 + 2 * i, visibility=0.0 if 10 <= i < 20 else 1.0)],
                          [] if 10 <= i < 20 else [_out(5 if i < 10 else 6, 10 + 2 * i)], []) for i in range(30)]
    assert len(occlusion_events(_run(frames), 0.3, 5)) == 1                  # 60 px boxes
    assert occlusion_events(_run(frames), 0.3, 5, min_box_px=80) == []      # don't-care for MOT too


def test_the_height_picture_pairs_each_track_with_the_object_it_follows(tmp_path):
    """Track 7 follows object 1, track 8 takes over object 2 from track 9 late, 5 is clutter."""
    frames = [FrameRecord([_truth(1, 10 + 3 * i), _truth(2, 200)],
                          [_out(7, 10 + 3 * i, 1.70), _out(9 if i < 5 else 8, 200, 1.80), _out(5, 400, 0.9)],
                          [DetectionBox((10 + 3 * i, 50.0, 20.0, 60.0), 1.6)]) for i in range(20)]
    followed = objects_followed(_run(frames), 0.3)
    assert {t: o.object_id for t, o in followed.items()} == {7: 1, 8: 2, 9: 2}
    plot_height_series(_run(frames), tmp_path / "heights.png", 0.3)
    assert (tmp_path / "heights.png").stat().st_size > 10_000


def test_misses_say_whether_detection_or_tracking_lost_an_object():
    """Object 1 tracked; 2 detected but no track there; 3 and 4 in one merged detection; 5 under
    a detection twice its width (IoU 0.5 is not reached); 6 not detected at all."""
    truth = [_truth(i, 100.0 * i) for i in range(1, 7)]
    truth[3] = _truth(4, 325.0)                                   # beside object 3 (x 300)
    detections = [DetectionBox((100.0, 50.0, 20.0, 60.0), 1.7), DetectionBox((200.0, 50.0, 20.0, 60.0), 1.7),
                  DetectionBox((300.0, 50.0, 45.0, 60.0), 1.7), DetectionBox((495.0, 50.0, 45.0, 60.0), 1.7)]
    run = _run([FrameRecord(truth, [_out(7, 100.0)], detections)])
    misses = miss_breakdown([run], 0.3)
    assert misses["all"] == {"tracked": 1, "detected, no track": 1, "merged with others": 2,
                             "box off": 1, "not detected": 1}
    assert misses["class person"] == misses["all"] and sum(misses["box 40-80 px"].values()) == 6


@pytest.mark.parametrize("heights, geometry, camera, header", [
    ("model", True, "true", "heights from model + geometry; "),
    ("model", False, "height", "heights from model, camera height only; "),
])
def test_the_report_says_what_the_runs_were_told_of_the_camera(heights, geometry, camera, header):
    report = evaluate([_run([FrameRecord([_truth(1, 10)], [_out(7, 10)], [])])], use_trackeval=False)
    report.update(heights=heights, geometry=geometry, camera=camera)
    assert header in format_report(report).splitlines()[0]


def test_the_report_says_how_often_the_truth_lies_within_the_reported_uncertainty():
    """Four objects tracked 10, 30, 50 and 100 cm off, each reported at ±20 cm (std): one within
    1 std, three within 2."""
    frames = []
    for i in range(12):
        truth = [_truth(k, 10 + 60 * k, height=1.70) for k in range(4)]
        outs = [OutputBox(10 + k, (10 + 60 * k, 50.0, 20.0, 60.0), 1.70 + off, 0.20, "person", "network", True)
                for k, off in enumerate((0.1, -0.3, 0.35, 1.0))]
        frames.append(FrameRecord(truth, outs, []))
    report = evaluate([_run(frames)], use_trackeval=False)
    cover = report["height_all"]
    assert (cover["within_1_std"], cover["within_2_std"], cover["uncertainty_objects"]) == (0.25, 0.75, 4)
    assert "±1 std for 25 % of objects, ±2 std 75 %" in format_report(report)
