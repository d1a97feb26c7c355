"""`heightpipe batch INPUTS... --out DIR`: an archive of videos, resumable, locally or on Ray.

One task per video (tracking is sequential within a video), each running ``run_pipeline``
exactly as `heightpipe run` does. DIR holds:

    manifest.json             what was done with each input (pipeline/batch_manifest.py)
    videos/<name>.rrd|.mcap|.tracks.csv|.objects.csv   each video's outputs, renamed in only when complete
    .partial/                 outputs of videos in progress; emptied at the start of a run
    tracks.csv, videos.csv    the whole archive: one row per track, one per video (+ .parquet)

A rerun skips every input whose file, config and outputs are unchanged; --force redoes all.
"""

from __future__ import annotations

import argparse
import dataclasses
import glob
import hashlib
import os
import shutil
import signal
import sys
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Iterator

from pipeline.batch_manifest import DONE, FAILED, INTERRUPTED
from pipeline.scene_camera import model_for
from core.config import Config

if TYPE_CHECKING:
    from pipeline.batch_engines import TaskResult, VideoTask, WorkerStatus
    from pipeline.batch_manifest import InputIdentity, Manifest

VIDEO_SUFFIXES = {".mp4", ".m4v", ".mov", ".avi", ".mkv", ".webm", ".mpg", ".mpeg", ".ts", ".mts",
                  ".m2ts", ".wmv", ".flv", ".3gp", ".dav", ".h264", ".h265", ".hevc"}
ENGINES = ("local", "ray")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("inputs", nargs="+", metavar="INPUT",
                        help="video files, folders (searched recursively for videos) or globs")
    parser.add_argument("--out", required=True, metavar="DIR",
                        help="batch folder: manifest, per-video outputs and the archive tables")
    parser.add_argument("--workers", type=int, metavar="N",
                        help="videos processed in parallel (default: batch.workers, 0 = one per core)")
    parser.add_argument("--engine", metavar="local|ray",
                        help="local process pool (default) or Ray (pip install 'heightpipe[ray]')")
    parser.add_argument("--address", metavar="ADDR",
                        help="Ray cluster to join (e.g. auto, ray://host:10001); default: start one here")
    parser.add_argument("--force", action="store_true", help="redo every input, finished or not")
    parser.add_argument("--retry-failed", action="store_true", help="retry inputs that failed before")
    parser.add_argument("--camera-height", type=float, metavar="M", help="camera height above the ground in metres")
    parser.add_argument("--calibration", metavar="JSON", help="OpenCV-convention calibration file")
    parser.add_argument("--max-frames", type=int, metavar="N", help="stop each video after N processed frames")
    parser.add_argument("--stride", type=int, metavar="N", help="process every Nth frame")
    parser.add_argument("--rerun", choices=["save", "off"], help="write the .rrd of each video (default: save)")
    parser.add_argument("--no-progress", action="store_true", help="no progress display, only the final table")


@dataclass
class BatchOptions:
    out_dir: Path
    engine: str = "local"
    workers: int = 0
    """0 = one per core (local), or every CPU of the cluster (Ray with an address)."""
    address: str | None = None
    force: bool = False
    retry_failed: bool = False
    progress: bool = True


@dataclass
class BatchReport:
    out_dir: Path
    engine: str
    workers: int
    threads: int
    inputs: int = 0
    queued: dict[str, int] = field(default_factory=dict)
    """Why inputs were (re)processed this run: 'new', 'file changed', 'config changed', ..."""
    done: int = 0
    skipped: int = 0
    failed: list[tuple[str, str]] = field(default_factory=list)
    """(source, error) of every input of this batch that is failed now, this run or earlier."""
    interrupted: int = 0
    frames: int = 0
    failed_frames: int = 0
    video_s: float = 0.0
    compute_s: float = 0.0
    wall_s: float = 0.0
    stopped: bool = False
    tables: list[Path] = field(default_factory=list)
    archive_tracks: int = 0
    archive_videos: int = 0


# --- inputs --------------------------------------------------------------------------------


def find_inputs(specs: list[str], out_dir: Path) -> list[Path]:
    """Files as given, folders searched recursively for video suffixes, globs expanded.

    Resolved, de-duplicated, sorted, and never anything inside DIR itself.
    """
    from core.errors import SourceError

    found: set[Path] = set()
    for spec in specs:
        path = Path(spec)
        if path.is_file():
            found.add(path.resolve())
        elif path.is_dir():
            found.update(p.resolve() for p in path.rglob("*") if p.suffix.lower() in VIDEO_SUFFIXES and p.is_file())
        elif any(c in spec for c in "*?["):
            found.update(Path(p).resolve() for p in glob.glob(spec, recursive=True) if Path(p).is_file())
        else:
            raise SourceError(f"no such file or folder: {spec}")
    out_dir = out_dir.resolve()
    inputs = sorted(p for p in found if not p.is_relative_to(out_dir))
    if not inputs:
        raise SourceError(f"no videos found in {' '.join(specs)} (folders are searched for video suffixes: "
                          f".mp4, .avi, .mkv, .mov, ...)")
    return inputs


def output_name(source: Path, length: int = 8) -> str:
    """File-name prefix of an input's outputs: its stem plus a hash of its full path.

    Two cameras' 08-00.mp4 in different folders get different names, and the name does not
    depend on which other inputs a run was given.
    """
    stem = "".join(c if c.isalnum() or c in "-_." else "_" for c in source.stem)[:60] or "video"
    return f"{stem}-{hashlib.sha1(str(source).encode()).hexdigest()[:length]}"


# --- the batch folder ----------------------------------------------------------------------


@contextmanager
def _locked(out_dir: Path) -> Iterator[None]:
    """One batch at a time per DIR: two would overwrite each other's manifest."""
    import fcntl

    from core.errors import HeightpipeError

    lock = open(out_dir / ".lock", "a+")
    try:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            lock.seek(0)
            holder = lock.read().strip() or "?"
            raise HeightpipeError(f"{out_dir} is in use by another heightpipe batch (pid {holder})") from None
        lock.seek(0)
        lock.truncate()
        lock.write(str(os.getpid()))
        lock.flush()
        yield
    finally:
        lock.close()


def prepare_out_dir(out_dir: Path) -> None:
    from core.errors import HeightpipeError

    if out_dir.exists() and not out_dir.is_dir():
        raise HeightpipeError(f"--out {out_dir} is a file, not a folder")
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise HeightpipeError(f"cannot create {out_dir}: {exc.strerror}") from None


@contextmanager
def _sigterm_stops_batch() -> Iterator[None]:
    """SIGTERM stops the batch like Ctrl-C does: workers finish cleanly, the manifest is kept."""
    def handler(signum, _frame):
        raise KeyboardInterrupt(signal.Signals(signum).name)

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


# --- progress ------------------------------------------------------------------------------


class BatchProgress:
    """One bar over files plus a line per worker on a terminal; one line per file otherwise."""

    def __init__(self, total: int, workers: int, enabled: bool):
        self.total = total
        self.finished = 0
        self.mode = "off" if not enabled or total == 0 else ("bars" if sys.stderr.isatty() else "lines")
        self.bar = None
        self.worker_lines = []
        if self.mode == "bars":
            from tqdm import tqdm

            self.bar = tqdm(total=total, unit="video", desc="videos", dynamic_ncols=True, position=0)
            self.worker_lines = [tqdm(total=0, bar_format="{desc}", position=i + 1, leave=False,
                                      desc=f"  worker {i + 1}: idle") for i in range(workers)]

    def status(self, status: WorkerStatus) -> None:
        if self.mode != "bars" or status.slot >= len(self.worker_lines):
            return
        name = Path(status.source).name[:40]
        if status.frames == 0:
            text = f"  worker {status.slot + 1}: {name} starting"
        else:
            total = f"/{status.total}" if status.total else ""
            text = f"  worker {status.slot + 1}: {name} frame {status.frames}{total} ({status.fps:.1f} fps)"
        self.worker_lines[status.slot].set_description_str(text)

    def result(self, result: TaskResult) -> None:
        self.finished += 1
        name = Path(result.source).name
        if self.mode == "bars":
            self.bar.update(1)
            if result.status == FAILED:
                self.bar.write(f"failed {name}: {result.error}", file=sys.stderr)
        elif self.mode == "lines":
            detail = (f"{result.frames} frames in {result.wall_s:.1f} s" if result.status == DONE
                      else result.error)
            print(f"[{self.finished}/{self.total}] {result.status} {name}: {detail}", file=sys.stderr, flush=True)

    def close(self) -> None:
        for line in self.worker_lines:
            line.close()
        if self.bar is not None:
            self.bar.close()


# --- the batch -----------------------------------------------------------------------------


def _make_engine(options: BatchOptions, cores: int):
    from pipeline.batch_engines import LocalEngine, RayEngine, ray_available
    from core.errors import ConfigError, HeightpipeError

    if options.engine not in ENGINES:
        raise ConfigError(f"unknown engine {options.engine!r} (choose {' or '.join(ENGINES)})")
    if options.workers < 0:
        raise ConfigError(f"--workers must be at least 1 (0 = one per core), got {options.workers}")
    if options.address and options.engine != "ray":
        raise ConfigError("--address is for --engine ray")
    if options.engine == "local":
        return LocalEngine(options.workers or cores)
    if not ray_available():
        raise HeightpipeError("--engine ray needs Ray: pip install 'heightpipe[ray]'")
    return RayEngine(options.workers or (0 if options.address else cores), options.address)


def _check_config(config: Config) -> None:
    from core.errors import ConfigError

    if config.capture.stride < 1:
        raise ConfigError("capture.stride must be at least 1")
    if config.output.rerun not in ("save", "off"):
        raise ConfigError(f"batch writes files only: output.rerun must be 'save' or 'off', not {config.output.rerun!r}")
    if not config.output.objects:
        raise ConfigError("batch needs output.objects = true: the archive's tracks table is built from "
                          "each video's objects.csv")


def _plan(inputs: list[Path], manifest: Manifest, fingerprint: str, config: Config, options: BatchOptions,
          threads: int, report: BatchReport) -> tuple[list[VideoTask], dict[str, InputIdentity]]:
    """The tasks to run now and every input's identity; counts skips and reasons in ``report``."""
    from pipeline.batch_engines import VideoTask
    from pipeline.batch_manifest import InputIdentity, ManifestEntry, identify

    out_dir = options.out_dir.resolve()
    names = {entry.output_name: key for key, entry in manifest.entries.items()}
    tasks, identities = [], {}
    for path in inputs:
        key = str(path)
        try:
            identities[key] = identify(path)
        except OSError as exc:  # unreadable: fails this input only
            identities[key] = InputIdentity(-1, -1, "")
            manifest.entries[key] = ManifestEntry(key, output_name(path), identities[key], fingerprint,
                                                  FAILED, f"cannot read {path}: {exc.strerror}")
            continue
        reason = manifest.reason_to_run(key, identities[key], fingerprint, out_dir,
                                        options.force, options.retry_failed)
        if reason is None:
            report.skipped += 1
            continue
        reason = reason.split(":")[0]
        report.queued[reason] = report.queued.get(reason, 0) + 1
        name = manifest.entries[key].output_name if key in manifest.entries else output_name(path)
        if names.get(name, key) != key:  # a 32-bit hash collision: take a longer one
            name = output_name(path, length=16)
        names[name] = key
        tasks.append(VideoTask(key, name, out_dir, config, threads))
    return tasks, identities


@dataclass
class _Recorder:
    """Puts each task's result into the manifest (saved at once) and the report."""

    manifest: Manifest
    out_dir: Path
    engine: str
    fingerprint: str
    identities: dict[str, InputIdentity]
    output_names: dict[str, str]
    report: BatchReport
    progress: BatchProgress

    def __call__(self, result: TaskResult) -> None:
        from pipeline.batch_manifest import ManifestEntry

        previous = self.manifest.entries.get(result.source)
        if result.status == DONE and previous is not None:
            for stale in set(previous.outputs) - set(result.outputs):  # e.g. the .rrd, now turned off
                (self.out_dir / stale).unlink(missing_ok=True)
        # Every TaskResult field is a ManifestEntry field; the entry adds what the batch knows.
        self.manifest.entries[result.source] = ManifestEntry(
            output_name=self.output_names[result.source], identity=self.identities[result.source],
            config_fingerprint=self.fingerprint, engine=self.engine, **dataclasses.asdict(result))
        self.manifest.save()
        report = self.report
        report.interrupted += result.status == INTERRUPTED
        if result.status == DONE:
            report.done += 1
            report.frames += result.frames
            report.failed_frames += result.failed_frames
            report.video_s += result.duration_s
            report.compute_s += result.wall_s
        self.progress.result(result)


def run_batch(specs: list[str], config: Config, options: BatchOptions) -> BatchReport:
    """Process every input not already done into options.out_dir; Ctrl-C returns a stopped report."""
    from pipeline.batch_engines import PARTIAL_FOLDER
    from pipeline.batch_manifest import Manifest, config_fingerprint
    from pipeline.batch_tables import write_tables
    from stages.heightnet_model import cores as usable_cores, most_threads

    _check_config(config)
    cores = usable_cores()
    engine = _make_engine(options, cores)
    out_dir = options.out_dir.resolve()
    inputs = find_inputs(specs, out_dir)
    prepare_out_dir(out_dir)
    fingerprint = config_fingerprint(config)
    # Parallel videos share the cores: one ONNX Runtime/OpenCV thread each rather than oversubscribing.
    threads = 1 if options.address else max(1, min(most_threads(config.height.threads),
                                                   cores // max(1, engine.workers)))
    start = time.perf_counter()
    with _locked(out_dir):
        shutil.rmtree(out_dir / PARTIAL_FOLDER, ignore_errors=True)  # outputs of videos a stop cut short
        manifest = Manifest.load(out_dir)
        report = BatchReport(out_dir, engine.name, engine.workers, threads, inputs=len(inputs))
        tasks, identities = _plan(inputs, manifest, fingerprint, config, options, threads, report)
        progress = BatchProgress(len(tasks), engine.workers, options.progress)
        record = _Recorder(manifest, out_dir, engine.name, fingerprint, identities,
                           {task.source: task.output_name for task in tasks}, report, progress)
        try:
            with _sigterm_stops_batch():
                if tasks:
                    engine.run(tasks, progress.status, record)
        except KeyboardInterrupt:
            report.stopped = True
        finally:
            progress.close()
            manifest.save()  # again: a Ctrl-C may have cut the last save short (each save is atomic)
            report.workers = engine.workers  # Ray on a cluster knows its size only now
            report.wall_s = time.perf_counter() - start
            report.failed = [(key, manifest.entries[key].error) for key in identities
                             if key in manifest.entries and manifest.entries[key].status == FAILED]
            report.tables, report.archive_tracks = write_tables(manifest, out_dir)
            report.archive_videos = sum(e.status == DONE for e in manifest.entries.values())
    return report


def format_report(report: BatchReport) -> str:
    per_compute = report.video_s / report.compute_s if report.compute_s else 0.0
    per_wall = report.video_s / report.wall_s if report.wall_s else 0.0
    head = (f"heightpipe batch: {report.inputs} inputs -> {report.out_dir} ({report.engine} engine, "
            f"{report.workers or 'all cluster'} workers, {report.threads} thread(s) each)")
    if report.stopped:
        head += "\n  STOPPED: finished videos are kept; run the same command again to continue"
    queued = ", ".join(f"{count} {reason}" for reason, count in sorted(report.queued.items()))
    rows = [
        ("queued", f"{sum(report.queued.values())}" + (f" ({queued})" if queued else "")),
        ("done", f"{report.done}"),
        ("skipped", f"{report.skipped} (unchanged since an earlier run)"),
        ("failed", f"{len(report.failed)}"),
    ]
    if report.interrupted:
        rows.append(("interrupted", f"{report.interrupted} (redone on the next run)"))
    frames = f"{report.frames}" + (f" ({report.failed_frames} failed to decode)" if report.failed_frames else "")
    rows.append(("frames", frames))
    rows.append(("video", f"{report.video_s / 3600:.3f} h processed in {report.compute_s:.1f} s of compute, "
                          f"{report.wall_s:.1f} s wall"))
    rows.append(("speed", f"{per_compute:.1f} h of video per hour of compute, {per_wall:.1f} per hour of wall time"))
    rows.append(("archive", f"{report.archive_videos} videos, {report.archive_tracks} tracks: "
                            + ", ".join(p.name for p in report.tables)))
    lines = [head] + [f"  {name:<12} {value}" for name, value in rows]
    lines += [f"    {Path(source).name}: {error}" for source, error in report.failed]
    return "\n".join(lines)


def main(args: argparse.Namespace, config: Config) -> int:
    from pipeline.run_command import apply_flags

    apply_flags(args, config)
    # Resolved before the fingerprints are made (run_pipeline would resolve it again, the same).
    config = model_for(config)
    options = BatchOptions(
        out_dir=Path(args.out),
        engine=args.engine or config.batch.engine,
        workers=args.workers if args.workers is not None else config.batch.workers,
        address=args.address,
        force=args.force,
        retry_failed=args.retry_failed,
        progress=config.output.progress,
    )
    report = run_batch(args.inputs, config, options)
    print(format_report(report), file=sys.stderr)
    if report.stopped:
        return 130
    return 1 if report.failed else 0
