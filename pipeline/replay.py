"""``heightpipe replay FILE.mcap [--save OUT.rrd | --web]``: an MCAP recording in the rerun viewer.

rerun opens our MCAP files itself but draws neither the track boxes (foxglove
ImageAnnotations) nor the per-track height plots (custom protobuf), and shows the height map
as a plain image. Replay reads the MCAP and logs each frame through the same
``RerunFrameLogger`` as ``heightpipe run``, so the result matches the live ``.rrd``.

The file is read front to back with the linear reader, so an unfinished recording (killed
writer, no summary) replays up to its last complete chunk, with a warning. ``--web`` serves
rerun's web viewer as ``heightpipe run --rerun web`` does (``[web]`` in config.toml).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from core.config import Config
from core.errors import HeightpipeError

TOPICS = ("/tracks", "/camera/image", "/camera/calibration", "/camera/height", "/camera/ground",
          "/camera/matches", "/capture/damage", "/capture/network_skipped", "/events")
"""What replay draws; /camera/annotations is redundant with /tracks (boxes are redrawn)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("mcap", type=Path, metavar="FILE.mcap", help="recording written by `heightpipe run`")
    target = parser.add_mutually_exclusive_group()
    target.add_argument("--save", type=Path, metavar="OUT.rrd",
                        help="write a .rrd file instead of opening the viewer (headless)")
    target.add_argument("--web", action="store_true",
                        help="serve rerun's web viewer as set in [web] (headless; loopback by default) "
                             "and keep serving until Ctrl-C")


def main(args: argparse.Namespace, config: Config) -> int:
    path: Path = args.mcap
    if not path.is_file():
        raise HeightpipeError(f"MCAP file not found: {path}")
    if args.save is not None and not args.save.parent.is_dir():
        raise HeightpipeError(f"output folder does not exist: {args.save.parent}")
    if not args.web:
        result = replay_mcap(path, args.save, config.output.ground_overlay)
        _report(path, result, args.save if args.save is not None else "the rerun viewer")
        return 0

    from pipeline.web_view import WebViewer

    with WebViewer(config.web) as viewer:
        result = replay_mcap(path, None, config.output.ground_overlay, web_url=viewer.grpc_url)
        _report(path, result, viewer.page_url)
        if config.web.keep_serving:
            viewer.wait_for_ctrl_c()
    return 0


def _report(path: Path, result: ReplayResult, target: object) -> None:
    print(f"replayed {result.frames} frames from {path} to {target}", file=sys.stderr, flush=True)
    if result.error:
        print(f"heightpipe: warning: {path} ends early ({result.error}); the recording was "
              f"probably not closed: replayed the {result.frames} complete frames "
              f"(`heightpipe recover {path}` rewrites it as a valid MCAP)", file=sys.stderr)


@dataclass
class ReplayResult:
    frames: int
    error: str = ""
    """Why reading stopped before the end of the file ("" = read to the end)."""


@dataclass
class _FrameMessages:
    log_time: int
    by_topic: dict[str, Any] = field(default_factory=dict)
    maps_every: int = 1
    """The recording stored height maps of every Nth frame only (``output.height_map_every``)."""


class _TruncatedMcap(Exception):
    """Reading failed part-way: the file is cut off or corrupt from here on."""


def replay_mcap(path: Path, save: Path | None, ground_overlay: bool = False,
                web_url: str | None = None) -> ReplayResult:
    """Logs every frame of ``path`` to a new rerun recording: ``save`` (.rrd), the web viewer
    server at ``web_url``, or a spawned viewer."""
    from stages.rerun_sink import (CONSTANTS, RerunFrameLogger, close_recording,
                                   has_display, heightpipe_blueprint, open_recording)
    import rerun as rr

    if save is None and web_url is None and not has_display():
        raise HeightpipeError("no display for the rerun viewer (DISPLAY/WAYLAND_DISPLAY unset); "
                              "use --save OUT.rrd")

    frames = _read_frames(path)
    try:
        first = next(frames)
    except StopIteration:
        raise HeightpipeError(f"{path} has no heightpipe frames (topics: {', '.join(TOPICS)})") from None
    except _TruncatedMcap as exc:
        raise HeightpipeError(f"cannot read MCAP {path}: {exc}") from None

    rec = open_recording(path.stem)
    if save is not None:
        rec.save(save, default_blueprint=heightpipe_blueprint())
    elif web_url is not None:
        rec.set_sinks(rr.GrpcSink(web_url), default_blueprint=heightpipe_blueprint())
    else:
        rec.spawn(memory_limit=CONSTANTS.viewer_memory_limit, default_blueprint=heightpipe_blueprint())
    logger = RerunFrameLogger(rec, ground_overlay=ground_overlay)
    count, error = 0, ""
    try:
        frame = first
        while frame is not None:
            _log_frame(logger, frame, count, first.log_time)
            count += 1
            try:
                frame = next(frames, None)
            except _TruncatedMcap as exc:
                error, frame = str(exc), None
    finally:
        close_recording(rec)
    return ReplayResult(frames=count, error=error)


def _read_frames(path: Path) -> Iterator[_FrameMessages]:
    """Messages grouped by log_time (one frame each), raising _TruncatedMcap on a read failure.

    Read in file order through ``pipeline.recover.linear_records``, the reader that
    ``heightpipe recover`` rewrites an unfinished recording with: the same frames either way.
    """
    from mcap.records import Channel, Message, Schema
    from mcap_protobuf.decoder import DecoderFactory

    from pipeline.recover import UnreadableTail, linear_records

    decoders, schemas, channels = DecoderFactory(), {}, {}
    current: _FrameMessages | None = None
    maps_every = 1
    with open(path, "rb") as stream:
        try:
            for record in linear_records(stream):
                if isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Message) and record.channel_id in channels:
                    channel = channels[record.channel_id]
                    if channel.topic not in TOPICS:
                        continue
                    decode = _decoder(decoders, channel, schemas.get(channel.schema_id))
                    if decode is None:
                        continue
                    if current is None or record.log_time != current.log_time:
                        if current is not None:
                            yield current
                        current = _FrameMessages(record.log_time)
                    if channel.topic == "/camera/height":
                        maps_every = max(1, int(channel.metadata.get("every", "1")))
                    current.maps_every = maps_every
                    if channel.topic == "/events":  # several events may share a frame
                        current.by_topic.setdefault("/events", []).append(decode(record.data))
                    else:
                        current.by_topic[channel.topic] = decode(record.data)
        except UnreadableTail as exc:
            if current is not None:  # its messages are all there that recovery would keep
                yield current
            raise _TruncatedMcap(str(exc)) from None
        except Exception as exc:  # protobuf errors on bad message bytes
            raise _TruncatedMcap(f"{type(exc).__name__}: {exc}") from None
    if current is not None:
        yield current


def _decoder(protobuf: Any, channel: Any, schema: Any) -> Any:
    """Protobuf channels through mcap_protobuf; heightpipe's JSON /events to dicts."""
    if channel.message_encoding == "json":
        import json

        return json.loads
    return protobuf.decoder_for(channel.message_encoding, schema)


def _log_frame(logger: Any, frame: _FrameMessages, ordinal: int, first_log_time: int) -> None:
    import numpy as np

    from stages.sink_common import height_to_mm
    from stages.track_record import tracks_from_record

    messages = frame.by_topic
    record = messages.get("/tracks")
    if record is not None:
        logger.begin_frame(record.frame_index, record.time_s)
    else:  # not written by heightpipe: number the frames and time them from the first
        logger.begin_frame(ordinal, (frame.log_time - first_log_time) / 1e9)

    if (image := messages.get("/camera/image")) is not None:
        media_type = "image/png" if image.format.lower() == "png" else "image/jpeg"
        logger.log_image(bytes(image.data), media_type)
    if (calibration := messages.get("/camera/calibration")) is not None and any(calibration.K):
        logger.log_camera(np.array(calibration.K, dtype=np.float64).reshape(3, 3),
                          calibration.width, calibration.height)
    skipped = messages.get("/capture/network_skipped")
    if skipped is not None or (record is not None and record.frame_index % frame.maps_every):
        logger.keep("/height")  # between stored maps, or the network skipped: keep the last
        logger.keep("/camera/ground")
    if (height := messages.get("/camera/height")) is not None:
        pixels = _raw_pixels(height)
        logger.log_height_mm(pixels if pixels.dtype == np.uint16 else height_to_mm(pixels, 1))
    if (ground := messages.get("/camera/ground")) is not None:
        logger.log_ground_mask(_raw_pixels(ground) >= 128)
    if (matches := messages.get("/camera/matches")) is not None:
        logger.log_matches(*_match_arrays(matches))
    if record is not None:
        logger.log_tracks(tracks_from_record(record))
    if (damage := messages.get("/capture/damage")) is not None:
        logger.log_damage(damage.message)
    if skipped is not None:
        logger.log_network_skipped(skipped.message)
    logger.log_events(messages.get("/events", []))
    logger.end_frame()


def _raw_pixels(image: Any) -> Any:
    """foxglove.RawImage (16UC1/mono16 millimetres, mono8, 32FC1 metres) -> H x W array."""
    import numpy as np

    dtypes = {"16UC1": "<u2", "mono16": "<u2", "mono8": "u1", "8UC1": "u1", "32FC1": "<f4"}
    if image.encoding not in dtypes:
        raise HeightpipeError(f"unsupported RawImage encoding {image.encoding!r} in replay")
    dtype = np.dtype(dtypes[image.encoding])
    rows = np.frombuffer(image.data, dtype=np.uint8).reshape(image.height, image.step)
    pixels = rows[:, :image.width * dtype.itemsize].copy().view(dtype)
    return pixels.astype(dtype.newbyteorder("="), copy=False)


def _match_arrays(annotations: Any) -> tuple[Any, Any, Any]:
    """/camera/matches LINE_LISTs -> prev points, current points, on-object flags."""
    import numpy as np
    from foxglove.messages import PointsAnnotationType

    from stages.sink_common import MATCH_KIND_KEY

    prev, curr = [np.zeros((0, 2), np.float32)], [np.zeros((0, 2), np.float32)]
    on_object = [np.zeros(0, bool)]
    for group in annotations.points:
        if group.type != PointsAnnotationType.LineList.value:
            continue
        kind = next((item.value for item in group.metadata if item.key == MATCH_KIND_KEY), "")
        points = [(p.x, p.y) for p in group.points]
        pairs = np.array(points[:len(points) // 2 * 2], dtype=np.float32).reshape(-1, 2, 2)
        prev.append(pairs[:, 0])
        curr.append(pairs[:, 1])
        on_object.append(np.full(len(pairs), kind == "object"))
    return np.concatenate(prev), np.concatenate(curr), np.concatenate(on_object)
