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
