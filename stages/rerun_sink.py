"""Rerun output: a ``.rrd`` file (optionally also a live viewer) with an embedded layout.

``RerunFrameLogger`` turns one frame's plain arrays into rerun entities; ``RerunSink`` feeds it
from FramePackets and ``heightpipe replay`` feeds it from an MCAP file, so both produce the
same recording. Entities:

    /camera             Pinhole (when the intrinsics are known)
    /camera/image       the frame, JPEG
    /camera/ground      ground mask overlay (SegmentationImage; only with output.ground_overlay)
    /camera/matches     matched features, arrows from the previous to this frame
    /camera/tracks      confirmed tracks: boxes labelled "1.72 m ±4 cm" (+ "#12 person, geometry"
                        when the box has room, + ", box predicted" / ", box interpolated" where no
                        detection placed it), coloured by quality: settled / settling / no height
    /camera/events      a magenta frame around each object that fired a height rule, for a few seconds
    /height             height map in millimetres, shown colour-mapped in metres
    /tracks/<id>/height one height time series per confirmed track; cleared while it coasts
    /capture/damage     a warning TextLog on each frame decoded with errors
    /capture/network_skipped  an info TextLog on each live frame that reused the last frame's
                        network outputs to keep up (its maps are not logged again)
    /events             height-rule firings as a text log
    /status             the camera's calibration state (what the heights can be trusted for; with a
                        v2 network, the camera its heights were decoded with and the heads' spread)

Timelines: ``frame`` (source frame index) and ``time`` (source time, a duration).
"""

from __future__ import annotations

import os
import sys
import urllib.parse
import uuid
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from core.config import OutputConfig
from core.errors import ConfigError, HeightpipeError
from core.packets import OBJECT_CLASSES, FramePacket, HeightCamera, Track
from stages.sink_common import (BACKGROUND_MATCH_RGB, CLASS_COLORS_RGB, DAMAGE_TOPIC, NETWORK_SKIPPED_TOPIC,
                                OBJECT_MATCH_RGB, FrameEncoder, camera_state_text, check_output_config,
                                class_id, confirmed, damage_text, estimate_text, height_text,
                                network_skipped_text, quality_rgb, track_label)

APPLICATION_ID = "heightpipe"
RERUN_MODES = ("save", "spawn", "web", "serve")
WEB_VIEWER_PORT = 9090
"""rerun's default web viewer port (serve mode)."""
EVENT_RGB = (255, 40, 200)


@dataclass(frozen=True)
class RerunSinkConstants:
    """The rerun sink's fixed numbers (the rule is in docs/design.md, Configuration)."""

    viewer_memory_limit: str = "2GB"
    """Spawned viewer's limit: it drops the oldest data beyond this (its default, 75 % of RAM,
    would compete with the run for memory)."""
    flush_timeout_s: float = 30.0
    """close() waits at most this long for a viewer to take the last data: long enough for a
    viewer that is busy, short enough that a vanished one does not hang the run's end."""
    event_marker_s: float = 3.0
    """An event's marker stays on the frame this long (source time): long enough to catch the eye."""
    event_marker_pad_px: float = 6.0
    """The marker is a thick magenta frame this far around the object's box, clear of its own
    quality-coloured box."""


CONSTANTS = RerunSinkConstants()


def has_display() -> bool:
    if not sys.platform.startswith("linux"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def web_grpc_url(bind: str, grpc_port: int) -> str:
    """Where the run streams to a web viewer server on this machine (see pipeline/web_view.py)."""
    host = "127.0.0.1" if bind in ("0.0.0.0", "::", "") else bind
    return f"rerun+http://{host}:{grpc_port}/proxy"


def heightpipe_blueprint(scene_camera: bool = False) -> rrb.Blueprint:
    """The view's layout; ``scene_camera``: with a panel for the camera read from the scene."""
    right = [rrb.TimeSeriesView(name="Track height (m)", origin="/tracks"),
             rrb.TextLogView(name="Height-rule events", origin="/events"),
             rrb.TextLogView(name="Frame notes (damaged, network skipped)", origin="/capture"),
             rrb.TextDocumentView(name="Camera", origin="/status")]
    if scene_camera:
        right.append(rrb.Spatial2DView(name="Camera read from the scene (1.70 m bars)", origin="/scene_camera"))
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Spatial2DView(name="Frame: tracks, events, matches", origin="/camera"),
                rrb.Spatial2DView(name="Height map (m)", origin="/height"),
                row_shares=[3, 2]),
            rrb.Vertical(*right, row_shares=[5, 2, 1, 1, 3][:len(right)]),
            column_shares=[3, 2]),
        collapse_panels=True)


class RerunFrameLogger:
    """Logs one frame at a time to a RecordingStream from plain arrays.

    Call ``begin_frame``, the ``log_*`` methods for what the frame has, then ``end_frame``,
    which clears per-frame entities the frame lacks so stale boxes or arrows do not linger.
    """

    _PER_FRAME = ("/camera/ground", "/camera/matches", "/height")

    def __init__(self, rec: rr.RecordingStream, ground_overlay: bool = True, camera_note: str = ""):
        self.rec = rec
        self.ground_overlay = ground_overlay
        self.camera_note = camera_note
        """Said under the camera's state (the camera read from the scene, when one was)."""
        self._logged_now: set[str] = set()
        self._logged_before: set[str] = set()
        self._named_series: set[int] = set()
        self._coasting: set[int] = set()
        self._camera_key: tuple | None = None
        self._camera_state: str | None = None
        self._marker_until_s: float | None = None
        self._time_s = 0.0
        rec.log("/camera/ground", rr.AnnotationContext(
            [(0, "other", (0, 0, 0, 0)), (1, "ground", (0, 200, 255, 255))]), static=True)
        rec.log("/camera/tracks", rr.AnnotationContext(
            [(i, name, CLASS_COLORS_RGB[name]) for i, name in enumerate(OBJECT_CLASSES)]),
            static=True)

    def begin_frame(self, frame_index: int, time_s: float) -> None:
        self.rec.set_time("frame", sequence=int(frame_index))
        self.rec.set_time("time", duration=float(time_s))
        self._time_s = float(time_s)
        self._logged_now = set()
        if self._marker_until_s is not None and self._time_s >= self._marker_until_s:
            self.rec.log("/camera/events", rr.Clear(recursive=False))
            self._marker_until_s = None

    def end_frame(self) -> None:
        for path in self._logged_before - self._logged_now:
            self.rec.log(path, rr.Clear(recursive=False))
        self._logged_before = self._logged_now

    def keep(self, path: str) -> None:
        """Leave what ``path`` showed last in place this frame (a map stored every Nth frame only)."""
        if path in self._logged_before:
            self._logged_now.add(path)

    def _log(self, path: str, entity: object) -> None:
        self.rec.log(path, entity)
        if path in self._PER_FRAME:
            self._logged_now.add(path)

    def log_image(self, encoded: bytes, media_type: str = "image/jpeg") -> None:
        self._log("/camera/image", rr.EncodedImage(contents=encoded, media_type=media_type))

    def log_camera(self, K: np.ndarray, width: int, height: int) -> None:
        """Logs the pinhole only when it changes (self-calibration may refine it)."""
        key = (tuple(np.asarray(K, dtype=np.float64).ravel()), int(width), int(height))
        if key != self._camera_key:
            self._log("/camera", rr.Pinhole(image_from_camera=np.asarray(K, dtype=np.float32),
                                            resolution=[width, height]))
            self._camera_key = key

    def log_camera_state(self, source: str, height_camera: HeightCamera | None = None) -> None:
        """Writes what the camera's calibration state means for the heights, when it changes
        (with a v2 network: the camera its heights were decoded with, and the camera heads'
        uncertainty where they supplied it)."""
        state = camera_state_text(source, height_camera, frames=False)
        if self.camera_note:
            state += f"\n\n{self.camera_note}"
        if state != self._camera_state:
            self._log("/status", rr.TextDocument(f"**Camera:** {state}", media_type="text/markdown"))
            self._camera_state = state

    def log_ground_mask(self, mask: np.ndarray) -> None:
        """``mask``: H x W, nonzero = ground, in frame pixels (only with ``ground_overlay``)."""
        if not self.ground_overlay:
            return
        labels = mask.view(np.uint8) if mask.dtype == np.bool_ else (mask != 0).view(np.uint8)
        self._log("/camera/ground", rr.SegmentationImage(labels, opacity=0.2))

    def log_height_mm(self, height_mm: np.ndarray) -> None:
        """``height_mm``: uint16 millimetres above the ground (possibly downscaled)."""
        self._log("/height", rr.DepthImage(height_mm, meter=1000.0, colormap="turbo"))

    def log_matches(self, prev_pts: np.ndarray, curr_pts: np.ndarray, on_object: np.ndarray) -> None:
        prev = np.asarray(prev_pts, dtype=np.float32).reshape(-1, 2)
        curr = np.asarray(curr_pts, dtype=np.float32).reshape(-1, 2)
        colors = np.where(np.asarray(on_object, dtype=bool).reshape(-1, 1),
                          np.uint8(OBJECT_MATCH_RGB), np.uint8(BACKGROUND_MATCH_RGB))
        self._log("/camera/matches", rr.Arrows2D(origins=prev, vectors=curr - prev, colors=colors))

    def log_damage(self, text: str) -> None:
        self.rec.log(DAMAGE_TOPIC, rr.TextLog(text, level=rr.TextLogLevel.WARN))

    def log_network_skipped(self, text: str) -> None:
        self.rec.log(NETWORK_SKIPPED_TOPIC, rr.TextLog(text, level=rr.TextLogLevel.INFO))

    def log_tracks(self, tracks: list[Track]) -> None:
        """Draws the confirmed ones; always logs (an empty list clears last frame's boxes).

        A coasting track (no detection this frame) keeps its box but its height series is
        cleared, so the plot shows a gap, not a flat line of predictions.
        """
        shown = confirmed(tracks)
        boxes = np.array([t.box for t in shown], dtype=np.float32).reshape(-1, 4)
        self.rec.log("/camera/tracks", rr.Boxes2D(
            array=boxes, array_format=rr.Box2DFormat.XYWH, labels=[track_label(t) for t in shown],
            colors=np.array([quality_rgb(t) for t in shown], dtype=np.uint8).reshape(-1, 3),
            class_ids=[class_id(t.cls) for t in shown], show_labels=True))
        for track in shown:
            path = f"/tracks/{track.track_id}/height"
            if track.track_id not in self._named_series:
                self.rec.log(path, rr.SeriesLines(names=f"#{track.track_id} {track.cls}"),
                             static=True)
                self._named_series.add(track.track_id)
            if not track.updated or not np.isfinite(track.height_m):
                if track.track_id not in self._coasting:
                    self.rec.log(path, rr.Clear(recursive=False))
                    self._coasting.add(track.track_id)
                continue
            self._coasting.discard(track.track_id)
            self.rec.log(path, rr.Scalars(track.height_m))

    def log_events(self, events: list[dict]) -> None:
        """Height-rule firings (``RuleEvent.to_dict()``): a text log line and a marker each."""
        if not events:
            return
        for event in events:
            text = (f"{event['rule']}: #{event['track_id']} {event['class']} "
                    f"{height_text(event['height_m'], event['height_std_m'])} ({event['height_source']})")
            self.rec.log("/events", rr.TextLog(text, level=rr.TextLogLevel.WARN))
        pad = CONSTANTS.event_marker_pad_px
        frames = []
        for event in events:  # the box is in source pixels, the image may be scaled down
            sx, sy = event.get("source_scale", (1.0, 1.0))
            x, y, w, h = event["box"]
            frames.append((x / sx - pad, y / sy - pad, w / sx + 2 * pad, h / sy + 2 * pad))
        self.rec.log("/camera/events", rr.Boxes2D(
            array=np.array(frames, dtype=np.float32), array_format=rr.Box2DFormat.XYWH,
            colors=[EVENT_RGB] * len(events), radii=2.0, labels=[e["rule"] for e in events],
            show_labels=True))
        self._marker_until_s = self._time_s + CONSTANTS.event_marker_s


def open_recording(recording_name: str) -> rr.RecordingStream:
    """A recording that sends every log call on as it comes, without rerun's chunk batcher.

    With the batcher (rerun 0.41's default) the process grew without bound on long runs: 30
    minutes of looped sample video went 444 -> 578 MB, the growth native (Python's traced memory
    flat) and gone with the rerun output off or without the per-track height series (the batcher
    keeps state per entity path it has seen; cf. rerun issue #12623). Unbatched, the 30-minute
    run grows less than half as much (401 -> 459 MB from minute 5 to 30) and the sample's .rrd
    is smaller (6.9 against 8.2 MB; the images dominate, and the batcher's chunks cost more
    than they save). The rest of the growth is the file sink's index (see ``writes_index``):
    without it the same run stays at 383 -> 388 MB.
    """
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=uuid.uuid4(),
                             batcher_config=rr.ChunkBatcherConfig.NEVER())
    rec.send_recording_name(recording_name)
    return rec


def writes_index(rrd_index: str, live: bool) -> bool:
    """Whether the .rrd gets rerun's index (footer) for ``output.rrd_index`` and this source.

    The file sink keeps one manifest row per chunk in memory until it writes the footer at the
    end (~1.4 kB each, a chunk per entity and flush): about 2 MB per minute of 640x360 video.
    A file's run ends, and its .rrd then seeks fast in the viewer; a live stream may not end,
    so by default its .rrd has no index and the process stays flat (the viewer reads such a
    file from the start, as it did every .rrd before rerun 0.31).
    """
    if rrd_index == "auto":
        return not live
    return rrd_index == "on"


def close_recording(rec: rr.RecordingStream) -> None:
    """Flushes every sink and finishes files (footer); a gone viewer only warns."""
    try:
        rec.flush(timeout_sec=CONSTANTS.flush_timeout_s)
    except RuntimeError as exc:  # e.g. the viewer window was closed: the file sink is still fine
        print(f"heightpipe: warning: rerun: {exc}", file=sys.stderr)
    rec.disconnect()


class RerunSink:
    """Writes PREFIX.rrd; in 'spawn', 'web' and 'serve' modes also streams to a viewer.

    'web' streams to the web viewer server at ``web_url`` (``pipeline.web_view`` starts it).
    """

    def __init__(self, path: Path, mode: str, config: OutputConfig, recording_name: str,
                 encoder: FrameEncoder | None = None, web_url: str | None = None,
                 live: bool = False, scene_camera: HeightCamera | None = None,
                 scene_picture: np.ndarray | None = None):
        if mode not in RERUN_MODES:
            raise ConfigError(f"output.rerun must be one of {', '.join(RERUN_MODES)} or off, "
                              f"got {mode!r}")
        if mode == "spawn" and not has_display():
            raise HeightpipeError("output.rerun=spawn needs a display for the viewer (none found: "
                                  "DISPLAY/WAYLAND_DISPLAY unset); use 'serve' or 'save'")
        check_output_config(config)
        self.path = Path(path)
        self.encoder = encoder or FrameEncoder.from_config(config)
        self.rec = open_recording(recording_name)
        self.indexed = writes_index(config.rrd_index, live)
        blueprint = heightpipe_blueprint(scene_camera=scene_picture is not None)
        try:
            if mode == "save":
                self.rec.save(self.path, default_blueprint=blueprint, write_footer=self.indexed)
            elif mode == "spawn":
                self.rec.spawn(connect=False, memory_limit=CONSTANTS.viewer_memory_limit)
                self.rec.set_sinks(rr.GrpcSink(), self._file_sink(), default_blueprint=blueprint)
            elif mode == "web":
                if web_url is None:
                    raise ConfigError("output.rerun=web needs the web viewer server (started by "
                                      "`heightpipe run`); use 'save' or 'serve' here")
                self.rec.set_sinks(rr.GrpcSink(web_url), self._file_sink(),
                                   default_blueprint=blueprint)
            else:
                server = rr.GrpcServerSink()  # all interfaces, port 9876: viewable from elsewhere
                self.rec.set_sinks(server, self._file_sink(), default_blueprint=blueprint)
                uri = server.uri.replace("0.0.0.0", "127.0.0.1")
                rr.serve_web_viewer(web_port=WEB_VIEWER_PORT, connect_to=uri, open_browser=False)
                print(f"rerun: web viewer at http://127.0.0.1:{WEB_VIEWER_PORT}/?url="
                      f"{urllib.parse.quote(uri, safe=':/')} (native viewer: rerun {uri})",
                      file=sys.stderr)
        except (OSError, RuntimeError, ValueError) as exc:
            raise HeightpipeError(f"cannot start rerun output ({mode}): {exc}") from None
        note = (f"**Read from {scene_camera.frames} early frames** (camera height {scene_camera.height_m:.2f} m "
                f"given): {estimate_text(scene_camera)}" if scene_camera is not None else "")
        self.logger = RerunFrameLogger(self.rec, ground_overlay=config.ground_overlay, camera_note=note)
        if scene_picture is not None:
            jpeg = cv2.imencode(".jpg", scene_picture, [cv2.IMWRITE_JPEG_QUALITY, 85])[1].tobytes()
            self.rec.log("/scene_camera", rr.EncodedImage(contents=jpeg, media_type="image/jpeg"), static=True)
        self.flush_interval_s = config.flush_interval_s
        self._last_flush_s: float | None = None
        self._closed = False

    def _file_sink(self) -> rr.FileSink:
        return rr.FileSink(self.path, write_footer=self.indexed)

    def write(self, packet: FramePacket) -> None:
        log = self.logger
        log.begin_frame(packet.frame.index, packet.frame.time_s)
        log.log_image(self.encoder.jpeg(packet))
        camera = packet.camera
        log.log_camera_state(camera.source, packet.height_camera)
        if camera.K is not None:
            log.log_camera(camera.K, camera.width, camera.height)
        if not self.encoder.maps_due(packet):
            log.keep("/camera/ground")
            log.keep("/height")
        else:
            if packet.ground_mask is not None:
                log.log_ground_mask(packet.ground_mask)
            height_mm = self.encoder.height_mm(packet)
            if height_mm is not None:
                log.log_height_mm(height_mm)
        if packet.matches is not None:
            log.log_matches(packet.matches.prev_pts, packet.matches.curr_pts, packet.matches.on_object)
        log.log_tracks(packet.tracks)
        if packet.frame.damage:
            log.log_damage(damage_text(packet.frame))
        if packet.network_reused:
            log.log_network_skipped(network_skipped_text(packet.frame))
        log.log_events([event.to_dict() for event in packet.events])
        log.end_frame()
        self._flush_if_due(packet.frame.time_s)

    def _flush_if_due(self, time_s: float) -> None:
        """Pushes rerun's batches to the file every ``flush_interval_s`` of source time, so a hard
        kill costs about that much of the .rrd, as of the MCAP (200 sink-test frames at 10 fps,
        flush_interval_s 0.5: 196 frames readable on disk before close(); 59 without flushing)."""
        if self._last_flush_s is None:
            self._last_flush_s = time_s
        elif time_s - self._last_flush_s >= self.flush_interval_s:
            try:
                self.rec.flush(timeout_sec=CONSTANTS.flush_timeout_s)
            except RuntimeError:  # a viewer gone or slow: the file sink has what it needs; close() reports
                pass
            self._last_flush_s = time_s

    def close(self) -> None:
        """Flushes and finishes the file (footer); idempotent."""
        if self._closed:
            return
        self._closed = True
        close_recording(self.rec)
