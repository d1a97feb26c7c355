"""bench.pipeline_bench's CPU clock: CPU per frame over the frames after the first."""

import math

import pytest

from bench.pipeline_bench import CpuClock


def test_cpu_per_frame_counts_from_the_first_processed_frame_not_from_start_up():
    readings = iter([10.0, 10.03, 10.05, 10.09])       # CPU seconds at each frame's callback
    cpu = CpuClock(clock=lambda: next(readings))
    for frame in range(4):
        cpu.on_frame(frame, 4, 0.0)
    assert math.isclose(cpu.ms_per_frame(), 30.0)        # 90 ms over the three frames after the first


def test_fewer_than_two_frames_give_no_number():
    cpu = CpuClock(clock=lambda: 1.0)
    assert math.isnan(cpu.ms_per_frame())
    cpu.on_frame(0, 1, 0.0)
    assert math.isnan(cpu.ms_per_frame())


def test_a_run_that_cannot_start_is_one_line_not_a_traceback(tmp_path):
    """A v2 model needs a camera: without one the bench says so in one line (``--set`` gives it)."""
    from bench.pipeline_bench import REPO_ROOT, main

    with pytest.raises(SystemExit) as stop:
        main([str(REPO_ROOT / "recordings" / "sample.mp4"), "--frames", "2", "--set", "height.model=v2"])
    message = str(stop.value.code)
    assert message.startswith("pipeline_bench: ") and "camera" in message and "\n" not in message
    with pytest.raises(SystemExit, match="pipeline_bench: .*no_such"):
        main(["--frames", "2", "--set", "no_such.key=1"])


def test_a_source_opencv_cannot_decode_as_one_video_gets_the_table_without_a_decode_rate(tmp_path, capsys):
    """An image folder runs through the pipeline's own capture; OpenCV's decode-only loop reads
    none of it, so the table says the rate was not measured instead of dividing by zero."""
    import cv2
    import numpy as np

    from bench.pipeline_bench import main

    rng = np.random.default_rng(0)
    for index in range(3):
        cv2.imwrite(str(tmp_path / f"{index:03d}.png"), rng.integers(0, 255, (120, 160, 3), dtype=np.uint8))
    main([str(tmp_path), "--frames", "3"])
    table = capsys.readouterr().out
    assert "| OpenCV decode only | not measured" in table
    assert "| ratio run / decode | - |" in table
    assert "clip: " in table and "(3 frames)" in table
