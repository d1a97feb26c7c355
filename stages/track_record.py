"""The ``heightpipe.TrackArray`` protobuf record written to MCAP ``/tracks``, one per frame.

The schema is built at run time from a FileDescriptorProto (no protoc step, no generated
code to keep in sync) and stored in the MCAP as a FileDescriptorSet, so Foxglove, rerun and
``mcap_protobuf`` decode it without this module. One message per processed frame, even with
no tracks, so a reader learns each frame's source index and time from it.

    message TrackArray {
      google.protobuf.Timestamp timestamp = 1;  // capture time (Unix epoch), = MCAP log_time
      uint64 frame_index = 2;                   // source frame index
      double time_s = 3;                        // source time from the start of the video
      repeated Track tracks = 4;                // confirmed and tentative tracks
    }
    message Track {
      uint32 id = 1;  Box box = 2;  string class_name = 3;  double height_m = 4;
      double height_std_m = 5;  GroundPosition ground_position = 6;  // unset: not calibrated
      bool confirmed = 7;  string height_source = 8;  double score = 9;
      string box_source = 10;                   // detected, interpolated or predicted
    }
    message Box { double x = 1; double y = 2; double width = 3; double height = 4; }  // pixels
    message GroundPosition { double x_m = 1; double y_m = 2; }  // world metres
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory, timestamp_pb2

from core.packets import Track

SCHEMA_NAME = "heightpipe.TrackArray"
_FILE_NAME = "heightpipe/track_array.proto"

_F = descriptor_pb2.FieldDescriptorProto
_MESSAGES: dict[str, list[tuple[str, int, int, str]]] = {
    # message: [(field, number, type, message type name or "")]
    "Box": [("x", 1, _F.TYPE_DOUBLE, ""), ("y", 2, _F.TYPE_DOUBLE, ""),
            ("width", 3, _F.TYPE_DOUBLE, ""), ("height", 4, _F.TYPE_DOUBLE, "")],
    "GroundPosition": [("x_m", 1, _F.TYPE_DOUBLE, ""), ("y_m", 2, _F.TYPE_DOUBLE, "")],
    "Track": [("id", 1, _F.TYPE_UINT32, ""), ("box", 2, _F.TYPE_MESSAGE, ".heightpipe.Box"),
              ("class_name", 3, _F.TYPE_STRING, ""), ("height_m", 4, _F.TYPE_DOUBLE, ""),
              ("height_std_m", 5, _F.TYPE_DOUBLE, ""),
              ("ground_position", 6, _F.TYPE_MESSAGE, ".heightpipe.GroundPosition"),
              ("confirmed", 7, _F.TYPE_BOOL, ""), ("height_source", 8, _F.TYPE_STRING, ""),
              ("score", 9, _F.TYPE_DOUBLE, ""), ("box_source", 10, _F.TYPE_STRING, "")],
    "TrackArray": [("timestamp", 1, _F.TYPE_MESSAGE, ".google.protobuf.Timestamp"),
                   ("frame_index", 2, _F.TYPE_UINT64, ""), ("time_s", 3, _F.TYPE_DOUBLE, ""),
                   ("tracks", 4, _F.TYPE_MESSAGE, ".heightpipe.Track")],
}


def _file_descriptor() -> descriptor_pb2.FileDescriptorProto:
    proto = descriptor_pb2.FileDescriptorProto(
        name=_FILE_NAME, package="heightpipe", syntax="proto3",
        dependency=[timestamp_pb2.DESCRIPTOR.name])
    for message_name, fields in _MESSAGES.items():
        message = proto.message_type.add(name=message_name)
        for name, number, field_type, type_name in fields:
            label = _F.LABEL_REPEATED if name == "tracks" else _F.LABEL_OPTIONAL
            message.field.add(name=name, number=number, type=field_type, label=label,
                              type_name=type_name or None, json_name=name)
    return proto


@dataclass
class TrackRecordType:
    """The message classes of one private descriptor pool (no protobuf global registry)."""

    track_array: Any
    file_descriptor_set: bytes
    """Serialized FileDescriptorSet: the MCAP schema data."""


def build_track_record_type() -> TrackRecordType:
    timestamp_file = descriptor_pb2.FileDescriptorProto()
    timestamp_pb2.DESCRIPTOR.CopyToProto(timestamp_file)
    track_file = _file_descriptor()
    pool = descriptor_pool.DescriptorPool()
    pool.Add(timestamp_file)
    pool.Add(track_file)
    descriptor_set = descriptor_pb2.FileDescriptorSet(file=[timestamp_file, track_file])
    return TrackRecordType(
        track_array=message_factory.GetMessageClass(pool.FindMessageTypeByName(SCHEMA_NAME)),
        file_descriptor_set=descriptor_set.SerializeToString())


def encode_track_array(record_type: TrackRecordType, log_time_ns: int, frame_index: int,
                       time_s: float, tracks: list[Track]) -> bytes:
    message = record_type.track_array(frame_index=frame_index, time_s=time_s)
    message.timestamp.seconds, message.timestamp.nanos = divmod(log_time_ns, 1_000_000_000)
    for track in tracks:
        item = message.tracks.add(
            id=track.track_id, class_name=track.cls, height_m=track.height_m,
            height_std_m=track.height_std_m, confirmed=track.confirmed,
            height_source=track.height_source, score=track.score, box_source=track.box_source)
        item.box.x, item.box.y, item.box.width, item.box.height = (float(v) for v in track.box)
        if track.ground_xy_m is not None:
            item.ground_position.x_m, item.ground_position.y_m = (float(v) for v in track.ground_xy_m)
    return message.SerializeToString()


def tracks_from_record(message: Any) -> list[Track]:
    """Decoded TrackArray (any protobuf class with this schema) -> pipeline Tracks."""
    tracks = []
    for item in message.tracks:
        ground = ((item.ground_position.x_m, item.ground_position.y_m)
                  if item.HasField("ground_position") else None)
        tracks.append(Track(
            track_id=item.id, box=(item.box.x, item.box.y, item.box.width, item.box.height),
            cls=item.class_name, height_m=item.height_m, height_std_m=item.height_std_m,
            score=item.score, confirmed=item.confirmed, ground_xy_m=ground,
            height_source=item.height_source,
            # Recordings from before box_source said nothing: their boxes read as detected.
            updated=item.box_source in ("", "detected"), filled=item.box_source == "interpolated"))
    return tracks
