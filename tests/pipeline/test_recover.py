"""`heightpipe recover`: valid MCAP, .rrd and CSV back from what a killed run left."""

from __future__ import annotations

import csv
import subprocess
import sys
import time
from pathlib import Path

import pytest

from pipeline import cli
from pipeline.recover import ORIGINAL_SUFFIX, mcap_is_complete, rrd_is_complete

from media import REPO_ROOT, make_sink_packet, write_moving_box_video, write_unfinished_recording


def default_reader_images(path: Path) -> list[int]:
    """Log times of /camera/image as the mcap library's default (indexed, log-time order) reader sees them."""
    from mcap.reader import make_reader

    with open(path, "rb") as stream:
        return [message.log_time for _, _, message in make_reader(stream).iter_messages(topics=["/camera/image"])]


def test_recover_unfinished_mcap_keeps_every_complete_chunk(tmp_path, capsys):
    path = tmp_path / "run.mcap"
    cut = write_unfinished_recording(path)  # 3.5 s at 10 fps: chunks closed at 1, 2 and 3 s
    assert not mcap_is_complete(path)

    assert cli.main(["recover", str(path)]) == 0
    err = capsys.readouterr().err
    frames = int(err.split("recovered ")[1].split(" frames")[0])
    assert 10 <= frames < 35 and ("unfinished chunk" in err or "cut off" in err)
    assert mcap_is_complete(path)
    assert len(default_reader_images(path)) == frames
    assert (tmp_path / f"run.mcap{ORIGINAL_SUFFIX}").read_bytes() == cut
    # replay reads the unfinished original through the same reader: the same frames
    assert cli.main(["replay", str(tmp_path / f"run.mcap{ORIGINAL_SUFFIX}"), "--save", str(tmp_path / "r.rrd")]) == 0
    assert f"replayed {frames} frames" in capsys.readouterr().err
    # a second recover leaves the now valid file alone
    assert cli.main(["recover", str(path)]) == 0
    assert f"complete, {frames} frames; nothing to recover" in capsys.readouterr().err


def test_recover_adds_the_index_to_a_live_streams_rrd(tmp_path, capsys):
    """A live stream's .rrd is written without rerun's index (output.rrd_index = "auto"); the
    README says `heightpipe recover` adds it afterwards."""
    from core.config import OutputConfig
    from stages.rerun_sink import RerunSink

    path = tmp_path / "cam.rrd"
    sink = RerunSink(path, "save", OutputConfig(), "cam", live=True)
    for index in range(6):
        sink.write(make_sink_packet(index))
    sink.close()
    assert not rrd_is_complete(path)

    assert cli.main(["recover", str(path)]) == 0
    assert "recovered 6 frames" in capsys.readouterr().err
    assert rrd_is_complete(path)


def test_csv_row_cut_mid_write_is_dropped(tmp_path, capsys):
    path = tmp_path / "run.tracks.csv"
    path.write_text("frame,time_s\n0,0.0\n1,0.1\n2,0.")
    assert cli.main(["recover", str(path)]) == 0
    assert path.read_text() == "frame,time_s\n0,0.0\n1,0.1\n"


@pytest.mark.parametrize("target, message", [
    ("nothing", "nothing to recover"),
    ("missing.mcap", "no such file"),
    ("garbage.mcap", "cannot recover"),
])
def test_unrecoverable_input_is_a_one_line_error(tmp_path, capsys, target, message):
    (tmp_path / "garbage.mcap").write_bytes(b"not an mcap file at all" * 10)
    assert cli.main(["recover", str(tmp_path / target)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("heightpipe: error: ") and message in err and "\n" not in err


def test_kill_9_then_recover_gives_files_every_reader_opens(tmp_path, tiny_model):
    """Must-show: after kill -9, recover; the MCAP opens with the default reader and holds every
    frame but the last second; the .rrd verifies."""
    video = write_moving_box_video(tmp_path / "long.mp4", frames=400, size=(160, 120))
    prefix = tmp_path / "long"
    process = subprocess.Popen(
        [sys.executable, "-m", "pipeline.cli", "run", str(video), "--out", str(prefix), "--no-progress",
         "--set", "output.flush_interval_s=0.5", "--set", f'height.model="{tiny_model}"'],
        cwd=REPO_ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    csv_path = Path(f"{prefix}.tracks.csv")
    deadline = time.monotonic() + 60
    while not (csv_path.exists() and len(csv_path.read_text().splitlines()) > 40):
        assert time.monotonic() < deadline and process.poll() is None, "the run produced no tracks in time"
        time.sleep(0.05)
    time.sleep(0.3)
    process.kill()
    process.communicate(timeout=30)
    mcap_path, rrd_path = Path(f"{prefix}.mcap"), Path(f"{prefix}.rrd")
    assert not mcap_is_complete(mcap_path) and not rrd_is_complete(rrd_path)
    try:  # what a user met before `recover` existed: nothing, or an error
        assert default_reader_images(mcap_path) == []
    except Exception as exc:  # noqa: BLE001 (whatever the reader raises on it)
        assert "RecordLengthLimitExceeded" in type(exc).__name__

    result = subprocess.run([sys.executable, "-m", "pipeline.cli", "recover", str(prefix)], cwd=REPO_ROOT,
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert "Traceback" not in result.stderr
    last_frame = max(int(row[0]) for row in list(csv.reader(open(csv_path)))[1:])
    images = default_reader_images(mcap_path)
    # 10 fps source, flush_interval_s = 0.5: at most half a second (+ the frame in flight) lost
    assert len(images) == len(set(images)) >= last_frame + 1 - 7
    assert f"recovered {len(images)} frames" in result.stderr
    assert rrd_is_complete(rrd_path)
    assert Path(f"{prefix}.mcap{ORIGINAL_SUFFIX}").exists() and Path(f"{prefix}.rrd{ORIGINAL_SUFFIX}").exists()
