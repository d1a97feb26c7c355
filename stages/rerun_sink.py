"""Rerun output: a ``.rrd`` file (optionally also a live viewer) with an embedded layout.

``RerunFrameLogger`` turns one frame's plain arrays into rerun entities; ``RerunSink`` feeds it
from FramePackets and ``heightpipe replay`` feeds it from an MCAP file, so both produce the
same recording. Entities:

    /camera             Pinhole (when the intrinsics are known)
    /camera/image       the frame, JPEG
    /camera/ground      ground mask overlay (SegmentationImage)
    /camera/matches     matched features, arrows from the previous to this frame
    /camera/tracks      confirmed tracks: boxes, labels "#id 1.72±0.04 m", class colours
    /height             height map in millimetres, shown colour-mapped in metres
    /tracks/<id>/height one height time series per confirmed track

Timelines: ``frame`` (source frame index) and ``time`` (source time, a duration).
"""

from __future__ import annotations

import os
import sys
import urllib.parse
import uuid
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from core.config import OutputConfig
from core.errors import ConfigError, HeightpipeError
from core.packets import OBJECT_CLASSES, FramePacket, Track
from stages.sink_common import (BACKGROUND_MATCH_RGB, CLASS_COLORS_RGB, OBJECT_MATCH_RGB,
                                FrameEncoder, check_output_config, class_id, confirmed,
                                track_label)

APPLICATION_ID = "heightpipe"
VIEWER_MEMORY_LIMIT = "2GB"
"""Spawned viewer's limit: it drops the oldest data beyond this (its default is 75% of RAM)."""
RERUN_MODES = ("save", "spawn", "serve")
WEB_VIEWER_PORT = 9090
"""rerun's default web viewer port (serve mode)."""
FLUSH_TIMEOUT_S = 30.0
"""close() waits at most this long for a viewer to take the last data."""


def has_display() -> bool:
    if not sys.platform.startswith("linux"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def heightpipe_blueprint() -> rrb.Blueprint:
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Spatial2DView(name="Frame: tracks, ground, matches", origin="/camera"),
                rrb.Spatial2DView(name="Height map (m)", origin="/height"),
                row_shares=[3, 2]),
            rrb.TimeSeriesView(name="Track height (m)", origin="/tracks"),
            column_shares=[3, 2]),
        collapse_panels=True)


class RerunFrameLogger:
    """Logs one frame at a time to a RecordingStream from plain arrays.

    Call ``begin_frame``, the ``log_*`` methods for what the frame has, then ``end_frame``,
    which clears per-frame entities the frame lacks so stale boxes or arrows do not linger.
    """

    _PER_FRAME = ("/camera/ground", "/camera/matches", "/height")

    def __init__(self, rec: rr.RecordingStream):
        self.rec = rec
        self._logged_now: set[str] = set()
        self._logged_before: set[str] = set()
        self._named_series: set[int] = set()
        self._camera_key: tuple | None = None
        rec.log("/camera/ground", rr.AnnotationContext(
            [(0, "other", (0, 0, 0, 0)), (1, "ground", (0, 230, 90, 255))]), static=True)
        rec.log("/camera/tracks", rr.AnnotationContext(
            [(i, name, CLASS_COLORS_RGB[name]) for i, name in enumerate(OBJECT_CLASSES)]),
            static=True)

    def begin_frame(self, frame_index: int, time_s: float) -> None:
        self.rec.set_time("frame", sequence=int(frame_index))
        self.rec.set_time("time", duration=float(time_s))
        self._logged_now = set()

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

    def log_ground_mask(self, mask: np.ndarray) -> None:
        """``mask``: H x W, nonzero = ground, in frame pixels."""
        labels = mask.view(np.uint8) if mask.dtype == np.bool_ else (mask != 0).view(np.uint8)
        self._log("/camera/ground", rr.SegmentationImage(labels, opacity=0.35))

    def log_height_mm(self, height_mm: np.ndarray) -> None:
        """``height_mm``: uint16 millimetres above the ground (possibly downscaled)."""
        self._log("/height", rr.DepthImage(height_mm, meter=1000.0, colormap="turbo"))

    def log_matches(self, prev_pts: np.ndarray, curr_pts: np.ndarray, on_object: np.ndarray) -> None:
        prev = np.asarray(prev_pts, dtype=np.float32).reshape(-1, 2)
        curr = np.asarray(curr_pts, dtype=np.float32).reshape(-1, 2)
        colors = np.where(np.asarray(on_object, dtype=bool).reshape(-1, 1),
                          np.uint8(OBJECT_MATCH_RGB), np.uint8(BACKGROUND_MATCH_RGB))
        self._log("/camera/matches", rr.Arrows2D(origins=prev, vectors=curr - prev, colors=colors))

    def log_tracks(self, tracks: list[Track]) -> None:
        """Draws the confirmed ones; always logs (an empty list clears last frame's boxes)."""
        shown = confirmed(tracks)
        boxes = np.array([t.box for t in shown], dtype=np.float32).reshape(-1, 4)
        self.rec.log("/camera/tracks", rr.Boxes2D(
            array=boxes, array_format=rr.Box2DFormat.XYWH, labels=[track_label(t) for t in shown],
            class_ids=[class_id(t.cls) for t in shown], show_labels=True))
        for track in shown:
            path = f"/tracks/{track.track_id}/height"
            if track.track_id not in self._named_series:
                self.rec.log(path, rr.SeriesLines(names=f"#{track.track_id} ({track.cls})"),
                             static=True)
                self._named_series.add(track.track_id)
            self.rec.log(path, rr.Scalars(track.height_m))


def open_recording(recording_name: str) -> rr.RecordingStream:
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=uuid.uuid4())
    rec.send_recording_name(recording_name)
    return rec


def close_recording(rec: rr.RecordingStream) -> None:
    """Flushes every sink and finishes files (footer); a gone viewer only warns."""
    try:
        rec.flush(timeout_sec=FLUSH_TIMEOUT_S)
    except RuntimeError as exc:  # e.g. the viewer window was closed: the file sink is still fine
        print(f"heightpipe: warning: rerun: {exc}", file=sys.stderr)
    rec.disconnect()


class RerunSink:
    """Writes PREFIX.rrd; in 'spawn' and 'serve' modes also streams to a viewer."""

    def __init__(self, path: Path, mode: str, config: OutputConfig, recording_name: str,
                 encoder: FrameEncoder | None = None):
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
        blueprint = heightpipe_blueprint()
        try:
            if mode == "save":
                self.rec.save(self.path, default_blueprint=blueprint)
            elif mode == "spawn":
                self.rec.spawn(connect=False, memory_limit=VIEWER_MEMORY_LIMIT)
                self.rec.set_sinks(rr.GrpcSink(), rr.FileSink(self.path), default_blueprint=blueprint)
            else:
                server = rr.GrpcServerSink()  # all interfaces, port 9876: viewable from elsewhere
                self.rec.set_sinks(server, rr.FileSink(self.path), default_blueprint=blueprint)
                uri = server.uri.replace("0.0.0.0", "127.0.0.1")
                rr.serve_web_viewer(web_port=WEB_VIEWER_PORT, connect_to=uri, open_browser=False)
                print(f"rerun: web viewer at http://127.0.0.1:{WEB_VIEWER_PORT}/?url="
                      f"{urllib.parse.quote(uri, safe=':/')} (native viewer: rerun {uri})",
                      file=sys.stderr)
        except (OSError, RuntimeError, ValueError) as exc:
            raise HeightpipeError(f"cannot start rerun output ({mode}): {exc}") from None
        self.logger = RerunFrameLogger(self.rec)
        self._closed = False

    def write(self, packet: FramePacket) -> None:
        log = self.logger
        log.begin_frame(packet.frame.index, packet.frame.time_s)
        log.log_image(self.encoder.jpeg(packet))
        camera = packet.camera
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
        log.end_frame()

    def close(self) -> None:
        """Flushes and finishes the file (footer); idempotent."""
        if self._closed:
            return
        self._closed = True
        close_recording(self.rec)
