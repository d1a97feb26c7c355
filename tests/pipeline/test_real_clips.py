"""`heightpipe run` on the real footage in ../shared/real, checked the way a user would."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from media import REPO_ROOT, SHARED_REAL, rrd_rows
from stages.objects_table import read_objects_csv
from stages.heightnet_model import SHIPPED_MODEL

TRAFFIC = SHARED_REAL / "traffic_bridge" / "car_traffic_small.mp4"


@pytest.mark.skipif(not TRAFFIC.exists(), reason="shared real clips not present")
@pytest.mark.skipif(not SHIPPED_MODEL.exists(), reason="no shipped model")
def test_traffic_clip_all_frames_and_outputs_read_back(tmp_path):
    """Also a height rule with a threshold: vehicles reading 2.0 m or more for 3 frames."""
    from mcap.reader import make_reader

    prefix = tmp_path / "traffic"
    rules = tmp_path / "rules.toml"
    rules.write_text('[[rules]]\nname = "over_2m"\nclass = "vehicle"\nmin_height_m = 2.0\nmin_frames = 3\n')
    result = subprocess.run([sys.executable, "-m", "pipeline.cli", "run", str(TRAFFIC), "--out", str(prefix),
                             "--config", str(rules), "--no-progress"],
                            cwd=REPO_ROOT, capture_output=True, text=True, timeout=900)
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

    events = [json.loads(line) for line in open(f"{prefix}.events.jsonl")]
    assert events, "tall vehicles pass on this clip"
    assert all(e["class"] == "vehicle" and e["height_m"] >= 2.0 and e["rule"] == "over_2m" for e in events)
    assert len({e["track_id"] for e in events}) == len(events), "once per track (no cooldown set)"
    assert counts["/events"] == len(events)
    assert f"events: {len(events)} height-rule firings" in result.stderr
    fired = {row.track_id for row in read_objects_csv(Path(f"{prefix}.objects.csv")) if row.rules_fired == ["over_2m"]}
    assert fired == {e["track_id"] for e in events}
    assert len(rrd_rows(Path(f"{prefix}.rrd"))["/events"]) == len(events)
