"""Open a video whose first bytes are damaged, by reading it through a corrected header.

The first four bytes of MP4, AVI and MKV files are a signature or a size that FFmpeg's probe
needs, and also the bytes a careless tool or a bad sector overwrites first. The rest of the
header says what they must have been:

- MP4/MOV: the size of the ``ftyp`` box (its type follows at byte 4), found as the offset of the
  next top-level box;
- AVI: ``RIFF`` (``AVI `` follows at byte 8);
- MKV/WebM: the EBML magic ``1A 45 DF A3`` (the doc type "matroska"/"webm" follows shortly).

The file on disk is not touched: ``PatchedFile`` serves the corrected bytes to FFmpeg.
"""

from __future__ import annotations

import io
import struct
from pathlib import Path

from stages.mp4_salvage import CONTAINER_BOXES

EBML_MAGIC = b"\x1a\x45\xdf\xa3"


def header_patch(path: Path) -> tuple[bytes, str] | None:
    """(the first four bytes as they must have been, what they are) if they are damaged, else None."""
    with open(path, "rb") as stream:
        head = stream.read(256)
    if len(head) < 16:
        return None
    if head[4:8] == b"ftyp":
        stated = struct.unpack(">I", head[:4])[0]
        if 8 <= stated <= len(head) - 8 and head[stated + 4:stated + 8] in CONTAINER_BOXES:
            return None
        for size in range(16, len(head) - 8, 4):
            if head[size + 4:size + 8] in CONTAINER_BOXES:
                return struct.pack(">I", size), "the MP4 ftyp box size"
        return None
    if head[8:12] == b"AVI " and head[:4] != b"RIFF":
        return b"RIFF", "the AVI RIFF signature"
    if (b"matroska" in head[:64] or b"webm" in head[:64]) and head[:4] != EBML_MAGIC:
        return EBML_MAGIC, "the Matroska EBML signature"
    return None


class PatchedFile(io.RawIOBase):
    """A read-only file whose first bytes read as ``patch`` (for av.open)."""

    def __init__(self, path: Path, patch: bytes):
        self._file = open(path, "rb")
        self._patch = patch

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def seek(self, offset: int, whence: int = io.SEEK_SET) -> int:
        return self._file.seek(offset, whence)

    def tell(self) -> int:
        return self._file.tell()

    def readinto(self, buffer) -> int:
        position = self._file.tell()
        count = self._file.readinto(buffer)
        if position < len(self._patch) and count:
            end = min(len(self._patch), position + count)
            buffer[:end - position] = self._patch[position:end]
        return count

    def close(self) -> None:
        self._file.close()
        super().close()
