import math

from pipeline.runner import RunSummary
from pipeline.summary import format_summary
from stages.objects_table import ObjectRow


def test_summary_counts_tracks_without_height_apart_and_flags_uncalibrated_runs():
    summary = RunSummary(source="clip.mp4", frames=10, wall_s=2.0, camera_source="none")
    for track_id, cls, height, std in ((1, "person", 1.70, 0.05), (2, "person", 1.80, 0.05),
                                       (3, "person", math.nan, math.inf), (4, "vehicle", math.nan, math.inf)):
        summary.objects.rows[track_id] = ObjectRow(track_id, cls, height, std, "network", 0.0, 1.0)
    text = format_summary(summary)
    assert "processed 10 frames of clip.mp4 in 2.0 s (5.0 frames/s)" in text
    assert "person 3 (median 1.75 m, 1 without a height)" in text
    assert "vehicle 1 (no height: tops outside the frame)" in text
    assert "UNCALIBRATED" in text and "nan" not in text


def test_summary_says_when_a_run_was_stopped():
    summary = RunSummary(source="cam", frames=4, wall_s=1.0, interrupted="SIGTERM", camera_source="calibration")
    text = format_summary(summary)
    assert "stopped by SIGTERM: the outputs hold the 4 frames processed" in text
    assert "tracks: none confirmed" in text


def test_summary_says_how_a_live_run_kept_up():
    summary = RunSummary(source="cam", frames=100, wall_s=4.0, camera_source="calibration",
                         reused_network_frames=12, dropped_frames=3)
    text = format_summary(summary)
    assert "12 frames given the previous frame's network outputs" in text
    assert "no heights measured on them" in text
    assert "3 frames dropped while the pipeline was busy" in text
    quiet = format_summary(RunSummary(source="cam", frames=100, wall_s=4.0, camera_source="calibration"))
    assert "live source" not in quiet


def test_a_stage_skipped_on_some_frames_is_timed_over_the_frames_it_ran_on():
    summary = RunSummary(source="cam", frames=100, wall_s=4.0, camera_source="calibration",
                         reused_network_frames=20)
    summary.stage_ms.update(ground=1600.0, tracking=200.0)  # the network on 80 frames, 20 ms each
    summary.stage_frames.update(ground=80, tracking=100)
    assert summary.ms_per_frame() == {"ground": 20.0, "tracking": 2.0}
    assert summary.total_ms_per_frame() == 18.0
    line = next(line for line in format_summary(summary).splitlines() if line.startswith("  ms per frame"))
    assert "over the frames it ran on" in line and "ground 20.0, tracking 2.0" in line


def test_summary_says_which_camera_a_v2_network_decoded_with():
    from core.packets import HeightCamera

    heads = HeightCamera("heads", 6.0, 18.24, 0.31, 512.0, pitch_std_deg=1.12, roll_std_deg=0.5,
                         focal_std_pct=6.2, frames=120)
    text = format_summary(RunSummary(source="cam", frames=120, wall_s=1.0, camera_source="camera-height",
                                     height_camera=heads))
    camera_line = next(line for line in text.splitlines() if line.startswith("  camera:"))
    assert "camera height given" in camera_line and "camera heads" in camera_line
    assert "pitch 18.2° ±1.1°" in camera_line and "focal 512 px ±6%" in camera_line
    assert "mean of 120 frames" in camera_line
    hint = next(line for line in text.splitlines() if line.startswith("  hint:"))
    assert "network's guess" in hint and "heightpipe calibrate SOURCE --camera-height H" in hint
    given = HeightCamera("calibration", 7.84, 23.5, 0.4, 1800.0)
    text = format_summary(RunSummary(source="cam", camera_source="calibration", height_camera=given))
    assert "with the calibration file's camera (height 7.84 m, pitch 23.5°" in text and "±" not in text
    assert "hint" not in text


def test_a_v1_run_told_only_the_camera_height_is_pointed_to_v2():
    """v2's camera heads were built for that case: the summary says how to use them."""
    text = format_summary(RunSummary(source="cam", camera_source="camera-height"))
    hint = next(line for line in text.splitlines() if line.startswith("  hint:"))
    assert "--set height.model=v2 --set objects.source=network" in hint
    for source in ("calibration", "self", "none"):
        assert "hint" not in format_summary(RunSummary(source="cam", camera_source=source))


def test_a_run_posed_from_its_first_frames_says_what_it_read():
    from core.packets import HeightCamera

    read = HeightCamera("heads", 7.84, 20.54, 1.31, 1379.0, pitch_std_deg=1.3, roll_std_deg=0.58,
                        focal_std_pct=7.0, frames=30, edges=55)
    text = format_summary(RunSummary(source="cam", camera_source="self", scene_camera=read))
    assert "  camera: self-calibrated" in text
    line = next(line for line in text.splitlines() if line.startswith("  camera read from"))
    assert "30 early frames: height 7.84 m given" in line and "55 straight lines of the scene" in line
    assert "pitch 20.5° ±1.3°, roll 1.3° ±0.6°, focal 1379 px ±7%" in line
    assert "hint" not in text
    assert "right angles" not in text


def test_a_camera_read_assuming_square_ground_lines_says_so():
    """Two families taken to cross at right angles is an assumption the scene may break."""
    from dataclasses import replace

    from core.packets import HeightCamera

    read = HeightCamera("heads", 6.4, 32.0, 1.5, 552.0, frames=30, edges=48, square_families=True)
    text = format_summary(RunSummary(source="cam", camera_source="self", scene_camera=read))
    assert "48 straight lines of the scene (two families of ground lines taken to cross at right angles)" in text
    plain = format_summary(RunSummary(source="cam", camera_source="self",
                                      scene_camera=replace(read, square_families=False)))
    assert "48 straight lines of the scene:" in plain and "right angles" not in plain
