"""Matroska's own checksums: the clusters whose CRC-32 does not match their bytes.

FFmpeg and mkvmerge write a CRC-32 element first in every cluster (the unit that holds a few
seconds of frames), but FFmpeg's demuxer does not check it: a flipped bit in a frame that
still decodes without error goes unnoticed (2 of 210 bit-flip runs on MKV clips, see
docs/results.md). Reading the file once more and checking each cluster finds those frames.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass
from pathlib import Path

SEGMENT, CLUSTER, CRC32 = 0x18538067, 0x1F43B675, 0xBF


@dataclass(frozen=True)
class MkvChecksumConstants:
    """The checksum reader's fixed numbers (the rule is in docs/design.md, Configuration)."""

    max_cluster_bytes: int = 1 << 28
    """A cluster claiming more than this (256 MiB) is a corrupt size field, not seconds of
    camera video: the reader stops rather than load it."""


CONSTANTS = MkvChecksumConstants()


def _vint(data: bytes, position: int, keep_marker: bool) -> tuple[int, int] | None:
    """(value, length) of the EBML variable-length integer at ``position``; None if invalid."""
    if position >= len(data) or data[position] == 0:
        return None
    length = 8 - data[position].bit_length() + 1
    if position + length > len(data):
        return None
    value = int.from_bytes(data[position:position + length], "big")
    if not keep_marker:
        value &= (1 << (7 * length)) - 1
    return value, length


def _element(stream, position: int) -> tuple[int, int, int] | None:
    """(id, payload start, payload size) of the element at ``position``; None if unreadable."""
    stream.seek(position)
    head = stream.read(12)
    ident = _vint(head, 0, keep_marker=True)
    if ident is None:
        return None
    size = _vint(head, ident[1], keep_marker=False)
    if size is None:
        return None
    return ident[0], position + ident[1] + size[1], size[0]


def damaged_clusters(path: Path) -> list[tuple[int, int]]:
    """Byte ranges (start, end) of the clusters whose stored CRC-32 does not match.

    Clusters without a CRC-32, of unknown size (a file still being written) or past a point
    where the structure cannot be walked are not judged.
    """
    damaged = []
    with open(path, "rb") as stream:
        stream.seek(0, 2)
        file_size = stream.tell()
        position = 0
        segment = None
        while position < file_size:  # the EBML header, then the segment
            element = _element(stream, position)
            if element is None:
                return damaged
            ident, start, size = element
            if ident == SEGMENT:
                segment = (start, min(file_size, start + size))
                break
            position = start + size
        if segment is None:
            return damaged
        position, end = segment
        while position < end:
            element = _element(stream, position)
            if element is None:
                break
            ident, start, size = element
            if start + size > file_size or size > CONSTANTS.max_cluster_bytes:
                break
            if ident == CLUSTER:
                stream.seek(start)
                payload = stream.read(size)
                crc = _stored_crc(payload)
                if crc is not None and zlib.crc32(payload[crc[0]:]) != crc[1]:
                    damaged.append((position, start + size))
            position = start + size
    return damaged


def _stored_crc(payload: bytes) -> tuple[int, int] | None:
    """(where the checked bytes begin, stored CRC) if the payload starts with a CRC-32 element."""
    ident = _vint(payload, 0, keep_marker=True)
    if ident is None or ident[0] != CRC32:
        return None
    size = _vint(payload, ident[1], keep_marker=False)
    if size is None or size[0] != 4:
        return None
    begin = ident[1] + size[1]
    return begin + 4, int.from_bytes(payload[begin:begin + 4], "little")
