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
import tempfile
from dataclasses import dataclass
from pathlib import Path

from core.config import CaptureConfig
from core.errors import SourceError

CONTAINER_BOXES = {b"ftyp", b"moov", b"mdat", b"free", b"skip", b"wide", b"uuid", b"pnot", b"meta", b"styp"}
RAW_FORMATS = {"h264": "h264", "hevc": "hevc", "mpeg4": "m4v", "mjpeg": "mjpeg"}
"""Codec of the reference -> FFmpeg's raw elementary-stream demuxer for the salvaged frames."""


@dataclass(frozen=True)
class Mp4SalvageConstants:
    """The salvage's fixed numbers (the rule is in docs/design.md, Configuration)."""

    copy_block: int = 1 << 20
    """Bytes copied at a time (1 MiB): few reads, little memory."""
    unsure_tail_frames: int = 3
    """Frames at the end of a cut stream with B-frames that may stand in the wrong place (x264's
    default of 3 B-frames)."""
    max_nal_bytes: int = 1 << 24
    """A length prefix claiming more than this (16 MiB, beyond any camera's key frame) is damage,
    not a NAL unit."""
    max_resync_bytes: int = 1 << 23
    """How far past a damaged or foreign stretch (audio interleaved with the video) to look for
    the next NAL unit (8 MiB) before giving up on the rest."""


CONSTANTS = Mp4SalvageConstants()


@dataclass
class Box:
    kind: bytes
    start: int
    """Offset of the payload (after size and type)."""
    end: int
    """End of the payload as the size field says (may lie past the end of a cut file)."""


def top_level_boxes(stream) -> list[Box]:
    """The top-level boxes as far as they can be walked (a cut file's last box runs past its end)."""
    stream.seek(0, 2)
    file_size = stream.tell()
    boxes, offset = [], 0
    while offset + 8 <= file_size:
        stream.seek(offset)
        head = stream.read(16)
        size, kind = struct.unpack(">I4s", head[:8])
        header = 8
        if size == 1 and len(head) == 16:
            size, header = struct.unpack(">Q", head[8:16])[0], 16
        elif size == 0:  # "to the end of the file"
            size = file_size - offset
        if size < header or kind not in CONTAINER_BOXES:
            break
        boxes.append(Box(kind, offset + header, offset + size))
        offset += size
    return boxes


def lacks_index(path: Path) -> bool:
    """An MP4/MOV with frame data (``mdat``) but no index (``moov``): a recording cut off."""
    try:
        with open(path, "rb") as stream:
            kinds = [box.kind for box in top_level_boxes(stream)]
    except OSError:
        return False
    return b"mdat" in kinds and b"moov" not in kinds


@dataclass
class Reference:
    """What the cut file lacks, read from a complete recording of the same camera."""

    codec: str
    extradata: bytes
    fps: float
    reorders: bool
    """The codec reorders frames (B-frames): decode order is not display order."""


def read_reference(path: Path) -> Reference:
    import av

    try:
        with av.open(str(path)) as container:
            if not container.streams.video:
                raise SourceError(f"reference {path} has no video stream")
            stream = container.streams.video[0]
            codec = stream.codec_context.name
            extradata = bytes(stream.codec_context.extradata or b"")
            fps = float(stream.average_rate or stream.guessed_rate or 25.0)
            reorders = bool(stream.codec_context.has_b_frames)
    except av.error.FFmpegError as exc:
        raise SourceError(f"reference {path} is not a readable video ({exc.strerror})") from None
    if codec not in RAW_FORMATS:
        raise SourceError(f"cannot salvage {codec} video (only {', '.join(sorted(RAW_FORMATS))}); "
                          f"reference {path}")
    return Reference(codec, extradata, fps, reorders)


def salvage_to_raw(cut: Path, reference: Reference, out) -> str:
    """Writes the cut file's frames as a raw elementary stream to ``out``; returns a note on
    what was skipped or where the salvage stopped ("" = read to the end of the file)."""
    import mmap

    with open(cut, "rb") as stream:
        boxes = top_level_boxes(stream)
        mdat = next((box for box in boxes if box.kind == b"mdat"), None)
        if mdat is None:
            raise SourceError(f"{cut} has no frame data (mdat box) to salvage")
        stream.seek(0, 2)
        end = min(mdat.end, stream.tell())
        if reference.codec in ("h264", "hevc"):
            with mmap.mmap(stream.fileno(), 0, access=mmap.ACCESS_READ) as data:
                return _length_prefixed_to_annex_b(data, mdat.start, end, reference, out)
        if reference.codec == "mpeg4":
            out.write(reference.extradata)  # the VOL header the cut file's index held
        stream.seek(mdat.start)
        _copy(stream, end - mdat.start, out)
        return ""


def _copy(stream, count: int, out) -> None:
    while count > 0:
        block = stream.read(min(CONSTANTS.copy_block, count))
        if not block:
            return
        out.write(block)
        count -= len(block)


START_CODE = b"\x00\x00\x00\x01"


def _length_prefixed_to_annex_b(data, start: int, end: int, reference: Reference, out) -> str:
    """H.264/H.265 in MP4: [length][NAL] ... -> start-code delimited NALs after the parameter sets.

    Where the chain of lengths breaks (deleted or flipped bytes, audio samples between the
    video's), the next place where two NAL units follow each other plausibly is searched for.
    """
    length_size, parameter_sets = _parameter_sets(reference)
    for nal in parameter_sets:
        out.write(START_CODE + nal)
    position, skipped, gaps = start, 0, 0
    frame_start = out.tell()  # where the access unit (frame) being written began
    while position + length_size < end:
        if not _nal_at(data, position, end, length_size, reference.codec, depth=2):
            reach = min(end, position + CONSTANTS.max_resync_bytes)
            found = next((candidate for candidate in range(position + 1, reach)
                          if _nal_at(data, candidate, end, length_size, reference.codec, depth=2)), None)
            if found is None:
                break
            skipped, gaps, position = skipped + found - position, gaps + 1, found
            continue
        length = int.from_bytes(data[position:position + length_size], "big")
        if _starts_frame(data[position + length_size:position + length_size + 3], reference.codec):
            frame_start = out.tell()
        out.write(START_CODE + data[position + length_size:position + length_size + length])
        position += length_size + length
    notes = [f"{skipped} unreadable bytes skipped in {gaps} places"] if gaps else []
    if position + length_size < end:
        # The last frame is cut off: its slices written so far would decode as a patched-up
        # picture that no decoder flags, so they go too.
        out.seek(frame_start)
        out.truncate()
        notes.append(f"the last frame is cut off ({end - position} bytes), left out")
    return "; ".join(notes)


def _starts_frame(head: bytes, codec: str) -> bool:
    """This NAL unit begins a new access unit: parameter sets, SEI, a delimiter, or the first
    slice of a picture (first_mb_in_slice = 0 / first_slice_segment_in_pic_flag = 1)."""
    if codec == "h264":
        kind = head[0] & 0x1F
        return kind in (6, 7, 8, 9) or (kind in (1, 5) and len(head) > 1 and bool(head[1] & 0x80))
    kind = (head[0] >> 1) & 0x3F
    return kind in (32, 33, 34, 35, 39) or (kind < 32 and len(head) > 2 and bool(head[2] & 0x80))


def _nal_at(data, position: int, end: int, length_size: int, codec: str, depth: int) -> bool:
    """A plausible NAL unit starts at ``position`` (and, to ``depth``, the ones after it)."""
    if position == end:  # the previous unit ended exactly at the end of the data
        return True
    if position + length_size + 2 > end:
        return False
    length = int.from_bytes(data[position:position + length_size], "big")
    if not 2 <= length <= CONSTANTS.max_nal_bytes or position + length_size + length > end:
        return False
    header = data[position + length_size]
    if header & 0x80:  # forbidden_zero_bit
        return False
    if codec == "h264":
        if not 1 <= header & 0x1F <= 12:
            return False
    elif (header >> 1) & 0x3F > 40 or data[position + length_size + 1] & 0x07 == 0:
        return False
    following = position + length_size + length
    return depth <= 1 or _nal_at(data, following, end, length_size, codec, depth - 1)


def _parameter_sets(reference: Reference) -> tuple[int, list[bytes]]:
    """(NAL length size, SPS/PPS/VPS NAL units) from an avcC or hvcC record."""
    data = reference.extradata
    if not data or data[0] != 1:  # already Annex B (or none): the stream carries its own
        return 4, [nal for nal in data.split(START_CODE) if nal] if data else []
    nals = []
    if reference.codec == "h264":
        length_size = (data[4] & 3) + 1
        offset, count = 6, data[5] & 0x1F
        for table in range(2):
            for _ in range(count):
                size = int.from_bytes(data[offset:offset + 2], "big")
                nals.append(data[offset + 2:offset + 2 + size])
                offset += 2 + size
            if table == 0:
                count, offset = data[offset], offset + 1
        return length_size, nals
    length_size, arrays, offset = (data[21] & 3) + 1, data[22], 23
    for _ in range(arrays):
        count = int.from_bytes(data[offset + 1:offset + 3], "big")
        offset += 3
        for _ in range(count):
            size = int.from_bytes(data[offset:offset + 2], "big")
            nals.append(data[offset + 2:offset + 2 + size])
            offset += 2 + size
    return length_size, nals


def open_salvaged(path: Path, config: CaptureConfig):
    """A ``PyAVFileSource`` over the frames of the index-less MP4 ``path``, decoded with the codec
    settings of ``capture.reference``; time stamps follow the reference's frame rate."""
    import av

    from stages.pyav_capture import PyAVFileSource

    reference = read_reference(Path(config.reference))
    raw = tempfile.NamedTemporaryFile(prefix="heightpipe-salvage-", suffix="." + RAW_FORMATS[reference.codec])
    stopped = salvage_to_raw(path, reference, raw)
    raw.flush()
    options = {"framerate": f"{reference.fps:.6f}"}
    source = PyAVFileSource(path, config, open_container=lambda: av.open(
        raw.name, format=RAW_FORMATS[reference.codec], options=options))
    source.description = f"{path} (salvaged)"
    if reference.reorders and stopped:
        source.unsure_tail = CONSTANTS.unsure_tail_frames
    source.stats.expected = None  # a raw stream has no frame count; a guess from its size would mislead
    source.stats.notes.append(f"salvaged from an MP4 without index with the codec settings of "
                              f"{config.reference}" + (f"; {stopped}" if stopped else ""))
    source.keep_alive(raw)
    return source
