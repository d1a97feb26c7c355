"""The pipeline, in the order docs/design.md lists it.

open the source → seed the background model from frames read ahead (files only) → for each
frame: (undistortion) → ground segmentation → height inference → keypoints → feature matching →
object extraction → (geometry) → tracking → sinks → close the sinks.

Sinks are closed whatever happens (end of video, Ctrl-C, SIGTERM, an exception), so a
stopped run still leaves a readable MCAP, .rrd and CSV of everything processed.
"""

from __future__ import annotations

import signal
import sys
import time
from collections import defaultdict
from contextlib import closing, contextmanager, suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

from core.config import Config
from core.packets import CameraInfo, FramePacket, HeightCamera
from core.stage import Sink
from pipeline.scene_camera import model_for, opening_images, pose_from_scene, reads_scene
from pipeline.stage_chain import build_stage_chain, close_all, import_stages, load_height_model
from pipeline.track_backfill import TrackBackfill
from stages.capture import CaptureStats, FrameSource, StreamSource, open_source
from stages.objects_table import ObjectTable


@dataclass
class RunOutputs:
    rrd: Path | None
    mcap: Path | None
    csv: Path | None
    objects: Path | None = None
    events: Path | None = None
    camera_picture: Path | None = None
    """PREFIX.camera.jpg: the camera read from the first frames, drawn on the scene (told only the height)."""

    def existing(self) -> list[Path]:
        return [p for p in (self.rrd, self.mcap, self.csv, self.objects, self.events, self.camera_picture)
                if p is not None]


@dataclass
class RunSummary:
    source: str
    frames: int = 0
    capture: CaptureStats = field(default_factory=CaptureStats)
    objects: ObjectTable = field(default_factory=ObjectTable)
    """One row per track ever confirmed: what PREFIX.objects.csv holds."""
    stage_ms: dict[str, float] = field(default_factory=lambda: defaultdict(float))
    stage_frames: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    """How many frames each stage and sink ran on: all of them, but a live run's network stages
    skip the frames that reuse their outputs."""
    wall_s: float = 0.0
    events: int = 0
    """Height-rule firings (each one a line of PREFIX.events.jsonl)."""
    webhook: str = ""
    """How the webhook fared ("" = none configured)."""
    interrupted: str | None = None
    dropped_frames: int = 0
    """Frames of a live source dropped because the pipeline was busy (overlapped runs only)."""
    reused_network_frames: int = 0
    """Frames of a live source given the previous frame's network outputs (``run.reuse_backlog``)."""
    overlapped: bool = False
    camera_source: str = "none"
    height_camera: HeightCamera | None = None
    """The camera a v2 network's heights were decoded with at the last frame (None: a v1 model)."""
    scene_camera: HeightCamera | None = None
    """Told only the camera height: the camera read from the first frames that posed the run."""
    outputs: RunOutputs | None = None

    @property
    def fps(self) -> float:
        return self.frames / self.wall_s if self.wall_s > 0 else 0.0

    def ms_per_frame(self) -> dict[str, float]:
        """Each stage's and sink's mean time over the frames it ran on (what one run of it costs)."""
        return {name: ms / max(1, self.stage_frames.get(name, self.frames)) for name, ms in self.stage_ms.items()}

    def total_ms_per_frame(self) -> float:
        """All stages' and sinks' time over all frames (what a frame costs, skipped stages included)."""
        return sum(self.stage_ms.values()) / max(1, self.frames)


class StopRequested(BaseException):
    """Raised from the SIGTERM handler so the run unwinds through its finally blocks.

    A BaseException, like KeyboardInterrupt, so no ``except Exception`` in a stage swallows it.
    """


class _StopSignals:
    """Turns SIGTERM (and Ctrl-C) into ``StopRequested``, held back while a frame is being written
    and while the outputs are closed.

    A frame half-written (in the MCAP but not yet in the CSV or the frame count) would leave
    outputs that disagree, so a signal arriving inside ``held()`` waits for it to end (a second
    one does not: the user insists). Every stop is also remembered: one raised where Python
    swallows it (inside a ``__del__``, which then prints "Exception ignored") still stops the
    run at the end of the next frame, and is not printed.
    """

    def __init__(self) -> None:
        self._held = False
        self.requested: str | None = None

    def _handler(self, signum, _frame) -> None:
        name = signal.Signals(signum).name
        again = self.requested is not None
        self.requested = name
        if not self._held or again:
            raise StopRequested(name)

    @contextmanager
    def installed(self) -> Iterator["_StopSignals"]:
        try:
            previous_term = signal.signal(signal.SIGTERM, self._handler)
        except ValueError:  # not the main thread (e.g. a batch worker thread): leave signals alone
            yield self
            return
        # SIGINT only where Python's own Ctrl-C handler is in place: a batch worker ignores it.
        previous_int = signal.getsignal(signal.SIGINT)
        if previous_int is signal.default_int_handler:
            signal.signal(signal.SIGINT, self._handler)
        try:
            with swallowed_stops_unprinted():
                yield self
        finally:
            signal.signal(signal.SIGTERM, previous_term)
            if previous_int is signal.default_int_handler:
                signal.signal(signal.SIGINT, previous_int)

    @contextmanager
    def held(self) -> Iterator[None]:
        """Signals arriving inside wait (``requested`` says whether one came)."""
        self._held = True
        try:
            yield
        finally:
            self._held = False

    @contextmanager
    def writing(self) -> Iterator[None]:
        """One frame out to every sink, then the stop that came meanwhile (or was swallowed)."""
        with self.held():
            yield
        if self.requested is not None:
            raise StopRequested(self.requested)


@contextmanager
def swallowed_stops_unprinted() -> Iterator[None]:
    """Keep Python from printing a stop it swallowed (raised by a signal handler inside a
    ``__del__``): whoever installed the handler remembers the stop and acts on it. Any other
    unraisable exception is printed as before."""
    previous = sys.unraisablehook

    def hook(unraisable) -> None:
        if not isinstance(unraisable.exc_value, (StopRequested, KeyboardInterrupt)):
            previous(unraisable)

    sys.unraisablehook = hook
    try:
        yield
    finally:
        sys.unraisablehook = previous


def output_paths(prefix: Path, config: Config) -> RunOutputs:
    return RunOutputs(
        rrd=prefix.with_name(prefix.name + ".rrd") if config.output.rerun != "off" else None,
        mcap=prefix.with_name(prefix.name + ".mcap") if config.output.mcap else None,
        csv=prefix.with_name(prefix.name + ".tracks.csv") if config.output.csv else None,
        objects=prefix.with_name(prefix.name + ".objects.csv") if config.output.objects else None,
        events=prefix.with_name(prefix.name + ".events.jsonl") if config.rules else None,
    )


def build_camera(config: Config, width: int, height: int) -> CameraInfo:
    from stages.calibration import camera_for_run

    return camera_for_run(config.camera, width, height)


def import_sinks(config: Config) -> None:
    """Import the libraries of the configured sinks (rerun alone takes ~0.3 s) without opening any."""
    if config.output.rerun != "off":
        import stages.rerun_sink  # noqa: F401
    if config.output.mcap:
        import stages.mcap_sink  # noqa: F401


def build_sinks(outputs: RunOutputs, config: Config, recording_name: str,
                objects: ObjectTable | None = None, live: bool = False,
                scene=None) -> list[tuple[str, Sink]]:
    """The sinks of this run; if one cannot be opened, those already open are closed first.

    ``live``: the source is a stream that may not end (the .rrd then has no index by default).
    ``scene``: the camera read from the first frames (``pipeline.scene_camera.SceneReading``),
    shown in the rerun view beside the camera's state.
    """
    from stages.sink_common import FrameEncoder

    encoder = FrameEncoder.from_config(config.output)  # one JPEG per frame, shared by both sinks
    sinks: list[tuple[str, Sink]] = []
    try:
        if outputs.rrd is not None:
            from stages.rerun_sink import RerunSink, web_grpc_url

            web_url = web_grpc_url(config.web.bind, config.web.grpc_port) if config.output.rerun == "web" else None
            sinks.append(("rerun", RerunSink(outputs.rrd, config.output.rerun, config.output, recording_name,
                                             encoder=encoder, web_url=web_url, live=live,
                                             scene_camera=scene.camera if scene is not None else None,
                                             scene_picture=scene.picture if scene is not None else None)))
        if outputs.mcap is not None:
            from stages.mcap_sink import McapSink

            sinks.append(("mcap", McapSink(outputs.mcap, config.output, encoder=encoder,
                                           recording_name=recording_name)))
        if outputs.csv is not None:
            from stages.csv_sink import TrackCsvSink

            sinks.append(("csv", TrackCsvSink(outputs.csv)))
        if outputs.objects is not None:
            from stages.objects_table import ObjectsSink

            # Not "objects": sink and stage times share packet.timings_ms, and the stage has that name.
            sinks.append(("objects.csv", ObjectsSink(outputs.objects, objects or ObjectTable())))
        if outputs.events is not None:
            from stages.events_sink import EventsSink

            sinks.append(("events", EventsSink(outputs.events, config.events, recording_name)))
    except BaseException:
        close_all([sink for _, sink in sinks])
        raise
    return sinks


def expected_frames(source: FrameSource, config: Config) -> int | None:
    """Frames this run will process, where the source says how many it has."""
    total = source.stats.expected
    if total is not None:
        total = -(-total // max(1, config.capture.stride))
        if config.capture.max_frames:
            total = min(total, config.capture.max_frames)
    return total


def _progress(source: FrameSource, config: Config):
    from tqdm import tqdm

    return tqdm(total=expected_frames(source, config), unit="frame", disable=not config.output.progress,
                dynamic_ncols=True, desc=Path(source.description).name[:30])


FrameCallback = Callable[[int, "int | None", float], None]
"""on_frame(frames processed, frames expected or None, elapsed seconds)."""


def _opening_frames(config: Config, told: Config, source: FrameSource) -> tuple[list, list]:
    """The frames the background model is primed with and, for a file run told only the camera
    height, those it reads its camera from (spread over its first ``read_scene_s``), in one
    look-ahead pass over the opening seconds."""
    scene = (told.camera.read_scene_frames, told.camera.read_scene_s)
    if not reads_scene(told) or isinstance(source, StreamSource):
        scene = (0, 0.0)
    background, images = source.opening_samples(
        (config.objects.background_prime_frames, config.objects.background_prime_s), scene)
    return background, images


def _stream_scene_images(told: Config, source: StreamSource, frames: Iterator) -> list:
    """A live stream's first ``read_scene_live_s`` seconds, taken from ``frames``, to read its
    camera from (they are not processed: the stream's frames cannot be read twice, and the run
    must not fall behind them)."""
    images, taken = opening_images(frames, told.camera.read_scene_frames, told.camera.read_scene_live_s)
    if taken:
        source.stats.notes.append(f"the first {taken} frames ({told.camera.read_scene_live_s:g} s) read the "
                                  "camera and were not processed")
    return images


def _write_picture(path: Path, picture) -> Path | None:
    """PREFIX.camera.jpg: the camera read from the scene, drawn on it (None if it cannot be written:
    the run does not stop for a picture)."""
    import cv2

    return path if cv2.imwrite(str(path), picture, [cv2.IMWRITE_JPEG_QUALITY, 85]) else None


def _posed_from_scene(told: Config, config: Config, model, images: list):
    """Told only the camera height (``told``), the camera read from ``images``
    (``pipeline/scene_camera.py``): the posed run's config, its model (the one loaded is kept if
    the posed config names the same) and the reading; ``config`` and ``model`` as they were
    when there are no images or the camera read cannot pose the run."""
    posed, reading = pose_from_scene(told, images, model)
    if reading is None:
        return config, model, None
    posed = model_for(posed)
    if posed.height != config.height or posed.objects != config.objects:
        model = load_height_model(posed)
    return posed, model, reading


def run_pipeline(source_spec: str, config: Config, prefix: Path,
                 on_frame: FrameCallback | None = None) -> RunSummary:
    """Process one source end to end and return what happened; outputs go to PREFIX.*

    ``on_frame`` is called after every frame (batch workers report progress through it).
    ``height.model = ""`` is resolved here by what the config tells of the camera
    (``pipeline.scene_camera.model_for``): every caller, benchmarks too, runs what ``heightpipe run`` runs.
    """
    told = config
    config = model_for(config)
    # The network, the stages' and the sinks' libraries first (~1.2 s): a live stream's frames
    # pile up from the moment it is opened, and those the run cannot catch up with are dropped.
    model = load_height_model(config)
    import_stages()
    import_sinks(config)
    source = open_source(source_spec, config.capture)
    summary = RunSummary(source=source.description, capture=source.stats)
    scaling = source.scaling_note()
    if scaling:
        source.stats.notes.insert(0, scaling)
    prefix.parent.mkdir(parents=True, exist_ok=True)
    width, height = source.size
    try:
        frames = source.frames()
        background, images = _opening_frames(config, told, source)
        reading = None
        if reads_scene(told):
            if isinstance(source, StreamSource):
                images = _stream_scene_images(told, source, frames)
            config, model, reading = _posed_from_scene(told, config, model, images)
        outputs = output_paths(prefix, config)
        summary.outputs = outputs
        if reading is not None:
            summary.scene_camera = reading.camera
            outputs.camera_picture = _write_picture(prefix.with_name(prefix.name + ".camera.jpg"), reading.picture)
        camera = build_camera(config, width, height)
        summary.camera_source = camera.source
        chain = build_stage_chain(config, camera, model=model)
        chain.prime(background)
        sinks = build_sinks(outputs, config, prefix.name, summary.objects,
                            live=isinstance(source, StreamSource), scene=reading)
    except BaseException:
        source.close()
        raise
    progress = _progress(source, config)
    total = expected_frames(source, config)
    overlapped = None
    if config.run.overlapped:
        from pipeline.overlapped import OverlappedChain

        overlapped = OverlappedChain(chain, camera, config.run.queue_frames,
                                     live=isinstance(source, StreamSource), reuse_backlog=config.run.reuse_backlog)
        packets = overlapped.packets(frames)
    else:
        packets = chain.run(frames, camera)
    summary.overlapped = overlapped is not None
    # A live source's outputs (its alerts, its view) are not held for gaps to close or boxes to
    # be smoothed: only files'.
    live = isinstance(source, StreamSource)
    backfill = TrackBackfill(enabled=config.tracking.backfill,
                             fill_gaps_s=0.0 if live else config.tracking.fill_gaps_s,
                             smooth_s=0.0 if live else config.tracking.smooth_s)
    start = time.perf_counter()

    def write(packet: FramePacket) -> None:
        summary.objects.add(packet)
        for name, sink in sinks:
            t0 = time.perf_counter()
            sink.write(packet)
            packet.timings_ms[name] = (time.perf_counter() - t0) * 1000.0
        summary.frames += 1
        for name, ms in packet.timings_ms.items():
            summary.stage_ms[name] += ms
            summary.stage_frames[name] += 1
        summary.events += len(packet.events)
        summary.height_camera = packet.height_camera or summary.height_camera

    with _StopSignals().installed() as stop_signals:
        try:
            with closing(packets):
                for packet in packets:
                    with stop_signals.writing():
                        for ready in backfill.push(packet):
                            write(ready)
                    progress.update(1)
                    progress.set_postfix(tracks=sum(t.confirmed for t in packet.tracks), refresh=False)
                    if on_frame is not None:
                        on_frame(summary.frames, total, time.perf_counter() - start)
                with stop_signals.writing():
                    for ready in backfill.drain():
                        write(ready)
        except (KeyboardInterrupt, StopRequested) as stop:
            summary.interrupted = str(stop) if isinstance(stop, StopRequested) else "SIGINT"
            # The frames held for backfilling were processed: they go out too (a second Ctrl-C
            # while they are written leaves them out, not a traceback).
            with suppress(KeyboardInterrupt, StopRequested), stop_signals.held():
                for ready in backfill.drain():
                    write(ready)
        finally:
            # A stop arriving now waits for the outputs to close (a second one does not).
            with stop_signals.held():
                summary.wall_s = time.perf_counter() - start
                if overlapped is not None:
                    summary.dropped_frames = overlapped.dropped
                    summary.reused_network_frames = overlapped.reused
                progress.close()
                close_all([stage for _, stage in chain.stages + sinks] + [source])
                webhook = next((sink.webhook_stats for name, sink in sinks if name == "events"), None)
                summary.webhook = webhook.summary() if webhook is not None else ""
    return summary

