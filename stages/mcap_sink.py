"""MCAP output with Foxglove schemas, so Foxglove and rerun open PREFIX.mcap directly.

Topics (all messages of one frame share one log_time = recording start, wall-clock Unix
epoch ns, + the frame's source time):

    /tracks               heightpipe.TrackArray (stages/track_record.py), one per frame, first
    /camera/image         foxglove.CompressedImage, JPEG
    /camera/calibration   foxglove.CameraCalibration, when the intrinsics are known
    /camera/height        foxglove.RawImage 16UC1: height above ground in millimetres, at
                          1/height_map_scale of the frame size
    /camera/ground        foxglove.RawImage mono8: 255 = ground plane, full frame size
    /camera/annotations   foxglove.ImageAnnotations: confirmed tracks' boxes and labels
    /camera/matches       foxglove.ImageAnnotations: matched features as prev->curr segments
    /capture/damage       foxglove.Log (warning), only on frames decoded with errors: why
    /capture/network_skipped  foxglove.Log (info), only on live frames that reused the last
                          frame's network outputs to keep up (no height or ground map stored on them)
    /events               JSON (schema heightpipe.RuleEvent): height-rule firings, at their frame

Written with foxglove-sdk (Rust; about twice as fast as the pure-Python mcap writer). Crash
safety: zstd chunks of at most ``mcap_chunk_size`` bytes, and the open chunk is closed at
least every ``flush_interval_s`` of source time, so after a kill -9 a linear reader
(``mcap.stream_reader``, ``rerun mcap convert --recover``) gets all but the last interval.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import foxglove
import numpy as np
from foxglove.channels import (CameraCalibrationChannel, CompressedImageChannel,
                               ImageAnnotationsChannel, LogChannel, RawImageChannel)
from foxglove.mcap import MCAPCompression, MCAPWriteOptions
from foxglove.messages import (CameraCalibration, Color, CompressedImage, ImageAnnotations,
                               KeyValuePair, Log, LogLevel, Point2, PointsAnnotation,
                               PointsAnnotationType,
                               RawImage, TextAnnotation, Timestamp)

from core.config import OutputConfig
from core.errors import HeightpipeError
from core.packets import CameraInfo, FeatureMatches, FramePacket, Track
from stages.height_rules import EVENT_JSON_SCHEMA
from stages.sink_common import (BACKGROUND_MATCH_RGB, DAMAGE_TOPIC, MATCH_KIND_KEY, NETWORK_SKIPPED_TOPIC,
                                OBJECT_MATCH_RGB, FrameEncoder, check_output_config, confirmed, damage_text,
                                network_skipped_text, quality_rgb, track_label)
from stages.track_record import SCHEMA_NAME, build_track_record_type, encode_track_array

FRAME_ID = "camera"
METADATA_NAME = "heightpipe"
"""Name of the MCAP metadata record holding the recording name, start time and units."""

_WHITE = Color(r=1.0, g=1.0, b=1.0, a=1.0)


def _color(rgb: tuple[int, int, int], alpha: float = 1.0) -> Color:
    return Color(r=rgb[0] / 255, g=rgb[1] / 255, b=rgb[2] / 255, a=alpha)


class McapSink:
    """Writes PREFIX.mcap; ``close()`` writes the summary (index) section."""

    def __init__(self, path: Path, config: OutputConfig, encoder: FrameEncoder | None = None,
                 recording_name: str = ""):
        check_output_config(config)
        self.path = Path(path)
        self.encoder = encoder or FrameEncoder.from_config(config)
        self.flush_interval_s = config.flush_interval_s
        self.start_epoch_ns = time.time_ns()
        self._context = foxglove.Context()
        # Compress in the logging thread: the pipeline stages need the other core.
        options = MCAPWriteOptions(compression=MCAPCompression.Zstd,
                                   chunk_size=config.mcap_chunk_size, compression_threads=0)
        try:
            self._writer = foxglove.open_mcap(self.path, allow_overwrite=True,
                                              context=self._context, writer_options=options)
        except Exception as exc:  # the Rust side raises its own FoxgloveError on I/O failures
            raise HeightpipeError(f"cannot write MCAP {self.path}: {exc}") from None
        self._writer.write_metadata(METADATA_NAME, {
            "recording_name": recording_name or self.path.stem,
            "start_epoch_ns": str(self.start_epoch_ns),
            "height_unit": "mm",
            "height_map_scale": str(self.encoder.height_map_scale),
        })
        self._record_type = build_track_record_type()
        context = self._context
        self._tracks = foxglove.Channel(
            "/tracks", message_encoding="protobuf", context=context,
            schema=foxglove.Schema(name=SCHEMA_NAME, encoding="protobuf",
                                   data=self._record_type.file_descriptor_set))
        self._image = CompressedImageChannel("/camera/image", context=context)
        self._calibration = CameraCalibrationChannel("/camera/calibration", context=context)
        self._height = RawImageChannel("/camera/height", context=context, metadata={
            "unit": "mm", "scale": "0.001 m per count", "quantity": "height above ground",
            "downscale": str(self.encoder.height_map_scale), "every": str(self.encoder.height_map_every)})
        self._ground = RawImageChannel("/camera/ground", context=context,
                                       metadata={"values": "255 = ground plane, 0 = other"})
        self._annotations = ImageAnnotationsChannel("/camera/annotations", context=context)
        self._matches = ImageAnnotationsChannel("/camera/matches", context=context)
        self._damage = LogChannel(DAMAGE_TOPIC, context=context)
        self._network_skipped = LogChannel(NETWORK_SKIPPED_TOPIC, context=context)
        self._events = foxglove.Channel(
            "/events", message_encoding="json", context=context,
            schema=foxglove.Schema(name=EVENT_JSON_SCHEMA["title"], encoding="jsonschema",
                                   data=json.dumps(EVENT_JSON_SCHEMA).encode()))
        self._last_log_time = 0
        self._last_flush_s: float | None = None
        self._closed = False

    def log_time_ns(self, time_s: float) -> int:
        """Epoch ns of a frame; strictly increasing so each frame has its own log_time."""
        log_time = max(self.start_epoch_ns + round(time_s * 1e9), self._last_log_time + 1)
        self._last_log_time = log_time
        return log_time

    def write(self, packet: FramePacket) -> None:
        frame = packet.frame
        log_time = self.log_time_ns(frame.time_s)
        stamp = Timestamp(*divmod(log_time, 1_000_000_000))
        self._tracks.log(encode_track_array(self._record_type, log_time, frame.index, frame.time_s,
                                            packet.tracks), log_time=log_time)
        self._image.log(CompressedImage(timestamp=stamp, frame_id=FRAME_ID,
                                        data=self.encoder.jpeg(packet), format="jpeg"),
                        log_time=log_time)
        if packet.camera.K is not None:
            self._calibration.log(_calibration(packet.camera, stamp), log_time=log_time)
        maps_due = self.encoder.maps_due(packet)
        height_mm = self.encoder.height_mm(packet) if maps_due else None
        if height_mm is not None:
            self._height.log(_raw_image(height_mm.astype("<u2", copy=False), "16UC1", stamp),
                             log_time=log_time)
        if packet.ground_mask is not None and maps_due:
            mask = packet.ground_mask
            ground = (mask if mask.dtype == np.bool_ else mask != 0).view(np.uint8) * np.uint8(255)
            self._ground.log(_raw_image(ground, "mono8", stamp), log_time=log_time)
        self._annotations.log(_track_annotations(confirmed(packet.tracks), stamp), log_time=log_time)
        if packet.matches is not None:
            self._matches.log(_match_annotations(packet.matches, stamp), log_time=log_time)
        if frame.damage:
            self._damage.log(Log(timestamp=stamp, level=LogLevel.Warning, name="capture",
                                 message=damage_text(frame)), log_time=log_time)
        if packet.network_reused:
            self._network_skipped.log(Log(timestamp=stamp, level=LogLevel.Info, name="network",
                                          message=network_skipped_text(frame)), log_time=log_time)
        for event in packet.events:
            self._events.log(event.to_dict(), log_time=log_time)
        self._flush_if_due(frame.time_s)

    def _flush_if_due(self, time_s: float) -> None:
        if self._last_flush_s is None:
            self._last_flush_s = time_s
        elif time_s - self._last_flush_s >= self.flush_interval_s:
            self._writer.flush()
            self._last_flush_s = time_s

    def close(self) -> None:
        """Finishes the open chunk and writes the summary; idempotent."""
        if self._closed:
            return
        self._closed = True
        self._writer.close()


def _raw_image(pixels: np.ndarray, encoding: str, stamp: Timestamp) -> RawImage:
    rows, cols = pixels.shape[:2]
    return RawImage(timestamp=stamp, frame_id=FRAME_ID, width=cols, height=rows,
                    encoding=encoding, step=cols * pixels.itemsize,
                    data=np.ascontiguousarray(pixels).tobytes())


def _calibration(camera: CameraInfo, stamp: Timestamp) -> CameraCalibration:
    K = np.asarray(camera.K, dtype=np.float64)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    dist = [] if camera.dist is None else [float(v) for v in np.ravel(camera.dist)]
    return CameraCalibration(
        timestamp=stamp, frame_id=FRAME_ID, width=camera.width, height=camera.height,
        distortion_model=("plumb_bob" if len(dist) <= 5 else "rational_polynomial") if dist else "",
        D=dist, K=[float(v) for v in K.ravel()], R=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        P=[fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0])


def _track_annotations(tracks: list[Track], stamp: Timestamp) -> ImageAnnotations:
    boxes, labels = [], []
    for track in tracks:
        x, y, w, h = (float(v) for v in track.box)
        rgb = quality_rgb(track)
        boxes.append(PointsAnnotation(
            timestamp=stamp, type=PointsAnnotationType.LineLoop, thickness=2.0,
            outline_color=_color(rgb),
            points=[Point2(x=x, y=y), Point2(x=x + w, y=y), Point2(x=x + w, y=y + h),
                    Point2(x=x, y=y + h)]))
        labels.append(TextAnnotation(
            timestamp=stamp, position=Point2(x=x, y=max(0.0, y - 2.0)), text=track_label(track),
            font_size=12.0, text_color=_WHITE, background_color=_color(rgb, 0.7)))
    return ImageAnnotations(timestamp=stamp, points=boxes, texts=labels)


def _match_annotations(matches: FeatureMatches, stamp: Timestamp) -> ImageAnnotations:
    """One LINE_LIST (prev0, curr0, prev1, curr1, ...) each for object and background matches."""
    prev = np.asarray(matches.prev_pts, dtype=np.float64).reshape(-1, 2)
    curr = np.asarray(matches.curr_pts, dtype=np.float64).reshape(-1, 2)
    on_object = np.asarray(matches.on_object, dtype=bool).reshape(-1)
    groups = []
    for kind, selected, rgb in (("object", on_object, OBJECT_MATCH_RGB),
                                ("background", ~on_object, BACKGROUND_MATCH_RGB)):
        segments = np.stack([prev[selected], curr[selected]], axis=1).reshape(-1, 2).tolist()
        groups.append(PointsAnnotation(
            timestamp=stamp, type=PointsAnnotationType.LineList, thickness=1.0,
            outline_color=_color(rgb), points=[Point2(x=x, y=y) for x, y in segments],
            metadata=[KeyValuePair(key=MATCH_KIND_KEY, value=kind)]))
    return ImageAnnotations(timestamp=stamp, points=groups)
