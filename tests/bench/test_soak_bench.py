"""bench.soak_bench: one RSS reading per period of video, whatever the runner's callbacks repeat."""

from __future__ import annotations

from bench.soak_bench import RssReadings


def test_one_reading_per_period_none_before_the_first_frame_is_written():
    readings = RssReadings(fps=10.0, every_min=0.5)  # a reading every 300 frames
    # The runner reports frames written: 0 while the first frames are held back for backfilling,
    # and the same count again while a new track's frames are held.
    for frames in [0, 0, 0, *range(1, 300), 300, 300, 300, *range(301, 600), 600, 600, 601]:
        readings.on_frame(frames, None, max(frames, 1) / 40.0)
    assert [row[4] for row in readings.rows] == [300, 600]
    assert [row[0] for row in readings.rows] == [0.5, 1.0]
    assert readings.rows[0][2] == 40.0 and readings.rows[0][3] > 0   # frames/s so far, RSS MB
