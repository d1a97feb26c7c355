"""`heightpipe batch`: an archive of clips on the local pool and on Ray, resumed after kills."""

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from media import REPO_ROOT, default_sigint, make_tiny_height_model, write_moving_box_video

from core.config import Config

CLIP_FRAMES = [20, 25, 30, 35, 40, 45]
LONG_CLIPS = 5


def heightpipe(*args, timeout=180):
    return subprocess.run([sys.executable, "-m", "pipeline.cli", *map(str, args)], cwd=REPO_ROOT,
                          capture_output=True, text=True, timeout=timeout)


def manifest(out_dir: Path) -> dict:
    return json.loads((out_dir / "manifest.json").read_text())["inputs"]


def report_value(stderr: str, name: str) -> str:
    """A row of the final table, e.g. report_value(stderr, 'done') -> '4'."""
    line = next(line for line in stderr.splitlines() if line.strip().startswith(name + " "))
    return line.split(None, 1)[1]


def read_csv(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


@pytest.fixture(scope="module")
def model(tmp_path_factory) -> Path:
    return make_tiny_height_model(tmp_path_factory.mktemp("model") / "tiny.onnx")


@pytest.fixture(scope="module")
def archive(tmp_path_factory) -> Path:
    """Six short clips of a box crossing the view (two share the stem 'clip0' in different folders)
    and a corrupt file. The box is what the tiny model sees as an object."""
    root = tmp_path_factory.mktemp("archive")
    for i, frames in enumerate(CLIP_FRAMES):
        folder = root / ("cam_a" if i < 3 else "cam_b")
        folder.mkdir(exist_ok=True)
        write_moving_box_video(folder / f"clip{i % 3}.mp4", frames=frames, fps=15.0)
    (root / "cam_b" / "broken.mp4").write_text("not a video\n" * 50)
    (root / "cam_b" / "notes.txt").write_text("a folder's non-video files are not inputs\n")
    return root


@pytest.fixture(scope="module")
def local_batch(archive, model, tmp_path_factory):
    out = tmp_path_factory.mktemp("local") / "out"
    result = heightpipe("batch", archive, "--out", out, "--workers", 2, "--no-progress",
                        "--set", f'height.model="{model}"')
    return out, result


def test_local_batch_processes_every_clip_and_reports_the_corrupt_one(local_batch, archive, model):
    out, result = local_batch
    assert result.returncode == 1, result.stderr  # 1: an input failed
    assert "Traceback" not in result.stderr
    entries = manifest(out)
    assert len(entries) == 7
    broken = entries[str(archive / "cam_b" / "broken.mp4")]
    assert broken["status"] == "failed" and "not a readable video" in broken["error"]
    assert "broken.mp4: " in result.stderr and report_value(result.stderr, "failed") == "1"
    done = {source: e for source, e in entries.items() if e["status"] == "done"}
    assert len(done) == 6 and report_value(result.stderr, "done") == "6"
    assert len({e["output_name"] for e in done.values()}) == 6, "clip0.mp4 twice must not collide"
    for source, entry in done.items():
        assert entry["frames"] == CLIP_FRAMES[["cam_a", "cam_b"].index(Path(source).parent.name) * 3
                                              + int(Path(source).stem[-1])]
        assert entry["duration_s"] == pytest.approx(entry["frames"] / 15.0)  # clips are 15 fps
        assert sorted(Path(name).name.split(".", 1)[1] for name in entry["outputs"]) == ["mcap", "objects.csv", "rrd",
                                                                                            "tracks.csv"]
        assert all((out / name).stat().st_size > 0 for name in entry["outputs"])
    assert not list((out / ".partial").iterdir())


def test_each_video_gets_exactly_what_heightpipe_run_writes(local_batch, archive, model, tmp_path):
    from core.config import Config
    from pipeline.runner import run_pipeline

    out, _ = local_batch
    source = archive / "cam_a" / "clip2.mp4"
    config = Config()
    config.height.model, config.height.threads, config.output.progress = str(model), 1, False
    run_pipeline(str(source), config, tmp_path / "direct")
    entry = manifest(out)[str(source)]
    for suffix in (".tracks.csv", ".objects.csv"):
        batch_csv = out / "videos" / f"{entry['output_name']}{suffix}"
        assert batch_csv.read_bytes() == (tmp_path / f"direct{suffix}").read_bytes()


def _values(row: dict) -> dict:
    """A table row's values, numbers as numbers (the archive and objects.csv format them apart)."""
    def value(text: str):
        try:
            return float(text)
        except ValueError:
            return text
    return {k: value(v) for k, v in row.items() if k not in ("source", "video")}


def test_archive_tables_hold_every_track_and_every_video(local_batch):
    out, _ = local_batch
    videos = read_csv(out / "videos.csv")
    assert sorted(v["status"] for v in videos) == ["done"] * 6 + ["failed"]
    tracks = read_csv(out / "tracks.csv")
    assert list(tracks[0]) == ["source", "video", "track_id", "class", "height_m", "height_std_m",
                               "height_source", "first_time_s", "last_time_s", "frames_seen", "frames_measured",
                               "ground_x_m", "ground_y_m", "rules_fired"]
    for entry in (e for e in manifest(out).values() if e["status"] == "done"):
        per_frame = read_csv(out / "videos" / f"{entry['output_name']}.tracks.csv")
        mine = [t for t in tracks if t["video"] == entry["output_name"]]
        objects = read_csv(out / "videos" / f"{entry['output_name']}.objects.csv")
        assert [_values(t) for t in mine] == [_values(o) for o in objects], \
            "the archive table is the videos' objects.csv rows"
        assert {int(t["track_id"]) for t in mine} == {int(r["track_id"]) for r in per_frame}
        assert len(mine) >= 1, "every clip has a moving box"
        for track in mine:
            rows = [r for r in per_frame if r["track_id"] == track["track_id"]]
            assert int(track["frames_seen"]) == len(rows)
            # NaN where no frame gave a height (e.g. an object only ever seen cut by the frame's edge).
            assert np.array_equal(float(track["height_m"] or "nan"), float(rows[-1]["height_m"]), equal_nan=True)
            assert track["height_source"] == rows[-1]["height_source"]
            assert float(track["first_time_s"]) == min(float(r["time_s"]) for r in rows)
            assert float(track["last_time_s"]) == max(float(r["time_s"]) for r in rows)
    try:
        import pyarrow.parquet as pq
    except ImportError:
        assert not (out / "tracks.parquet").exists()
    else:
        assert pq.read_table(out / "tracks.parquet").num_rows == len(tracks)


def test_second_run_skips_everything(local_batch, archive, model):
    out, _ = local_batch
    before = manifest(out)
    mtimes = {name: (out / name).stat().st_mtime_ns for e in before.values() for name in e["outputs"]}
    result = heightpipe("batch", archive, "--out", out, "--no-progress", "--set", f'height.model="{model}"')
    assert result.returncode == 1, result.stderr  # the corrupt file is still failed
    assert report_value(result.stderr, "done") == "0"
    assert report_value(result.stderr, "skipped").startswith("7 ")
    assert manifest(out) == before
    assert {name: (out / name).stat().st_mtime_ns for name in mtimes} == mtimes


def _without_timestamps(message):
    for descriptor, value in list(message.ListFields()):
        if descriptor.message_type is None:
            continue
        if descriptor.message_type.full_name == "google.protobuf.Timestamp":
            message.ClearField(descriptor.name)
        elif descriptor.is_repeated:
            for item in value:
                _without_timestamps(item)
        else:
            _without_timestamps(value)
    return message


def _mcap_messages(path: Path) -> list[tuple[str, int, bytes]]:
    """(topic, time since the recording's start, message without its time stamps).

    MCAP log times and stamps are the wall-clock start of the run plus the frame's source time.
    """
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    with open(path, "rb") as f:
        start = int(next(make_reader(f).iter_metadata()).metadata["start_epoch_ns"])
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        return [(channel.topic, message.log_time - start,
                 _without_timestamps(decoded).SerializeToString(deterministic=True))
                for _, channel, message, decoded in reader.iter_decoded_messages()]


def test_ray_engine_writes_the_same_per_video_outputs(local_batch, archive, model, tmp_path):
    pytest.importorskip("ray")
    local_out, _ = local_batch
    out = tmp_path / "ray"
    result = heightpipe("batch", archive, "--out", out, "--engine", "ray", "--workers", 2, "--no-progress",
                        "--set", f'height.model="{model}"')
    assert result.returncode == 1, result.stderr
    assert "(ray engine, 2 workers" in result.stderr
    ray_entries, local_entries = manifest(out), manifest(local_out)
    assert {s: e["status"] for s, e in ray_entries.items()} == {s: e["status"] for s, e in local_entries.items()}
    assert ray_entries[str(archive / "cam_b" / "broken.mp4")]["error"] == \
        local_entries[str(archive / "cam_b" / "broken.mp4")]["error"]
    for source, entry in ray_entries.items():
        assert entry["engine"] == "ray"
        assert entry["outputs"] == local_entries[source]["outputs"]
        for name in entry["outputs"]:
            if name.endswith(".tracks.csv"):
                assert (out / name).read_bytes() == (local_out / name).read_bytes()
            elif name.endswith(".mcap"):
                assert _mcap_messages(out / name) == _mcap_messages(local_out / name)
    assert (out / "tracks.csv").read_bytes() == (local_out / "tracks.csv").read_bytes()


@pytest.fixture(scope="module")
def long_archive(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("long")
    for i in range(LONG_CLIPS):
        write_moving_box_video(root / f"long{i}.mp4", frames=60)
    return root


def _children(pid: int) -> list[int]:
    children = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            children.append(int(stat.parent.name))
    return children


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGKILL])
def test_killed_half_way_then_resumed_without_redoing_finished_videos(long_archive, model, tmp_path, sig):
    out = tmp_path / "out"
    args = [sys.executable, "-m", "pipeline.cli", "batch", str(long_archive), "--out", str(out), "--workers", "2",
            "--no-progress", "--set", f'height.model="{model}"']
    process = subprocess.Popen(args, cwd=REPO_ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               preexec_fn=default_sigint)
    deadline = time.monotonic() + 90
    while time.monotonic() < deadline and process.poll() is None:
        if (out / "manifest.json").exists() and any(e["status"] == "done" for e in manifest(out).values()):
            break
        time.sleep(0.02)
    workers = _children(process.pid)
    process.send_signal(sig)
    _, stderr = process.communicate(timeout=60)
    if sig == signal.SIGINT:
        assert process.returncode == 130, stderr
        assert "STOPPED" in stderr and "Traceback" not in stderr, stderr
    else:
        deadline = time.monotonic() + 20  # the workers die with their parent (PR_SET_PDEATHSIG)
        while any(Path(f"/proc/{pid}").exists() for pid in workers) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not any(Path(f"/proc/{pid}").exists() for pid in workers), "orphaned workers"
    first = manifest(out)
    finished = {source: entry for source, entry in first.items() if entry["status"] == "done"}
    assert 1 <= len(finished) < LONG_CLIPS, "the kill must land half-way"
    mtimes = {name: (out / name).stat().st_mtime_ns for e in finished.values() for name in e["outputs"]}

    result = heightpipe("batch", long_archive, "--out", out, "--workers", 2, "--no-progress",
                        "--set", f'height.model="{model}"')
    assert result.returncode == 0, result.stderr
    assert report_value(result.stderr, "done") == str(LONG_CLIPS - len(finished))
    assert report_value(result.stderr, "skipped").startswith(f"{len(finished)} ")
    second = manifest(out)
    assert all(entry["status"] == "done" for entry in second.values()) and len(second) == LONG_CLIPS
    assert all(second[source] == entry for source, entry in finished.items())
    assert {name: (out / name).stat().st_mtime_ns for name in mtimes} == mtimes
    assert not list((out / ".partial").iterdir())
    assert len(read_csv(out / "videos.csv")) == LONG_CLIPS


def test_changed_file_is_redone_and_others_skipped(tmp_path, model):
    from pipeline.batch import BatchOptions, run_batch
    from core.config import Config

    config = Config()
    config.height.model = str(model)
    (tmp_path / "in").mkdir()
    for name in ("a.mp4", "b.mp4"):
        write_moving_box_video(tmp_path / "in" / name, frames=12)
    options = BatchOptions(out_dir=tmp_path / "out", workers=1, progress=False)
    first = run_batch([str(tmp_path / "in")], config, options)
    assert (first.done, first.skipped) == (2, 0)
    write_moving_box_video(tmp_path / "in" / "b.mp4", frames=15)
    second = run_batch([str(tmp_path / "in")], config, options)
    assert (second.done, second.skipped) == (1, 1)
    assert manifest(tmp_path / "out")[str(tmp_path / "in" / "b.mp4")]["frames"] == 15


def test_what_a_rerun_redoes(tmp_path):
    from pipeline.batch_manifest import DONE, FAILED, InputIdentity, Manifest, ManifestEntry, config_fingerprint
    from core.config import Config

    identity = InputIdentity(100, 5, "abc")
    fingerprint = config_fingerprint(Config())
    (tmp_path / "videos").mkdir()
    (tmp_path / "videos" / "a-1.mcap").write_bytes(b"x")
    manifest = Manifest(tmp_path / "manifest.json", {
        "/a.mp4": ManifestEntry("/a.mp4", "a-1", identity, fingerprint, DONE, outputs=["videos/a-1.mcap"]),
        "/b.mp4": ManifestEntry("/b.mp4", "b-1", identity, fingerprint, FAILED, error="broken"),
    })
    manifest.save()
    manifest = Manifest.load(tmp_path)

    def reason(key, ident=identity, fp=fingerprint, force=False, retry_failed=False):
        return manifest.reason_to_run(key, ident, fp, tmp_path, force, retry_failed)

    assert reason("/a.mp4") is None
    assert reason("/a.mp4", force=True) == "forced"
    assert reason("/new.mp4") == "new"
    assert reason("/a.mp4", ident=InputIdentity(100, 6, "abc")) == "file changed"
    assert reason("/a.mp4", ident=InputIdentity(100, 5, "abd")) == "file changed"
    changed = Config()
    changed.tracking.min_hits = 4
    assert reason("/a.mp4", fp=config_fingerprint(changed)) == "config changed"
    changed = Config()
    changed.objects.min_area_px = 80
    assert reason("/a.mp4", fp=config_fingerprint(changed)) == "config changed"
    threads_only = Config()
    threads_only.height.threads, threads_only.output.progress = 1, False
    assert reason("/a.mp4", fp=config_fingerprint(threads_only)) is None
    wider = Config()
    wider.height.input_width = 640
    assert reason("/a.mp4", fp=config_fingerprint(wider)) == "config changed"
    mirrored = Config()
    mirrored.height.mirror = True
    assert reason("/a.mp4", fp=config_fingerprint(mirrored)) == "config changed"
    # Network-mode keys are not read in blobs mode (archives made before they existed stay done) ...
    blobs = Config()
    blobs.objects.score_person, blobs.objects.keep_motion_blobs = 0.9, True
    assert reason("/a.mp4", fp=config_fingerprint(blobs)) is None
    # ... and in network mode they count.
    network = Config()
    network.objects.source = "network"
    assert reason("/a.mp4", fp=config_fingerprint(network)) == "config changed"
    stricter = Config()
    stricter.objects.source, stricter.objects.score_person = "network", 0.9
    assert config_fingerprint(stricter) != config_fingerprint(network)
    # The scene-reading keys count only for a camera told just its height; a pose's spread counts.
    not_read = Config()
    not_read.camera.read_scene_frames = 0
    assert reason("/a.mp4", fp=config_fingerprint(not_read)) is None
    told = Config()
    told.camera.height_m = 6.0
    told_not_read = Config()
    told_not_read.camera.height_m, told_not_read.camera.read_scene_frames = 6.0, 0
    assert config_fingerprint(told) != config_fingerprint(told_not_read)
    from media import write_lens_calibration

    lens = write_lens_calibration(tmp_path / "lens.json")
    lens_told, lens_not_read = Config(), Config()
    lens_told.camera.height_m, lens_told.camera.calibration = 6.0, str(lens)
    lens_not_read.camera.height_m, lens_not_read.camera.calibration = 6.0, str(lens)
    lens_not_read.camera.read_scene_frames = 0
    assert config_fingerprint(lens_told) != config_fingerprint(lens_not_read)   # a lens alone: read too
    spread = Config()
    spread.camera.pitch_std_deg = 1.2
    assert reason("/a.mp4", fp=config_fingerprint(spread)) == "config changed"
    assert reason("/b.mp4") is None and reason("/b.mp4", retry_failed=True) == "retry failed"
    (tmp_path / "videos" / "a-1.mcap").unlink()
    assert reason("/a.mp4").startswith("output missing")


class KillsItsWorker(Config):
    """A config whose copy SIGKILLs the process making it: a worker dying mid-video."""

    def __deepcopy__(self, memo):
        os.kill(os.getpid(), signal.SIGKILL)


def test_a_worker_that_dies_fails_only_its_video(tmp_path, model):
    from pipeline.batch_engines import LocalEngine, VideoTask

    config = Config()
    config.height.model, config.output.progress = str(model), False
    crash = KillsItsWorker()
    crash.height.model = str(model)
    clips = [write_moving_box_video(tmp_path / f"{name}.mp4", frames=8) for name in ("crash", "fine")]
    tasks = [VideoTask(str(clips[0]), "crash", tmp_path, crash, 1),
             VideoTask(str(clips[1]), "fine", tmp_path, config, 1)]
    results = []
    LocalEngine(workers=1).run(tasks, lambda status: None, results.append)
    by_source = {Path(r.source).stem: r for r in results}
    assert by_source["crash"].status == "failed"
    assert "worker process died (killed by SIGKILL" in by_source["crash"].error
    assert by_source["fine"].status == "done" and by_source["fine"].frames == 8


def test_output_names_are_unique_and_stable():
    from pipeline.batch import output_name

    a, b = Path("/archive/cam1/08-00.mp4"), Path("/archive/cam2/08-00.mp4")
    assert output_name(a) != output_name(b)
    assert output_name(a) == output_name(Path("/archive/cam1/08-00.mp4"))
    assert output_name(Path("/x/a b?.mp4")).startswith("a_b_-")


def assert_clean_error(argv, message, capsys):
    from pipeline.cli import main

    assert main(argv) == 2
    error = capsys.readouterr().err
    lines = [line for line in error.splitlines() if line.startswith("heightpipe: error:")]
    assert len(lines) == 1 and message in lines[0], error


def test_no_inputs_found(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    assert_clean_error(["batch", str(tmp_path / "empty"), "--out", str(tmp_path / "o")], "no videos found", capsys)
    assert_clean_error(["batch", str(tmp_path / "none.mp4"), "--out", str(tmp_path / "o")],
                       "no such file or folder", capsys)


def test_out_dir_that_is_a_file(tmp_path, capsys):
    clip = write_moving_box_video(tmp_path / "c.mp4", frames=3)
    (tmp_path / "file").write_text("x")
    assert_clean_error(["batch", str(clip), "--out", str(tmp_path / "file")], "is a file, not a folder", capsys)


def test_unknown_engine_or_missing_ray(tmp_path, capsys, monkeypatch):
    import pipeline.batch_engines

    clip = write_moving_box_video(tmp_path / "c.mp4", frames=3)
    assert_clean_error(["batch", str(clip), "--out", str(tmp_path / "o"), "--engine", "spark"],
                       "unknown engine 'spark'", capsys)
    monkeypatch.setattr(pipeline.batch_engines, "ray_available", lambda: False)
    assert_clean_error(["batch", str(clip), "--out", str(tmp_path / "o"), "--engine", "ray"],
                       "--engine ray needs Ray: pip install 'heightpipe[ray]'", capsys)
    assert not (tmp_path / "o").exists(), "a refused batch leaves no folder behind"


def test_unreadable_manifest(tmp_path, capsys):
    clip = write_moving_box_video(tmp_path / "c.mp4", frames=3)
    (tmp_path / "o").mkdir()
    (tmp_path / "o" / "manifest.json").write_text("{ half a manifest")
    assert_clean_error(["batch", str(clip), "--out", str(tmp_path / "o")], "not a heightpipe batch manifest", capsys)


def test_second_batch_on_the_same_folder_is_refused(tmp_path, capsys):
    import fcntl

    clip = write_moving_box_video(tmp_path / "c.mp4", frames=3)
    (tmp_path / "o").mkdir()
    with open(tmp_path / "o" / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        assert_clean_error(["batch", str(clip), "--out", str(tmp_path / "o")], "in use by another heightpipe batch",
                           capsys)
    assert os.path.exists(tmp_path / "o" / ".lock")


def test_a_named_model_s_file_is_part_of_the_fingerprint(tmp_path, monkeypatch):
    """height.model = "v2" names a shipped file: a new export there redoes the archive."""
    import os

    import stages.heightnet_model as models
    from core.config import Config
    from pipeline.batch_manifest import config_fingerprint

    export = tmp_path / "heightnet_v2.onnx"
    export.write_bytes(b"first export")
    monkeypatch.setitem(models.NAMED_MODELS, "v2", export)
    config = Config()
    config.height.model = "v2"
    before = config_fingerprint(config)
    export.write_bytes(b"a later export")
    os.utime(export, ns=(export.stat().st_atime_ns, export.stat().st_mtime_ns + 10**9))
    assert config_fingerprint(config) != before
