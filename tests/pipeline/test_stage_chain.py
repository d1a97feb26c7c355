"""The stage builder and the frame loop shared by run, eval-tracks, calibrate and the benchmarks."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from core.config import Config
from core.packets import CameraInfo, Frame, FramePacket
from core.stage import PrimedStage, Sink, Stage
from pipeline.stage_chain import StageChain, build_stage_chain, close_all

K = np.array([[300.0, 0.0, 160.0], [0.0, 300.0, 120.0], [0.0, 0.0, 1.0]])
POSE = dict(R=np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]), t=np.array([0.0, 5.0, 0.0]))


def _camera(**changes) -> CameraInfo:
    return dataclasses.replace(CameraInfo(width=320, height=240, K=K, height_m=5.0), **changes)


@pytest.mark.parametrize("camera, geometry, names", [
    (_camera(), True, ["ground", "height", "keypoints", "matching", "objects", "tracking"]),
    (_camera(**POSE), True, ["ground", "height", "keypoints", "matching", "objects", "geometry", "tracking"]),
    (_camera(**POSE), False, ["ground", "height", "keypoints", "matching", "objects", "tracking"]),
    (_camera(dist=np.array([-0.3, 0.1, 0, 0, 0])),
     True, ["undistortion", "ground", "height", "keypoints", "matching", "objects", "tracking"]),
])
def test_the_camera_decides_undistortion_and_geometry(camera, geometry, names):
    chain = build_stage_chain(Config(), camera, geometry=geometry)
    assert [name for name, _ in chain.stages] == names
    assert all(isinstance(stage, Stage) for _, stage in chain.stages)
    primed = [name for name, stage in chain.stages if isinstance(stage, PrimedStage)]
    assert primed == [n for n in ("undistortion", "objects") if n in names]
    chain.close()


class _Recorder:
    """A stage that notes what it saw, to check the loop's order and the prime hand-over."""

    def __init__(self, name: str, log: list, primes: bool = False):
        self.name, self.log = name, log
        if primes:
            self.prime = self._prime

    def _prime(self, images):
        self.log.append((self.name, "prime", list(images)))
        return [image + 1 for image in images]

    def process(self, packet):
        self.log.append((self.name, "process", packet.frame.index))
        return packet

    def close(self):
        self.log.append((self.name, "close", None))


def test_the_loop_runs_stages_in_order_and_primes_through_them():
    log: list = []
    chain = StageChain([("a", _Recorder("a", log, primes=True)), ("b", _Recorder("b", log)),
                        ("c", _Recorder("c", log, primes=True))])
    chain.prime([0, 10])
    frames = [Frame(i, i / 10, np.zeros((4, 4, 3), np.uint8)) for i in range(2)]
    packets = list(chain.run(frames, _camera()))
    chain.close()
    assert log == [("a", "prime", [0, 10]), ("c", "prime", [1, 11]),
                   ("a", "process", 0), ("b", "process", 0), ("c", "process", 0),
                   ("a", "process", 1), ("b", "process", 1), ("c", "process", 1),
                   ("a", "close", None), ("b", "close", None), ("c", "close", None)]
    assert all(isinstance(p, FramePacket) and set(p.timings_ms) == {"a", "b", "c"} for p in packets)


def test_close_all_closes_the_rest_when_one_fails():
    closed = []

    class Broken:
        def write(self, packet):
            pass

        def close(self):
            raise OSError("disk full")

    class Fine(Broken):
        def close(self):
            closed.append(self)

    parts = [Broken(), Fine(), Fine()]
    assert all(isinstance(part, Sink) for part in parts)
    with pytest.raises(OSError, match="disk full"):
        close_all(parts)
    assert closed == parts[1:]
