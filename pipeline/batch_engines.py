"""Where batch tasks run: a local process pool (default) or Ray. One task = one video.

Both engines run the same ``process_video`` (``run_pipeline`` into DIR/.partial, then rename
into place) and report through the same two callbacks, ``on_status`` (which file and frame a
worker is at) and ``on_result`` (a finished, failed or interrupted task). On Ctrl-C both
stop the running videos cleanly, hand over every result that still arrives, and re-raise.
"""

from __future__ import annotations

import copy
import ctypes
import os
import pickle
import queue
import signal
import socket
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable, Iterator

from pipeline.batch_manifest import DONE, FAILED, INTERRUPTED
from core.config import Config

VIDEOS_FOLDER = "videos"
PARTIAL_FOLDER = ".partial"


@dataclass(frozen=True)
class BatchEngineConstants:
    """The engines' fixed numbers (the rule is in docs/design.md, Configuration)."""

    status_interval_s: float = 0.5
    """A worker reports its frame count at most this often: a live progress bar, few messages."""
    shutdown_timeout_s: float = 30.0
    """How long a stop waits for workers to close their outputs before killing them: the sinks'
    own close waits up to 30 s (``stages.rerun_sink``)."""


CONSTANTS = BatchEngineConstants()


@dataclass
class VideoTask:
    source: str
    """Resolved path of the input video (also its manifest key)."""
    output_name: str
    """Unique file name prefix of this input's outputs (see batch.output_name)."""
    out_dir: Path
    """DIR: outputs go to DIR/videos/, temporary ones to DIR/.partial/."""
    config: Config
    threads: int
    """ONNX Runtime and OpenCV threads for this task (1 when videos run in parallel)."""


@dataclass
class TaskResult:
    source: str
    status: str
    """'done', 'failed' or 'interrupted' (see pipeline.batch_manifest)."""
    error: str = ""
    outputs: list[str] = field(default_factory=list)
    """Finished outputs, relative to DIR."""
    frames: int = 0
    failed_frames: int = 0
    duration_s: float = 0.0
    video_fps: float = 0.0
    wall_s: float = 0.0
    tracks: int = 0
    camera: str = ""
    started_at: str = ""
    finished_at: str = ""
    worker: str = ""


@dataclass
class WorkerStatus:
    slot: int
    source: str
    frames: int = 0
    total: int | None = None
    fps: float = 0.0


StatusCallback = Callable[[WorkerStatus], None]
ResultCallback = Callable[[TaskResult], None]


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def _one_line(exc: BaseException) -> str:
    from core.errors import HeightpipeError

    text = str(exc).strip().replace("\n", " ")
    return text if isinstance(exc, HeightpipeError) else f"{type(exc).__name__}: {text}"


def _throttled(report: Callable[[int, int | None, float], None] | None):
    """run_pipeline's on_frame callback, reporting (frames, total, fps) at most every CONSTANTS.status_interval_s."""
    if report is None:
        return None
    last = [0.0]

    def on_frame(frames: int, total: int | None, elapsed_s: float) -> None:
        if elapsed_s - last[0] >= CONSTANTS.status_interval_s:
            last[0] = elapsed_s
            report(frames, total, frames / max(elapsed_s, 1e-9))

    return on_frame


def _video_fps(source: str) -> float:
    import cv2

    capture = cv2.VideoCapture(source, cv2.CAP_FFMPEG)
    try:
        fps = capture.get(cv2.CAP_PROP_FPS) if capture.isOpened() else 0.0
    finally:
        capture.release()
    return fps if 0 < fps < 1000 else 0.0


def _fsync(path: Path) -> None:
    with open(path, "rb") as f:
        os.fsync(f.fileno())


def process_video(task: VideoTask, report: Callable[[int, int | None, float], None] | None = None) -> TaskResult:
    """Run the pipeline on one video into DIR/.partial and rename the outputs into DIR/videos.

    Never raises for a bad video: the error goes into the result, so one broken file does not
    stop the batch. A stop (SIGTERM, Ctrl-C, Ray cancel) leaves the outputs in .partial.
    """
    import cv2

    from pipeline.runner import StopRequested, run_pipeline

    result = TaskResult(source=task.source, status=FAILED, started_at=_now(),
                        worker=f"{socket.gethostname()}:{os.getpid()}")
    start = time.perf_counter()
    partial_prefix = task.out_dir / PARTIAL_FOLDER / task.output_name
    config = copy.deepcopy(task.config)
    config.height.threads = task.threads
    config.output.progress = False
    cv2.setNumThreads(task.threads)
    try:
        summary = run_pipeline(task.source, config, partial_prefix, on_frame=_throttled(report))
    except (KeyboardInterrupt, StopRequested):
        summary = None
        result.status, result.error = INTERRUPTED, "stopped before the video was finished"
    except Exception as exc:  # any failure of one video is that video's result, not the batch's
        summary = None
        result.error = _one_line(exc)
    if summary is not None:
        result.frames = summary.frames
        result.failed_frames = summary.capture.failed
        result.tracks = len(summary.objects.rows)
        result.camera = summary.camera_source
        if summary.interrupted:
            result.status, result.error = INTERRUPTED, "stopped before the video was finished"
        else:
            result.video_fps = _video_fps(task.source)
            if result.video_fps:
                result.duration_s = summary.capture.decoded / result.video_fps
            videos = task.out_dir / VIDEOS_FOLDER
            videos.mkdir(parents=True, exist_ok=True)
            for partial in summary.outputs.existing():
                _fsync(partial)
                os.replace(partial, videos / partial.name)
                result.outputs.append(f"{VIDEOS_FOLDER}/{partial.name}")
            result.status = DONE
    result.wall_s = time.perf_counter() - start
    result.finished_at = _now()
    return result


# --- local process pool ------------------------------------------------------------------


def _die_with_parent(parent_pid: int) -> None:
    """Ask Linux to SIGTERM this worker when the batch process dies (even by kill -9)."""
    try:
        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass  # not Linux: orphans finish their current video, then find their queue gone
    if os.getppid() != parent_pid:  # the parent died before prctl took effect
        os._exit(0)


WARM_UP_MODULES = ("pipeline.runner", "stages.object_extraction", "stages.tracking", "stages.rerun_sink",
                   "stages.mcap_sink", "stages.heightnet_model", "stages.feature_matching")
"""The slow imports of run_pipeline (~1 s each under load), done once when a worker starts so a
video's compute time is the pipeline's own; a name missing here is just imported on first use."""


def _warm_up_imports() -> None:
    import importlib

    for name in WARM_UP_MODULES:
        try:
            importlib.import_module(name)
        except ImportError:
            pass


def _local_worker(slot: int, tasks, events, parent_pid: int) -> None:
    """Worker process: take tasks from ``tasks`` until None, report on ``events`` (this worker's
    own pipe to the parent).

    Ctrl-C from the terminal reaches every process in the group; workers ignore it and wait
    for the parent's SIGTERM, which run_pipeline turns into a clean stop of the video. A
    stopped video ends the worker, and so does a parent that is gone. A SIGTERM between videos
    is remembered too: raised inside a ``__del__``, Python swallows it, and the worker would
    otherwise go on to the next video.
    """
    from pipeline.runner import StopRequested, swallowed_stops_unprinted

    _die_with_parent(parent_pid)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    stops: list[str] = []

    def stop(signum, _frame):
        stops.append(signal.Signals(signum).name)
        raise StopRequested(stops[-1])

    signal.signal(signal.SIGTERM, stop)
    with swallowed_stops_unprinted():
        try:
            _warm_up_imports()
            while not stops:
                try:
                    # A timeout, not a blocking get: a signal delivered to one of ONNX Runtime's
                    # threads only runs its Python handler once the main thread wakes up.
                    task = tasks.get(timeout=1.0)
                except queue.Empty:
                    if os.getppid() != parent_pid:
                        break
                    continue
                if task is None:
                    return

                def report(frames, total, fps, source=task.source):
                    events.send((slot, WorkerStatus(slot, source, frames, total, fps)))

                events.send((slot, WorkerStatus(slot, task.source)))
                result = process_video(task, report)
                events.send((slot, result))
                if result.status == INTERRUPTED:
                    break
        except (StopRequested, BrokenPipeError):   # stopped, or the parent is gone
            pass


@contextmanager
def _sigint_ignored() -> Iterator[None]:
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


@dataclass
class _Slot:
    process: object
    tasks: object
    """This worker's own task queue: the parent always knows which video a worker holds."""
    events: object
    """The read end of this worker's own pipe of statuses and results. Not one queue shared by
    all workers: a worker killed while writing to a shared ``multiprocessing.Queue`` can leave
    its lock taken, and every other worker then waits on it for ever (seen once in
    ``tests/pipeline/test_batch.py::test_a_worker_that_dies_fails_only_its_video``)."""
    task: VideoTask | None = None


class LocalEngine:
    """A pool of worker processes, one video each at a time; no services needed.

    A worker that dies (segfault, out-of-memory kill) fails only the video it held and is
    replaced.
    """

    name = "local"

    def __init__(self, workers: int):
        self.workers = workers

    def run(self, tasks: list[VideoTask], on_status: StatusCallback, on_result: ResultCallback) -> None:
        _LocalRun(self.workers, tasks, on_status, on_result).run()


class _LocalRun:
    """The state of one LocalEngine.run: worker slots, tasks still to hand out, the event queue."""

    def __init__(self, workers: int, tasks: list[VideoTask], on_status: StatusCallback,
                 on_result: ResultCallback):
        import multiprocessing

        self.context = multiprocessing.get_context("spawn")
        self.workers = min(workers, len(tasks))
        self.pending = list(reversed(tasks))
        self.slots: dict[int, _Slot] = {}
        self.on_status = on_status
        self.on_result = on_result
        self.stopping = False

    def run(self) -> None:
        try:
            for slot_id in range(self.workers):
                self._start_worker(slot_id)
            last_check = time.monotonic()
            while any(slot.task is not None for slot in self.slots.values()):
                self._receive(timeout=0.5)
                if time.monotonic() - last_check > 1.0:
                    last_check = time.monotonic()
                    self._replace_dead_workers()
            for slot in self.slots.values():
                slot.process.join(timeout=CONSTANTS.shutdown_timeout_s)
        except BaseException:
            self._stop()
            raise

    def _start_worker(self, slot_id: int) -> None:
        task_queue = self.context.Queue()
        events, worker_end = self.context.Pipe(duplex=False)
        process = self.context.Process(target=_local_worker, name=f"heightpipe-batch-{slot_id}", daemon=True,
                                       args=(slot_id, task_queue, worker_end, os.getpid()))
        with _sigint_ignored():  # inherited through exec: a Ctrl-C cannot hit the worker's start-up
            process.start()
        worker_end.close()  # the worker holds the only write end: its death is the pipe's end
        if slot_id in self.slots:
            self.slots[slot_id].events.close()
        self.slots[slot_id] = _Slot(process, task_queue, events)
        self._feed(self.slots[slot_id])

    def _receive(self, timeout: float) -> None:
        """Hand over what the workers sent, waiting up to ``timeout`` for the first of it."""
        from multiprocessing.connection import wait

        open_pipes = [slot.events for slot in self.slots.values() if not slot.events.closed]
        for pipe in wait(open_pipes, timeout=timeout):
            try:
                self._handle(*pipe.recv())
            except (EOFError, OSError, pickle.UnpicklingError):
                pipe.close()   # its worker is gone (mid-message, perhaps): _replace_dead_workers knows

    def _feed(self, slot: _Slot) -> None:
        """Hand the next task to an idle worker, or None (its signal to exit) when none is left."""
        slot.task = self.pending.pop() if self.pending and not self.stopping else None
        slot.tasks.put(slot.task)

    def _handle(self, slot_id: int, payload: WorkerStatus | TaskResult) -> None:
        slot = self.slots[slot_id]
        if isinstance(payload, WorkerStatus):
            self.on_status(payload)
            return
        slot.task = None
        self.on_result(payload)
        if not self.stopping:
            self._feed(slot)

    def _drain(self) -> None:
        while any(not slot.events.closed and slot.events.poll() for slot in self.slots.values()):
            self._receive(timeout=0.0)

    def _replace_dead_workers(self) -> None:
        if not any(slot.task is not None and slot.process.exitcode is not None for slot in self.slots.values()):
            return
        self._drain()  # a result it sent just before dying still counts
        for slot_id, slot in list(self.slots.items()):
            if slot.task is None or slot.process.exitcode is None:
                continue
            code = slot.process.exitcode
            why = f"killed by {signal.Signals(-code).name}" if code < 0 else f"exit code {code}"
            self.on_result(TaskResult(source=slot.task.source, status=FAILED, finished_at=_now(),
                                      error=f"worker process died ({why}; out of memory?)"))
            self._start_worker(slot_id)

    def _stop(self) -> None:
        """Stop every worker: idle ones get None, busy ones SIGTERM (a clean end of their video).

        Results that still arrive (a video that finished meanwhile) are handed over; a second
        Ctrl-C here kills the workers outright.
        """
        self.stopping = True
        try:
            for slot in self.slots.values():
                if slot.process.is_alive():
                    slot.tasks.put(None)
                    if slot.task is not None:
                        os.kill(slot.process.pid, signal.SIGTERM)
            deadline = time.monotonic() + CONSTANTS.shutdown_timeout_s
            while any(slot.process.is_alive() for slot in self.slots.values()) and time.monotonic() < deadline:
                self._receive(timeout=0.1)
            self._drain()
        finally:
            for slot in self.slots.values():
                if slot.process.is_alive():
                    slot.process.kill()
                slot.process.join(timeout=5)


# --- Ray -----------------------------------------------------------------------------------


def _ray_task(task: VideoTask, slot: int, progress_queue) -> TaskResult:
    def report(frames, total, fps):
        try:
            progress_queue.put_nowait(WorkerStatus(slot, task.source, frames, total, fps))
        except Exception:  # progress is best-effort; a full or gone queue must not fail a video
            pass

    report(0, None, 0.0)
    _warm_up_imports()
    return process_video(task, report)


class RayEngine:
    """The same tasks as Ray tasks: ``ray.init()`` locally, or joining the cluster at ``address``.

    On a cluster, every node must see the inputs and DIR at the same paths (a shared file
    system) and have heightpipe installed.
    """

    name = "ray"

    def __init__(self, workers: int, address: str | None):
        self.workers = workers
        self.address = address

    def run(self, tasks: list[VideoTask], on_status: StatusCallback, on_result: ResultCallback) -> None:
        os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
        import ray
        from ray.util.queue import Queue

        if self.address:
            ray.init(address=self.address, include_dashboard=False, log_to_driver=False, logging_level="ERROR")
        else:
            ray.init(num_cpus=self.workers, include_dashboard=False, log_to_driver=False,
                     logging_level="ERROR", object_store_memory=256 * 1024 * 1024)
        try:
            if not self.workers:  # a cluster: keep every CPU of it busy
                self.workers = max(1, int(ray.cluster_resources().get("CPU", 1)))
            progress = Queue(actor_options={"num_cpus": 0})
            remote_task = ray.remote(num_cpus=1, max_retries=0)(_ray_task)
            self._run(ray, remote_task, progress, tasks, on_status, on_result)
        finally:
            ray.shutdown()

    def _run(self, ray, remote_task, progress, tasks, on_status, on_result) -> None:
        pending = list(reversed(tasks))
        in_flight: dict[object, tuple[int, VideoTask]] = {}
        free_slots = list(reversed(range(self.workers)))

        def submit() -> None:
            while pending and free_slots:
                task, slot = pending.pop(), free_slots.pop()
                in_flight[remote_task.remote(task, slot, progress)] = (slot, task)

        def collect(ref) -> None:
            slot, task = in_flight.pop(ref)
            free_slots.append(slot)
            try:
                result = ray.get(ref)
            except ray.exceptions.TaskCancelledError:
                result = TaskResult(task.source, INTERRUPTED, "cancelled", finished_at=_now())
            except ray.exceptions.RayError as exc:  # the worker died, or Ray lost the task
                result = TaskResult(task.source, FAILED, _one_line(exc).splitlines()[0][:300],
                                    finished_at=_now())
            on_result(result)

        def drain_progress() -> None:
            try:
                items = progress.get_nowait_batch(progress.qsize())
            except Exception:
                return
            for status in items:
                if any(slot == status.slot and task.source == status.source for slot, task in in_flight.values()):
                    on_status(status)

        try:
            submit()
            while in_flight:
                done, _ = ray.wait(list(in_flight), num_returns=1, timeout=CONSTANTS.status_interval_s)
                drain_progress()
                for ref in done:
                    collect(ref)
                submit()
        except BaseException:
            pending.clear()
            for ref in list(in_flight):
                ray.cancel(ref)  # KeyboardInterrupt inside the task: run_pipeline closes its outputs
            deadline = time.monotonic() + CONSTANTS.shutdown_timeout_s
            while in_flight and time.monotonic() < deadline:
                done, _ = ray.wait(list(in_flight), num_returns=1, timeout=1.0)
                for ref in done:
                    collect(ref)
            raise


def ray_available() -> bool:
    try:
        import ray  # noqa: F401
    except ImportError:
        return False
    return True
