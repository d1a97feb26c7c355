"""Video files through PyAV (FFmpeg's own API): every frame says whether it decoded clean.

OpenCV's ``VideoCapture`` hides FFmpeg's error concealment: a frame rebuilt from a damaged
packet comes out as a normal image, and the heights measured on it look as good as any.
PyAV shows what FFmpeg knows, frame by frame:

- the decoder's corrupt-frame flag (``AV_FRAME_FLAG_CORRUPT``) and the errors it logs while
  decoding a packet ("ac-tex damaged", "concealing 120 DC errors", ...);
- packets that fail to decode at all;
- packet time stamps, so frames that vanished from the stream show as a gap in time, and a
  time stamp that jumps back or far ahead is noticed;
- the container's own checksums where it has them (Matroska clusters' CRC-32, which FFmpeg
  does not check: ``stages.mkv_checksums``);
- the stream's structure: a frame predicted from a damaged one is damaged too, up to the next
  key frame (concealed errors spread through the motion vectors; measured on the corpus of
  ``tests/damage_corpus.py``).

Each damaged frame carries its reason in ``Frame.damage`` (the tracker withholds its heights,
the sinks mark it) and is counted in ``CaptureStats.damaged``; frames lost outright count as
failed. Streams and webcams stay on OpenCV (``stages.capture``).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from core.config import CaptureConfig
from core.errors import SourceError
from core.packets import Frame
from stages.capture import FrameSource



@dataclass(frozen=True)
class PyAVCaptureConstants:
    """PyAV capture's fixed numbers (the rule is in docs/design.md, Configuration)."""

    max_gap_s: float = 10.0
    """A time stamp further than this past the previous frame is taken as damaged, not as a gap
    of lost frames (no camera drops ten seconds and then carries on in the same file)."""


CONSTANTS = PyAVCaptureConstants()


def _av():
    """PyAV with FFmpeg's errors routed to Python (captured per packet, never printed)."""
    import av

    av.logging.set_level(av.logging.ERROR)
    return av


class PyAVFileSource(FrameSource):
    """A video file decoded with PyAV, with per-frame damage detection."""

    def __init__(self, path: Path, config: CaptureConfig, open_container=None):
        super().__init__(config)
        self.path = Path(path)
        self.description = str(path)
        if not self.path.exists():
            raise SourceError(f"no such file: {path}")
        if self.path.is_dir():
            raise SourceError(f"{path} is a folder without images")
        self._resources: list = []
        self.unsure_tail = 0
        """The last this many frames are marked damaged: set for a salvaged stream with B-frames,
        whose last frames may stand in the place of B-frames cut off after them in decode order
        (a raw stream has no time stamps to tell)."""
        av = _av()
        self._open = open_container or (lambda: av.open(str(self.path)))
        self._plain_file = open_container is None
        self.container, self.stream = self._open_video(first=True)
        self.damaged_ranges = self._checksum_failures()
        """Byte ranges whose container checksum fails: their frames are damaged, decoded or not."""
        self.fps = float(self.stream.average_rate or self.stream.guessed_rate or 0) or None
        self.stats.expected = self.stream.frames or self._frames_from_duration()
        self.source_size = (self.stream.codec_context.width, self.stream.codec_context.height)
        if not all(self.source_size):
            self.close()
            raise SourceError(f"{path} is not a readable video (its video stream has no frame size)")

    def _open_video(self, first: bool = False):
        av = _av()
        # A damaged signature can also make FFmpeg take the file for another format: repair first
        # (the repaired opener then serves later opens too).
        container = self._open_with_repaired_header() if first and self._plain_file else None
        try:
            with av.logging.Capture(local=False):  # FFmpeg's own account goes into our one line
                container = container or self._open()
        except av.error.FFmpegError as exc:
            raise SourceError(not_readable_message(self.path, exc)) from None
        if not container.streams.video:
            container.close()
            raise SourceError(f"{self.path} is not a readable video (no video stream)")
        stream = container.streams.video[0]
        # Slice threads only: frame threads would hand back frames late, and the errors logged
        # for a packet could no longer be told to belong to its frame.
        stream.thread_type = "SLICE"
        return container, stream

    def _checksum_failures(self) -> list[tuple[int, int]]:
        if not self._plain_file or "matroska" not in self.container.format.name:
            return []
        from stages.mkv_checksums import damaged_clusters

        return damaged_clusters(self.path)

    def _in_damaged_range(self, position: int | None) -> bool:
        return position is not None and any(start <= position < end for start, end in self.damaged_ranges)

    def _frames_from_duration(self) -> int | None:
        """The frame count a header without one implies (duration x rate), as OpenCV reports it."""
        if self.stream.duration and self.stream.time_base:
            seconds = float(self.stream.duration * self.stream.time_base)
        elif self.container.duration:
            seconds = self.container.duration / 1e6
        else:
            return None
        return round(seconds * self.fps) if self.fps else None

    def _open_with_repaired_header(self):
        """The container read through a corrected first four bytes, if that is what is damaged."""
        from stages.header_repair import PatchedFile, header_patch

        av = _av()
        patch = header_patch(self.path)
        if patch is None:
            return None
        fixed, what = patch
        self._open = lambda: av.open(PatchedFile(self.path, fixed))
        try:
            with av.logging.Capture(local=False):
                container = self._open()
        except av.error.FFmpegError:
            return None
        self.stats.notes.append(f"read with {what} repaired (its first bytes were damaged)")
        return container

    def frames(self) -> Iterator[Frame]:
        decoded = self._decode(self.container, self.stream, keep=lambda index: not self._skip(index), count=True)
        yield from self._fitted(frame for frame in decoded if not self._skip(frame.index))
        if self.stats.reached_end:
            self._count_frames_never_read()

    def _count_frames_never_read(self) -> None:
        """Frames the header counts (MP4, AVI) that never came out count as failed: cut off, or
        lost inside the file where no time stamp shows the gap (an AVI read past a damaged
        index numbers the frames after it as if nothing was missing)."""
        counted = self.stream.frames if self.stream is not None else 0
        missing = counted - self.stats.decoded - self.stats.failed
        if counted and missing > 0:
            self.stats.failed += missing
            self.stats.notes.append(f"{missing} frames the header counts never came (cut off, or lost "
                                    f"inside the file: then frame numbers after the first damage may "
                                    f"be off by up to {missing})")

    def _decode(self, container, stream, keep: Callable[[int], bool], count: bool) -> Iterator[Frame]:
        """Every decodable frame in order, with its damage; updates the stats if ``count``.

        Images are converted only for the frame indices ``keep`` wants; the rest carry an empty one.
        """
        tail: deque[Frame] = deque()
        for frame in self._decode_each(container, stream, keep, count):
            tail.append(frame)
            if len(tail) > self.unsure_tail:
                yield tail.popleft()
        for frame in tail:
            if not frame.damage and count:
                self.stats.damaged += 1
            frame.damage = frame.damage or "may be out of place: the frames after it were cut off"
            yield frame

    def _decode_each(self, container, stream, keep: Callable[[int], bool], count: bool) -> Iterator[Frame]:
        av = _av()
        # AVI stores no presentation times, only a frame rate: with B-frames FFmpeg hands out
        # decode-order stamps (1, 3, 4, 2, ...). Its frames are counted instead.
        tracker = DamageTracker(self.fps, use_stamps="avi" not in container.format.name.split(","))
        # One converter for the whole decode: ``VideoFrame.to_ndarray(format=...)`` builds a new
        # one, and with it FFmpeg's colour conversion context, on every frame (640x360: 1-2 ms of
        # CPU a frame against 0.1; the same pixels, bit for bit).
        to_bgr = av.video.reformatter.VideoReformatter()
        with av.logging.Capture(local=False) as logs:
            packets = container.demux(stream)
            while True:
                try:
                    packet = next(packets)
                except StopIteration:
                    break
                except av.error.FFmpegError as exc:  # the container breaks off: the rest is lost
                    if count:
                        self.stats.notes.append(f"reading stopped early: {_reason(exc)}")
                    break
                logged = len(logs)
                try:
                    decoded = packet.decode()
                except av.error.FFmpegError as exc:
                    tracker.packet_failed(_reason(exc))
                    continue
                finally:
                    errors = [log[2].strip() for log in logs[logged:]]
                    del logs[:]
                    if self._in_damaged_range(packet.pos):
                        errors.append("its bytes fail the container's checksum (Matroska cluster CRC-32)")
                for av_frame in decoded:
                    frame = tracker.next_frame(av_frame, errors)
                    errors = []  # one packet's errors go to its first frame
                    if count:
                        self.stats.decoded += 1
                        self.stats.failed += frame.lost_before
                        self.stats.damaged += bool(frame.frame.damage)
                    if keep(frame.frame.index):
                        frame.frame.image = to_bgr.reformat(av_frame, format="bgr24").to_ndarray()
                    yield frame.frame

    def _images_at(self, indices: list[int]) -> Iterator[tuple[int, np.ndarray]]:
        if not indices:
            return
        wanted = set(indices)
        container, stream = self._open_video()  # a second reader: the run's is untouched
        try:
            for frame in self._decode(container, stream, keep=wanted.__contains__, count=False):
                if frame.index > max(wanted):
                    break
                if frame.index in wanted and not frame.damage:
                    yield frame.index, frame.image
        finally:
            container.close()

    def keep_alive(self, resource) -> None:
        """Close ``resource`` (e.g. a temporary file the container reads) with this source."""
        self._resources.append(resource)

    def close(self) -> None:
        container = getattr(self, "container", None)
        if container is not None:
            container.close()
            self.container = None
        for resource in getattr(self, "_resources", []):
            resource.close()
        self._resources = []


@dataclass
class _Decoded:
    frame: Frame
    lost_before: int
    """Frames missing from the source just before this one (a gap in the time stamps)."""


class DamageTracker:
    """Turns decoded frames (in output order) into ``Frame``s with index, time and damage.

    Indices are the source's: frames lost between two decoded ones (a gap in the time stamps)
    are skipped over and counted, so frame N is the same picture as in a clean copy.
    """

    def __init__(self, fps: float | None, use_stamps: bool = True):
        self.fps = fps
        self.use_stamps = use_stamps
        self.index = -1
        self.time_s = 0.0
        self.origin_s: float | None = None
        self.spreading: str = ""
        """Damage this frame inherits from a damaged reference, until the next clean key frame."""
        self.failed_packet: str = ""

    def packet_failed(self, reason: str) -> None:
        self.failed_packet = reason

    def next_frame(self, av_frame, errors: list[str]) -> _Decoded:
        reasons = []
        if self.failed_packet:
            reasons.append(f"a packet before it failed to decode ({self.failed_packet})")
            self.failed_packet = ""
        if av_frame.is_corrupt:
            reasons.append("decoder flags it corrupt")
        if errors:
            reasons.append(f"decoder error: {errors[0]}" + (f" (+{len(errors) - 1} more)" if len(errors) > 1 else ""))
        lost, time_s, time_note = self._place(av_frame)
        if lost and not av_frame.key_frame:  # a key frame needs no earlier frame: it is whole
            reasons.append(f"{lost} frame{'s' if lost > 1 else ''} missing before it")
        if time_note:
            reasons.append(time_note)
        if reasons:
            self.spreading = f"predicted from a damaged frame (frame {self.index}: {reasons[0]})"
        elif av_frame.key_frame:
            self.spreading = ""
        damage = "; ".join(reasons) or self.spreading
        return _Decoded(Frame(index=self.index, time_s=time_s, image=_EMPTY, damage=damage), lost)

    def _place(self, av_frame) -> tuple[int, float, str]:
        """(frames lost before this one, its time from the first frame, a time stamp problem)."""
        step = 1.0 / self.fps if self.fps else 0.0
        stamp = av_frame.time
        if stamp is None or not self.fps or not self.use_stamps:  # no time stamps: count frames
            self.index += 1
            self.time_s = self.index * step
            return 0, self.time_s, ""
        if self.origin_s is None:
            self.origin_s = stamp
            self.index = 0
            self.time_s = 0.0
            return 0, 0.0, ""
        time_s = stamp - self.origin_s
        gap = time_s - self.time_s
        if gap <= 0 or gap > CONSTANTS.max_gap_s:
            self.index += 1
            self.time_s += step
            return 0, self.time_s, f"time stamp {'goes back' if gap <= 0 else 'jumps ahead'} ({gap:+.3f} s)"
        lost = max(0, round(gap * self.fps) - 1)
        self.index += 1 + lost
        self.time_s = time_s
        return lost, time_s, ""


_EMPTY = np.zeros((0, 0, 3), np.uint8)


def _reason(exc: Exception) -> str:
    text = getattr(exc, "strerror", None) or str(exc)
    return str(text).strip()


def not_readable_message(path: Path, exc: Exception) -> str:
    """One line saying why FFmpeg cannot open ``path`` and what the user can do."""
    from stages.mp4_salvage import lacks_index

    if lacks_index(path):
        return (f"{path} is an MP4/MOV without its index (moov atom): the recording was cut off before "
                f"it was finished. Salvage its frames with --reference GOOD.mp4 (a complete recording "
                f"from the same camera and settings), or record to MKV or MPEG-TS, which survive a cut")
    return f"{path} is not a readable video (FFmpeg: {_reason(exc)})"
