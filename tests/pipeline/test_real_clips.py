"""`heightpipe run` on the real footage in ../shared/real, checked the way a user would."""

import subprocess
import sys

import pytest

from media import REPO_ROOT, SHARED_REAL
from stages.heightnet_model import SHIPPED_MODEL

TRAFFIC = SHARED_REAL / "traffic_bridge" / "car_traffic_small.mp4"


@pytest.mark.skipif(not TRAFFIC.exists(), reason="shared real clips not present")
@pytest.mark.skipif(not SHIPPED_MODEL.exists(), reason="no shipped model")
def test_traffic_clip_all_frames_and_outputs_read_back(tmp_path):
    from mcap.reader import make_reader

    prefix = tmp_path / "traffic"
    result = subprocess.run([sys.executable, "-m", "pipeline.cli", "run", str(TRAFFIC), "--out", str(prefix),
                             "--no-progress"], cwd=REPO_ROOT, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    assert "processed 917 frames" in result.stderr
    assert "917 frames decoded" in result.stderr
    assert "UNCALIBRATED" in result.stderr, "no calibration given: heights must be flagged"

    with open(f"{prefix}.mcap", "rb") as f:
        summary = make_reader(f).get_summary()
    counts = {summary.channels[cid].topic: n for cid, n in summary.statistics.channel_message_counts.items()}
    assert counts["/camera/image"] == 917
    # output.height_map_every = 5: maps of frames 0, 5, ..., 915
    assert counts["/camera/height"] == counts["/camera/ground"] == 184

    converted = subprocess.run(["rerun", "mcap", "convert", f"{prefix}.mcap", "-o", str(tmp_path / "conv.rrd")],
                               capture_output=True, text=True, timeout=300)
    assert converted.returncode == 0, converted.stderr
    assert (tmp_path / "conv.rrd").stat().st_size > 0

    verify = subprocess.run(["rerun", "rrd", "verify", f"{prefix}.rrd"], capture_output=True, text=True, timeout=300)
    assert verify.returncode == 0, verify.stderr
