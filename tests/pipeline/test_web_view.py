"""`--rerun web`: rerun's web viewer served from the run, and seen in a real (headless) browser."""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
import time
import urllib.request

import pytest

from bench.live_view import MIN_BOX_PIXELS, box_pixels, browser_available, free_port, watch_live_run
from media import REPO_ROOT, SHARED_REAL, default_sigint

TRAFFIC = SHARED_REAL / "traffic_bridge" / "car_traffic_small.mp4"


def web_flags(web_port: int, grpc_port: int) -> list[str]:
    return ["--set", f"web.web_port={web_port}", "--set", f"web.grpc_port={grpc_port}"]


def test_a_taken_port_is_a_one_line_error(tmp_path, box_video, tiny_model):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        result = subprocess.run(
            [sys.executable, "-m", "pipeline.cli", "run", str(box_video), "--out", str(tmp_path / "x"),
             "--rerun", "web", "--no-progress", "--set", f'height.model="{tiny_model}"',
             *web_flags(port, free_port())], cwd=REPO_ROOT, capture_output=True, text=True, timeout=120)
    assert result.returncode == 2 and "Traceback" not in result.stderr, result.stderr
    (line,) = [line for line in result.stderr.splitlines() if line.startswith("heightpipe:")]
    assert f"127.0.0.1:{port} (web.web_port) is taken" in line and "--set web.web_port=PORT" in line
    assert not (tmp_path / "x.rrd").exists(), "nothing is processed when the view cannot be served"


def test_web_mode_serves_the_viewer_writes_the_file_and_stops_on_ctrl_c(tmp_path, box_video, tiny_model):
    web_port, grpc_port = free_port(), free_port()
    run = subprocess.Popen(
        [sys.executable, "-m", "pipeline.cli", "run", str(box_video), "--out", str(tmp_path / "box"),
         "--rerun", "web", "--no-progress", "--set", f'height.model="{tiny_model}"',
         *web_flags(web_port, grpc_port)],
        cwd=REPO_ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, preexec_fn=default_sigint)
    try:
        lines = []
        for line in run.stdout:
            lines.append(line)
            if "still serving" in line:  # the run is done; the viewer stays up until Ctrl-C
                break
        text = "".join(lines)
        assert f"watch the run at http://127.0.0.1:{web_port}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{grpc_port}" \
               "%2Fproxy" in text, text
        assert "processed 30 frames" in text
        page = urllib.request.urlopen(f"http://127.0.0.1:{web_port}/", timeout=30).read().decode()
        assert "<html" in page.lower()
        run.send_signal(signal.SIGINT)
        assert run.wait(timeout=60) == 0
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
    assert (tmp_path / "box.rrd").stat().st_size > 0
    time.sleep(0.5)
    for port in (web_port, grpc_port):
        with socket.socket() as probe:
            assert probe.connect_ex(("127.0.0.1", port)) != 0, f"the server on {port} must end with the run"


def test_box_pixels_counts_box_colours_in_the_frame_panel():
    import numpy as np

    from stages.sink_common import QUALITY_RGB

    shot = np.zeros((900, 1400, 3), np.uint8)
    assert box_pixels(shot) == 0
    shot[200:260, 100:103] = QUALITY_RGB["settling"]  # a box's left edge inside the frame panel
    shot[700:760, 1300:1303] = QUALITY_RGB["settled"]  # outside it: not counted
    assert box_pixels(shot) == 180


@pytest.mark.skipif(browser_available() is not None, reason=str(browser_available()))
@pytest.mark.skipif(not TRAFFIC.exists(), reason="shared real clips not present")
def test_headless_chromium_shows_the_frame_with_boxes_during_a_run(tmp_path):
    """The viewer compiles and renders in software (SwiftShader): slow on a loaded machine."""
    result = watch_live_run(TRAFFIC, tmp_path / "traffic", timeout_s=900)
    assert result.url, result.run_output
    assert result.seconds_to_view is not None, \
        f"no boxes in the frame panel ({result.box_pixels} px of box colours): {result.run_output[-2000:]}"
    assert result.box_pixels >= MIN_BOX_PIXELS
    assert result.run_alive, "the screenshot was taken while the run was still processing frames"
