"""Frame capture: video files, image folders or globs, RTSP/HTTP streams and webcams.

Every source yields ``Frame``s with the source's own frame index and the container's or
stream's time stamp, and keeps ``CaptureStats`` so that frames that fail to decode are
counted and reported instead of silently skipped.
"""

from __future__ import annotations

import glob
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

import cv2
import numpy as np

from core.config import CaptureConfig
from core.errors import ConfigError, SourceError
from core.packets import Frame

IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp"}
STREAM_PREFIXES = ("rtsp://", "rtsps://", "http://", "https://", "rtmp://", "udp://", "tcp://")


@dataclass(frozen=True)
class CaptureConstants:
    """Capture's fixed numbers (the rule is in docs/design.md, Configuration)."""

    max_consecutive_decode_failures: int = 25
    """A video read failing this many times in a row is taken as its end (truncated or corrupt
    tail): about a second of video."""
    aspect_tolerance: float = 0.02
    """Frames whose width / height differs from the run's by less than this share are the same
    view at another resolution (1280x720 for 1920x1080; 704x576 is not 768x576)."""


CONSTANTS = CaptureConstants()

# Markers _read() yields in place of an image.
SKIPPED = np.zeros((0, 0, 3), np.uint8)
FAILED = np.zeros((0, 0, 3), np.uint8)


@dataclass
class CaptureStats:
    decoded: int = 0
    """Frames decoded (processed or skipped by stride)."""
    failed: int = 0
    """Frames (or images) that could not be decoded, or vanished from the stream."""
    damaged: int = 0
    """Frames decoded with errors (concealed by the decoder): processed, heights withheld."""
    notes: list[str] = field(default_factory=list)
    """What else went wrong reading the source (one line each)."""
    reconnects: int = 0
    expected: int | None = None
    """Frame count the container header claims, where it has one (not always right)."""
    reached_end: bool = False
    """The source ran out (rather than the run stopping early)."""
    rescaled: int = 0
    """Frames that came at another resolution of the run's aspect ratio (a camera that changed
    streams at a reconnect): scaled to the run's size, then processed as usual."""
    wrong_shape: int = 0
    """Frames of another aspect ratio than the run's (another view or crop): not processed."""

    def summary(self) -> str:
        text = f"{self.decoded} frames decoded"
        if self.failed:
            text += f", {self.failed} failed to decode"
        if self.damaged:
            text += f", {self.damaged} damaged (decoded with errors: heights not measured on them)"
        if self.reached_end and self.expected is not None and self.expected != self.decoded:
            text += f" (header claims {self.expected})"
        if self.reconnects:
            text += f", {self.reconnects} stream reconnects"
        if self.rescaled:
            text += f", {self.rescaled} at another resolution (scaled)"
        if self.wrong_shape:
            text += f", {self.wrong_shape} of another aspect ratio (not processed)"
        return "; ".join([text, *self.notes])


class FrameSource:
    """Base class: subclasses implement ``_read()`` yielding (index, time_s, image|None)."""

    description = "source"

    def __init__(self, config: CaptureConfig):
        self.config = config
        self.stats = CaptureStats()
        self.fps: float | None = None
        if config.max_width < 0:
            raise ConfigError(f"capture.max_width must be 0 (full size) or a width in pixels, got {config.max_width}")
        self.source_size: tuple[int, int] | None = None
        """(width, height) of the source's frames, known after opening."""

    @property
    def size(self) -> tuple[int, int] | None:
        """(width, height) of the frames this source hands out (``processing_size``)."""
        return processing_size(self.source_size, self.config.max_width)

    @property
    def source_scale(self) -> tuple[float, float]:
        """Source pixels per pixel of the frames handed out, along x and y."""
        if self.source_size is None or self.size == self.source_size:
            return (1.0, 1.0)
        return (self.source_size[0] / self.size[0], self.source_size[1] / self.size[1])

    def frames(self) -> Iterator[Frame]:
        """Frames after stride and max_frames, counting decoded and failed ones."""
        yield from self._fitted(self._decoded())

    def _decoded(self) -> Iterator[Frame]:
        """``_read()``'s frames as decoded, stride applied, decoded and failed ones counted."""
        for index, time_s, image in self._read():
            if image is FAILED:
                self.stats.failed += 1
                continue
            self.stats.decoded += 1
            if image is not SKIPPED:
                yield Frame(index=index, time_s=time_s, image=_ensure_bgr(image))

    def _fitted(self, decoded: Iterator[Frame]) -> Iterator[Frame]:
        """``decoded`` at the run's frame size (``fit_to_size``), up to ``capture.max_frames``;
        ``stats.reached_end`` once the source ran out."""
        emitted = 0
        for frame in decoded:
            image = self.fit_to_size(frame.image, frame.index)
            if image is None:
                continue
            frame.image, frame.source_scale = image, self.source_scale
            yield frame
            emitted += 1
            if self.config.max_frames and emitted >= self.config.max_frames:
                return
        self.stats.reached_end = True

    def scaling_note(self) -> str:
        """One line for the run's summary when frames are processed scaled down ("" if not)."""
        if self.source_size is None or self.size == self.source_size:
            return ""
        (sw, sh), (w, h) = self.source_size, self.size
        return (f"{sw}x{sh} frames processed at {w}x{h} (capture.max_width = {self.config.max_width}; "
                "tracks.csv boxes and events in the source's pixels)")

    def fit_to_size(self, image: np.ndarray, index: int | None = None) -> np.ndarray | None:
        """The image at the run's frame size, or None where it cannot be.

        Everything after capture (the camera model, the background model, the previous frame
        for matching, zones in pixels) is built for one frame size. The source's own frames are
        scaled down to it when they are wider than ``capture.max_width`` (``processing_size``).
        A frame at another resolution of the same aspect ratio is the same view (a camera that
        switched streams at a reconnect): scaled too, and counted. Another aspect ratio is
        another view or crop whose pixels no longer map to the camera's: not processed, as a
        frame that failed to decode. ``index`` None: a look-ahead frame, not counted.
        """
        got = image.shape[1::-1]
        if self.size is None or got == self.source_size:
            return image if got == self.size else cv2.resize(image, self.size, interpolation=cv2.INTER_AREA)
        width, height = self.source_size
        got_w, got_h = got
        other_aspect = abs(got_w * height - got_h * width) > CONSTANTS.aspect_tolerance * got_h * width
        if index is not None:
            if not (self.stats.wrong_shape if other_aspect else self.stats.rescaled):
                self.stats.notes.append(f"frame {index} was the first at {got_w}x{got_h} "
                                        f"(the run's frames are {width}x{height})")
            if other_aspect:
                self.stats.wrong_shape += 1
            else:
                self.stats.rescaled += 1
        if other_aspect:
            return None
        if got == self.size:
            return image
        shrink = got_w > self.size[0]
        return cv2.resize(image, self.size, interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)

    def _skip(self, index: int) -> bool:
        return index % max(1, self.config.stride) != 0

    def _read(self) -> Iterator[tuple[int, float, np.ndarray]]:
        """Yield (source index, time in s, image, or SKIPPED for stride, or FAILED)."""
        raise NotImplementedError

    def background_sample(self, count: int, span_s: float) -> list[np.ndarray]:
        """Up to ``count`` frames spread over the first ``span_s`` seconds, read ahead of the run,
        at the run's frame size (``fit_to_size``; those of another aspect ratio left out).

        Only sources that can be read twice (files, image folders) have one; a live stream
        returns none and its background model starts from its first frames.
        """
        return self.opening_samples((count, span_s))[0]

    def opening_samples(self, *requests: tuple[int, float]) -> list[list[np.ndarray]]:
        """``background_sample(count, span_s)`` for each (count, span_s) of ``requests``, read in one
        pass: a run told only the camera height reads its camera from more early frames than its
        background model is primed with, and each pass decodes the video's opening seconds again."""
        total = self.stats.expected or 0
        wanted = [background_indices(total, self.fps or 25.0, count, span_s) if count > 0 and total > 0 else []
                  for count, span_s in requests]
        read = dict(self._look_ahead(sorted(set().union(*wanted))))
        return [[read[index] for index in indices if index in read] for indices in wanted]

    def spread_sample(self, count: int) -> Iterator[np.ndarray]:
        """Up to ``count`` frames spread evenly over the whole source, first and last included, at
        the run's frame size, one at a time (a long recording's frames are not held at once); none
        from a source that cannot be read twice or does not say how long it is.

        Why: reading a camera once to keep (``heightpipe calibrate --camera-height``) needs a few
        hundred frames of its scene, not every frame of an archive; spread over it, they also
        see the scene under more of its light and traffic than its first minutes."""
        total = self.stats.expected or 0
        if count > 0 and total > 0:
            for _, image in self._look_ahead(evenly_spaced(total, count)):
                yield image

    def _look_ahead(self, indices: list[int]) -> Iterator[tuple[int, np.ndarray]]:
        """(index, frame) at ``indices`` (ascending), read by a second reader and fitted to the
        run's size; those that fail to decode or are of another aspect ratio left out."""
        for index, image in self._images_at(indices):
            fitted = self.fit_to_size(_ensure_bgr(image))
            if fitted is not None:
                yield index, fitted

    def _images_at(self, indices: list[int]) -> Iterator[tuple[int, np.ndarray]]:
        """(index, frame as decoded) at ``indices`` (sources that can be read twice override this)."""
        return iter(())

    def close(self) -> None:
        pass


def processing_size(size: tuple[int, int] | None, max_width: int) -> tuple[int, int] | None:
    """The frame size a run works at: ``size`` divided by the smallest whole factor that makes it
    at most ``max_width`` wide (0: ``size`` itself).

    The network sees 320x192 pixels and matching and blobs work at 320 wide, so a 1920x1080
    frame carries nothing the measurements use that a 960x540 one lacks, while every per-pixel
    step (maps, masks, encoding) costs four times as much. A whole factor keeps the scaling
    exact and cheap (INTER_AREA averages whole blocks: 0.5 ms for 1920x1080 -> 960x540, 7 ms
    to 1280x720).
    """
    if size is None or max_width <= 0 or size[0] <= max_width:
        return size
    factor = -(-size[0] // max_width)
    return (max(1, round(size[0] / factor)), max(1, round(size[1] / factor)))


def evenly_spaced(total: int, count: int) -> list[int]:
    """Up to ``count`` distinct indices spread evenly over range(total), first and last included."""
    if total <= 0 or count <= 0:
        return []
    return sorted({int(round(i)) for i in np.linspace(0, total - 1, min(count, total))})


def background_indices(total: int, fps: float, count: int, span_s: float) -> list[int]:
    """Up to ``count`` frame indices spread over the first ``span_s`` seconds of ``total`` frames."""
    return evenly_spaced(min(total, max(1, int(span_s * fps))), count)


def _ensure_bgr(image: np.ndarray) -> np.ndarray:
    if image.ndim == 2:
        return cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    if image.shape[2] == 4:
        return cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    return image


class VideoFileSource(FrameSource):
    def __init__(self, path: Path, config: CaptureConfig):
        super().__init__(config)
        self.description = str(path)
        self.path = path
        if not path.exists():
            raise SourceError(f"no such file: {path}")
        if path.is_dir():
            raise SourceError(f"{path} is a folder without images")
        self.capture = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
        if not self.capture.isOpened():
            raise SourceError(f"{path} is not a readable video (OpenCV/FFmpeg cannot open it)")
        self.fps = self.capture.get(cv2.CAP_PROP_FPS) or None
        count = int(self.capture.get(cv2.CAP_PROP_FRAME_COUNT))
        self.stats.expected = count if count > 0 else None
        ok, first = self.capture.read()
        if not ok or first is None:
            self.capture.release()
            raise SourceError(f"{path} is not a readable video (no frame decodes)")
        self._first = first
        self.source_size = (first.shape[1], first.shape[0])

    def _timestamp(self, index: int) -> float:
        """Presentation time from the container; index/fps only if it has none."""
        msec = self.capture.get(cv2.CAP_PROP_POS_MSEC)
        if msec > 0 or index == 0:
            return msec / 1000.0
        return index / self.fps if self.fps else float(index)

    def _read(self) -> Iterator[tuple[int, float, np.ndarray]]:
        index = 0
        yield index, self._timestamp(index), self._first
        self._first = None
        failures_in_row = 0
        while True:
            index += 1
            ok = self.capture.grab()
            if ok:
                failures_in_row = 0
                if self._skip(index):
                    yield index, self._timestamp(index), SKIPPED
                    continue
                ok, image = self.capture.retrieve()
                yield index, self._timestamp(index), image if ok else FAILED
                continue
            # A failed grab is a corrupt frame or the end. Past the header's count, or after
            # many failures in a row, it is the end; frames the header still promised then
            # count as failed rather than vanishing from the report.
            failures_in_row += 1
            expected = self.stats.expected or 0
            if index >= expected:
                return
            if failures_in_row >= CONSTANTS.max_consecutive_decode_failures:
                self.stats.failed += expected - index
                return
            yield index, 0.0, FAILED

    def _images_at(self, indices: list[int]) -> Iterator[tuple[int, np.ndarray]]:
        if not indices:
            return
        wanted = set(indices)
        capture = cv2.VideoCapture(str(self.path), cv2.CAP_FFMPEG)  # a second reader: the run's is untouched
        try:
            for index in range(max(wanted) + 1):
                if not capture.grab():
                    break
                if index in wanted:
                    ok, image = capture.retrieve()
                    if ok and image is not None:
                        yield index, image
        finally:
            capture.release()

    def close(self) -> None:
        self.capture.release()


class ImageFolderSource(FrameSource):
    """Images in name order; they carry no time stamps, so time = index / capture.image_fps."""

    def __init__(self, paths: list[Path], description: str, config: CaptureConfig, fps: float):
        super().__init__(config)
        self.description = description
        self.paths = paths
        self.fps = fps
        self.stats.expected = len(paths)
        first = next((cv2.imread(str(p), cv2.IMREAD_COLOR) for p in paths[:5]), None)
        if first is None:
            raise SourceError(f"{description}: the first images cannot be decoded")
        self.source_size = (first.shape[1], first.shape[0])

    def _read(self) -> Iterator[tuple[int, float, np.ndarray]]:
        for index, path in enumerate(self.paths):
            if self._skip(index):
                yield index, index / self.fps, SKIPPED
                continue
            image = cv2.imread(str(path), cv2.IMREAD_COLOR)
            yield index, index / self.fps, FAILED if image is None else image

    def _images_at(self, indices: list[int]) -> Iterator[tuple[int, np.ndarray]]:
        for index in indices:
            image = cv2.imread(str(self.paths[index]), cv2.IMREAD_COLOR)
            if image is not None:
                yield index, image


Opener = Callable[[str], cv2.VideoCapture]


def _open_stream(url: str, read_timeout_s: float) -> cv2.VideoCapture:
    params = [cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, int(read_timeout_s * 1000),
              cv2.CAP_PROP_READ_TIMEOUT_MSEC, int(read_timeout_s * 1000)]
    if url.isdigit():
        return cv2.VideoCapture(int(url))
    return cv2.VideoCapture(url, cv2.CAP_FFMPEG, params)


class StreamSource(FrameSource):
    """A live stream or webcam: bounded retries with back-off to open, reconnects on drops.

    Time stamps are the stream's own where it has them, else wall-clock time since the
    first frame (live sources have no other clock).
    """

    def __init__(self, url: str, config: CaptureConfig, opener: Opener | None = None,
                 sleep: Callable[[float], None] = time.sleep):
        super().__init__(config)
        self.url = url
        self.description = url if not url.isdigit() else f"webcam {url}"
        self._opener = opener or (lambda u: _open_stream(u, config.read_timeout_s))
        self._sleep = sleep
        self.capture = self._connect(config.connect_attempts)
        if self.capture is None:
            raise SourceError(f"cannot open stream {self.description} after "
                              f"{config.connect_attempts} attempts")
        # The frame size (the camera model needs it before the run) is only sure once a frame
        # has come: read the first one now and hand it out first.
        ok, first = self.capture.read()
        if not ok or first is None:
            self.capture.release()
            raise SourceError(f"stream {self.description} opened but sent no frame within "
                              f"{config.read_timeout_s:g} s")
        self._first: np.ndarray | None = first
        self.source_size = (first.shape[1], first.shape[0])

    def _connect(self, attempts: int) -> cv2.VideoCapture | None:
        delay = self.config.backoff_s
        for attempt in range(max(1, attempts)):
            capture = self._opener(self.url)
            if capture is not None and capture.isOpened():
                fps = capture.get(cv2.CAP_PROP_FPS)
                self.fps = fps if fps and fps < 1000 else self.fps
                return capture
            if capture is not None:
                capture.release()
            if attempt + 1 < attempts:
                self._sleep(delay)
                delay *= 2
        return None

    def _read(self) -> Iterator[tuple[int, float, np.ndarray]]:
        index = 0
        start_wall = time.monotonic()
        offset_s = 0.0  # stream clocks restart after a reconnect: keep time increasing
        last_time = 0.0
        while True:
            if self._first is not None:
                ok, image, self._first = True, self._first, None
            else:
                ok, image = self.capture.read()
            if ok and image is not None:
                msec = self.capture.get(cv2.CAP_PROP_POS_MSEC)
                stream_time = msec / 1000.0 if msec > 0 else None
                time_s = (offset_s + stream_time) if stream_time is not None else time.monotonic() - start_wall
                time_s = max(time_s, last_time)
                last_time = time_s
                yield index, time_s, SKIPPED if self._skip(index) else image
                index += 1
                continue
            self.capture.release()
            if self.stats.reconnects >= self.config.reconnect_attempts:
                return
            self.stats.reconnects += 1
            capture = self._connect(self.config.connect_attempts)
            if capture is None:
                return
            self.capture = capture
            offset_s = last_time

    def close(self) -> None:
        self.capture.release()


def open_source(spec: str, config: CaptureConfig, image_fps: float = 10.0) -> FrameSource:
    """Pick the source kind from the spec: URL, webcam index, folder, glob or video file."""
    if spec.startswith(STREAM_PREFIXES) or spec.isdigit():
        return StreamSource(spec, config)
    if any(ch in spec for ch in "*?["):
        paths = sorted(Path(p) for p in glob.glob(spec) if Path(p).suffix.lower() in IMAGE_SUFFIXES)
        if not paths:
            raise SourceError(f"no images match {spec}")
        return ImageFolderSource(paths, spec, config, image_fps)
    path = Path(spec)
    if path.is_dir():
        paths = sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not paths:
            raise SourceError(f"{path} is a folder without images")
        return ImageFolderSource(paths, str(path), config, image_fps)
    if config.backend not in ("pyav", "opencv"):
        raise ConfigError(f"capture.backend must be 'pyav' or 'opencv', got {config.backend!r}")
    if config.reference:
        from stages.mp4_salvage import lacks_index, open_salvaged

        if lacks_index(path):
            return open_salvaged(path, config)
    if config.backend == "opencv":
        return VideoFileSource(path, config)
    from stages.pyav_capture import PyAVFileSource

    return PyAVFileSource(path, config)
