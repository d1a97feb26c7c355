"""Frames back from an MP4 cut off before its index was written, as ``untrunc`` does.

An MP4 (or MOV) keeps its frames in the ``mdat`` box and, in the ``moov`` box, the index that
says where each frame starts and how to decode them (codec settings, frame rate). A camera
or a screen recorder writes ``moov`` last, on closing the file; a power loss or a full disk
leaves an ``mdat`` full of frames that no player can find.

The frames are still there, one after the other. For the codecs CCTV uses they can be found
without the index: H.264 and H.265 store each frame as length-prefixed NAL units; MPEG-4 part 2
as start-code delimited VOPs. What is missing is the codec set-up (H.264 SPS/PPS, MPEG-4 VOL
header) and the frame rate: they come from a *reference*, a complete recording of the same
camera with the same settings. The salvaged frames are written as a raw elementary stream
(H.264 Annex B, raw MPEG-4) that FFmpeg decodes frame by frame, damage detection included.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

CONTAINER_BOXES = {b"ftyp", b"moov", b"mdat", b"free", b"skip", b"wide", b"uuid", b"pnot", b"meta", b"styp"}


@dataclass
class Box:
    kind: bytes
    start: int
    """Offset of the payload (after size and type)."""
    end: int
    """End of the payload as the size field says (may lie past the end of a cut file)."""


def top_level_boxes(data: bytes) -> list[Box]:
    """The top-level boxes as far as they can be walked (a cut file's last box runs past its end)."""
    boxes, offset = [], 0
    while offset + 8 <= len(data):
        size, kind = struct.unpack(">I4s", data[offset:offset + 8])
        header = 8
        if size == 1 and offset + 16 <= len(data):
            size = struct.unpack(">Q", data[offset + 8:offset + 16])[0]
            header = 16
        elif size == 0:  # "to the end of the file"
            size = len(data) - offset
        if size < header or kind not in CONTAINER_BOXES and not kind.isalnum():
            break
        boxes.append(Box(kind, offset + header, offset + size))
        offset += size
    return boxes


def lacks_index(path: Path) -> bool:
    """An MP4/MOV with frame data (``mdat``) but no index (``moov``): a recording cut off."""
    try:
        with open(path, "rb") as stream:
            data = stream.read()
    except OSError:
        return False
    kinds = [box.kind for box in top_level_boxes(data)]
    return b"mdat" in kinds and b"moov" not in kinds
