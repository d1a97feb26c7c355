"""The threaded run: same packets in the same order as the sequential loop, bounded, stoppable."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import pytest

from core.config import load_config
from core.packets import CameraInfo, Frame, FramePacket
from pipeline.overlapped import OverlappedChain, split_chain
from pipeline.runner import run_pipeline
from pipeline.stage_chain import StageChain

SAMPLE = Path(__file__).resolve().parents[2] / "recordings" / "sample.mp4"
CAMERA = CameraInfo(width=8, height=8)


class _Note:
    """Appends (its name, the frame's index, the thread's name) to a shared log."""

    def __init__(self, name: str, log: list, delay_s: float = 0.0, fail_at: int | None = None):
        self.name, self.log, self.delay_s, self.fail_at = name, log, delay_s, fail_at

    def process(self, packet: FramePacket) -> FramePacket:
        if packet.frame.index == self.fail_at:
            raise RuntimeError(f"{self.name} failed at frame {self.fail_at}")
        time.sleep(self.delay_s)
        self.log.append((self.name, packet.frame.index, threading.current_thread().name))
        return packet

    def close(self) -> None:
        pass


def _frames(count: int):
    for index in range(count):
        yield Frame(index=index, time_s=index / 10.0, image=np.zeros((8, 8, 3), np.uint8))


def _chain(log: list, **network_options) -> StageChain:
    return StageChain([("ground", _Note("ground", log, **network_options)), ("height", _Note("height", log)),
                       ("matching", _Note("matching", log)), ("tracking", _Note("tracking", log))])


def test_split_after_the_last_network_stage():
    network, rest = split_chain(_chain([]))
    assert [n for n, _ in network.stages] == ["ground", "height"]
    assert [n for n, _ in rest.stages] == ["matching", "tracking"]


def test_every_frame_in_order_network_on_its_thread_the_rest_on_the_callers():
    log: list = []
    packets = list(OverlappedChain(_chain(log), CAMERA, queue_frames=2).packets(_frames(20)))
    assert [p.frame.index for p in packets] == list(range(20))
    assert set(packets[0].timings_ms) == {"ground", "height", "matching", "tracking"}
    for name in ("ground", "height", "matching", "tracking"):
        assert [index for n, index, _ in log if n == name] == list(range(20))
    threads = {name: {t for n, _, t in log if n == name} for name in ("ground", "tracking")}
    assert threads["ground"] == {"heightpipe-network"}
    assert threads["tracking"] == {threading.current_thread().name}


def test_a_stage_error_reaches_the_caller_and_the_threads_end():
    before = threading.active_count()
    with pytest.raises(RuntimeError, match="ground failed at frame 5"):
        list(OverlappedChain(_chain([], fail_at=5), CAMERA).packets(_frames(20)))
    assert threading.active_count() == before


def test_stopping_early_ends_the_threads():
    before = threading.active_count()
    packets = OverlappedChain(_chain([]), CAMERA, queue_frames=1).packets(_frames(1000))
    assert next(packets).frame.index == 0
    packets.close()
    assert threading.active_count() == before


def test_a_live_source_drops_frames_when_busy_and_counts_them():
    log: list = []
    overlapped = OverlappedChain(_chain(log, delay_s=0.01), CAMERA, queue_frames=1, live=True, live_wait_s=0.0)
    processed = [p.frame.index for p in overlapped.packets(_frames(60))]
    assert overlapped.dropped > 0
    assert len(processed) + overlapped.dropped == 60
    assert processed == sorted(processed)


class _SlowNetwork(_Note):
    """A network stage that takes ``delay_s`` and leaves its frame's index in the height map."""

    def process(self, packet: FramePacket) -> FramePacket:
        packet = super().process(packet)
        packet.height_map = np.full((8, 8), float(packet.frame.index), np.float32)
        return packet


def _paced_frames(count: int, interval_s: float):
    """A live camera: a frame every ``interval_s``."""
    for frame in _frames(count):
        time.sleep(interval_s)
        yield frame


def _chain_with_undistortion(log: list, delay_s: float) -> StageChain:
    return StageChain([("undistortion", _Note("undistortion", log)), ("ground", _SlowNetwork("ground", log, delay_s)),
                       ("tracking", _Note("tracking", log))])


def test_a_live_source_behind_the_network_reuses_its_last_outputs_before_it_drops():
    log: list = []
    overlapped = OverlappedChain(_chain_with_undistortion(log, delay_s=0.01), CAMERA, queue_frames=3,
                                 live=True, reuse_backlog=1, live_wait_s=0.0)
    packets = list(overlapped.packets(_paced_frames(60, 0.005)))
    reused = [p for p in packets if p.network_reused]
    assert overlapped.reused == len(reused) > 0
    assert len(packets) + overlapped.dropped == 60
    ran = [index for name, index, _ in log if name == "ground"]
    assert len(ran) == len(packets) - len(reused)
    # Undistortion still runs on every frame; a reused frame carries the last map the network made.
    assert [index for name, index, _ in log if name == "undistortion"] == [p.frame.index for p in packets]
    for packet in reused:
        assert packet.height_map[0, 0] == max(i for i in ran if i < packet.frame.index)
    # Without reuse the same source drops more.
    plain = OverlappedChain(_chain_with_undistortion([], delay_s=0.01), CAMERA, queue_frames=3, live=True,
                            live_wait_s=0.0)
    list(plain.packets(_paced_frames(60, 0.005)))
    assert plain.reused == 0 and plain.dropped > overlapped.dropped


def _bursts(count: int, burst: int, interval_s: float):
    """A live camera whose frames arrive ``burst`` at a time (network jitter, a decoder's flush)."""
    for frame in _frames(count):
        if frame.index % burst == 0:
            time.sleep(interval_s)
        yield frame


def test_a_burst_of_live_frames_waits_a_moment_for_room_instead_of_being_dropped():
    # Four frames at once every 80 ms (25 frames/s on average), a 5 ms network, room for two.
    waiting = OverlappedChain(_chain([], delay_s=0.005), CAMERA, queue_frames=2, live=True)
    assert len(list(waiting.packets(_bursts(40, 4, 0.08)))) == 40 and waiting.dropped == 0
    hasty = OverlappedChain(_chain([], delay_s=0.005), CAMERA, queue_frames=2, live=True, live_wait_s=0.0)
    list(hasty.packets(_bursts(40, 4, 0.08)))
    assert hasty.dropped > 0


def test_a_file_never_reuses_network_outputs():
    overlapped = OverlappedChain(_chain_with_undistortion([], delay_s=0.005), CAMERA, queue_frames=1,
                                 reuse_backlog=1)
    packets = list(overlapped.packets(_frames(30)))
    assert len(packets) == 30 and overlapped.reused == 0
    assert not any(p.network_reused for p in packets)


def test_a_file_is_never_dropped_from():
    overlapped = OverlappedChain(_chain([], delay_s=0.005), CAMERA, queue_frames=1, live=False)
    assert len(list(overlapped.packets(_frames(30)))) == 30
    assert overlapped.dropped == 0


def test_tracks_csv_identical_to_the_sequential_run_on_the_sample(tmp_path):
    """Must-show 5 of issue 23: the shipped model and the whole sample clip, both ways."""
    outputs = {}
    for overlapped in (False, True):
        config = load_config(None, [f"run.overlapped={str(overlapped).lower()}"])
        config.output.progress = False
        config.output.rerun = "off"
        config.output.mcap = False
        summary = run_pipeline(str(SAMPLE), config, tmp_path / f"overlapped_{overlapped}")
        assert summary.frames == 180 and summary.overlapped == overlapped
        outputs[overlapped] = summary.outputs.csv.read_text()
    assert outputs[True].count("\n") > 100
    assert outputs[True] == outputs[False]
