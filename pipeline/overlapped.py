"""The stage chain with its parts on their own threads, so a second core is not left idle.

    capture thread ──q──> network thread ──q──> the caller's thread
    decode frames         undistortion,         matching, objects, geometry, tracking,
                          ground + height,      then the caller's sinks
                          keypoints

Why threads and not processes: ONNX Runtime, OpenCV's decoder and most of the OpenCV work in
matching and object extraction release the GIL, so threads overlap the work without copying
frames between processes. Each stage still sees every frame in order, on one thread, so its
state (the previous frame for matching, the background model, the tracks) evolves exactly as in
the sequential loop: a file gives the same outputs either way (tests/pipeline/test_overlapped.py).
The stages after the network stay on the caller's thread for that reason too: OpenCV's random
generator, which the background model draws from, is per thread, and the caller's is the one
that was seeded and that primed the background model.

The queues between threads hold at most ``run.queue_frames`` frames. A file's capture thread
waits when the queue is full (back-pressure: nothing is buffered without bound); a live
source's waits at most one frame's time (``live_wait_s``: bursts) and then drops the frame, so
the run stays live rather than falls behind, and ``dropped`` counts those frames.

Before it drops, a live run sheds the network: with ``run.reuse_backlog`` frames or more
waiting for the network thread, the next frame gets the last frame's network outputs (its
undistortion still runs) and is marked ``network_reused``; the tracker moves its tracks on the
boxes but measures no height on it (a map one frame old lies beside a moving object).
``reused`` counts those frames. Why not drop: a dropped frame has no tracks at all. On the
25 frames/s held-out set (docs/results.md, 2026-12-05 seventeenth session) one frame in five
without the network kept HOTA (0.393 against 0.391) where one in ten dropped cost a tenth of it
(0.351).
"""

from __future__ import annotations

import queue
import threading
from dataclasses import dataclass, field
from typing import Callable, Iterable, Iterator

from core.packets import CameraInfo, Frame, FramePacket
from pipeline.stage_chain import StageChain

NETWORK_STAGES = ("undistortion", "ground", "height", "heights", "keypoints")
"""Stages run on the network thread: the network, what must happen to the frame before it, and
the keypoints matching will use, which need the network's height map but not the last frame: the
calling thread has more to do (docs/design.md, Threads and processes)."""

BEFORE_NETWORK = ("undistortion",)
"""Of those, the ones a frame that reuses the last network outputs still goes through."""

NETWORK_OUTPUTS = ("ground_mask", "height_map", "network_detections", "height_camera")
"""The packet fields the network's stages fill: what a frame that reuses them copies."""


@dataclass(frozen=True)
class OverlappedConstants:
    """The threads' fixed numbers (the rule is in docs/design.md, Configuration)."""

    poll_s: float = 0.1
    """How often a waiting thread looks whether the run was stopped: a stop is felt at once,
    the checks cost nothing."""
    live_wait_s: float = 0.04
    """How long a live frame waits for room before it is dropped: one frame of a 25 frames/s
    camera. Frames come in bursts (network jitter; the decoder's buffered frames at once when
    a stream ends) that the queue absorbs a moment later; the socket holds the stream meanwhile."""


CONSTANTS = OverlappedConstants()


class _End:
    """Put into a queue after the last item."""


@dataclass
class _Failed:
    """Put into a queue instead of an item when the thread producing it raised."""

    error: BaseException


def split_chain(chain: StageChain) -> tuple[StageChain, StageChain]:
    """The chain as (network part, the rest), cut after its last network stage."""
    cut = 0
    for position, (name, _) in enumerate(chain.stages):
        if name in NETWORK_STAGES:
            cut = position + 1
    return StageChain(chain.stages[:cut]), StageChain(chain.stages[cut:])


@dataclass
class OverlappedChain:
    """Runs a ``StageChain`` on threads; ``packets`` yields finished packets in frame order.

    Parameters
    ----------
    chain : StageChain
        The stages, as ``build_stage_chain`` made them (they are not closed here).
    camera : CameraInfo
        The run's camera, put into every packet.
    queue_frames : int
        Capacity of each queue between two threads.
    live : bool
        The source cannot wait (a stream or webcam): frames that find the first queue full are
        dropped and counted in ``dropped`` instead of holding up the capture.
    reuse_backlog : int
        Live sources only: with at least this many frames waiting for the network, the next one
        reuses the last network outputs (counted in ``reused``); 0 = never.
    live_wait_s : float
        Live sources only: how long a frame waits for room in the first queue before it is dropped.
    """

    chain: StageChain
    camera: CameraInfo
    queue_frames: int = 4
    live: bool = False
    reuse_backlog: int = 0
    live_wait_s: float = CONSTANTS.live_wait_s
    dropped: int = 0
    reused: int = 0
    _stop: threading.Event = field(default_factory=threading.Event)

    def packets(self, frames: Iterable[Frame]) -> Iterator[FramePacket]:
        """Every frame's packet after all stages; closing the generator stops and joins the threads."""
        network, analysis = split_chain(self.chain)
        size = max(1, self.queue_frames)
        decoded: queue.Queue = queue.Queue(size)
        measured: queue.Queue = queue.Queue(size)
        threads = [
            threading.Thread(target=self._capture, args=(frames, decoded), name="heightpipe-capture", daemon=True),
            threading.Thread(target=self._work, args=(self._network_step(network, decoded), decoded, measured),
                             name="heightpipe-network", daemon=True),
        ]
        self._stop.clear()
        for thread in threads:
            thread.start()
        try:
            while True:
                item = self._get(measured)
                if item is None or isinstance(item, _End):
                    return
                if isinstance(item, _Failed):
                    raise item.error
                yield analysis.process(item)
        finally:
            self._stop.set()
            for thread in threads[1:]:
                thread.join()
            # A live capture may sit in a read until the stream's timeout: it is a daemon and
            # stops at its next frame; a file's returns within one poll.
            threads[0].join(timeout=None if not self.live else 2 * CONSTANTS.poll_s)

    def _capture(self, frames: Iterable[Frame], outbox: queue.Queue) -> None:
        try:
            for frame in frames:
                packet = FramePacket(frame=frame, camera=self.camera)
                if self.live:
                    try:
                        outbox.put(packet, timeout=self.live_wait_s)
                    except queue.Full:
                        self.dropped += 1
                elif not self._put(outbox, packet):
                    return
                if self._stop.is_set():
                    return
        except BaseException as error:  # handed to the caller's thread, which re-raises it
            self._put(outbox, _Failed(error))
            return
        self._put(outbox, _End())

    def _network_step(self, network: StageChain, inbox: queue.Queue) -> Callable[[FramePacket], FramePacket]:
        """What the network thread does to a packet: the network's stages, or, for a live source
        that is ``reuse_backlog`` frames behind, the stages before the network and the last
        network outputs."""
        if not (self.live and self.reuse_backlog > 0):
            return network.process
        before = StageChain([(name, stage) for name, stage in network.stages if name in BEFORE_NETWORK])
        last: FramePacket | None = None

        def step(packet: FramePacket) -> FramePacket:
            nonlocal last
            if last is None or inbox.qsize() < self.reuse_backlog:
                last = network.process(packet)
                return last
            packet = before.process(packet)
            for name in NETWORK_OUTPUTS:
                setattr(packet, name, getattr(last, name))
            packet.network_reused = True
            self.reused += 1
            return packet

        return step

    def _work(self, process: Callable[[FramePacket], FramePacket], inbox: queue.Queue,
              outbox: queue.Queue) -> None:
        while True:
            item = self._get(inbox)
            if item is None:
                return
            if not isinstance(item, (_End, _Failed)):
                try:
                    item = process(item)
                except BaseException as error:
                    item = _Failed(error)
            if not self._put(outbox, item) or isinstance(item, (_End, _Failed)):
                return

    def _put(self, outbox: queue.Queue, item: object) -> bool:
        """Waits for room; False if the run was stopped first."""
        while not self._stop.is_set():
            try:
                outbox.put(item, timeout=CONSTANTS.poll_s)
                return True
            except queue.Full:
                continue
        return False

    def _get(self, inbox: queue.Queue) -> object | None:
        """The next item; None if the run was stopped first."""
        while not self._stop.is_set():
            try:
                return inbox.get(timeout=CONSTANTS.poll_s)
            except queue.Empty:
                continue
        return None
