"""A new height source is one stage: it adds a channel to the detections, the tracker fuses it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from core.config import TrackingConfig
from core.packets import NETWORK, CameraInfo, Detection, Frame, FramePacket, Measurement
from core.stage import Stage
from stages.tracking import TrackingStage


class StereoHeights:
    """A toy height source (say, a second camera): every detection measures 1.80 m."""

    def __init__(self, height_m: float = 1.80, noise_m: float = 0.05, bias_m: float = 0.02):
        self.reading = Measurement(height_m, noise_m, source="stereo", bias_m=bias_m)

    def process(self, packet: FramePacket) -> FramePacket:
        for detection in packet.detections:
            detection.add_height("stereo", self.reading)
        return packet

    def close(self) -> None:
        """Nothing to release."""


def _run(stages: list[Stage], network_m: float | None, frames: int = 30) -> FramePacket:
    image = np.zeros((240, 320, 3), np.uint8)
    for i in range(frames):
        heights = {} if network_m is None else {NETWORK: Measurement(network_m, 0.05, source="objects")}
        packet = FramePacket(Frame(i, i / 10, image), CameraInfo(320, 240),
                             detections=[Detection(box=(10.0 + 2 * i, 10.0, 30.0, 80.0), heights=heights,
                                                   cls="person")])
        for stage in stages:
            packet = stage.process(packet)
    return packet


def test_a_toy_stage_adds_a_channel_and_the_tracker_fuses_it_with_no_other_edit():
    toy, config = StereoHeights(), TrackingConfig(min_hits=1, stature_window=0)
    assert isinstance(toy, Stage)
    tracking = TrackingStage(config)
    track = _run([toy, tracking], network_m=1.50).tracks[0]
    # The two channels disagree by 30 cm in every frame: each has a bias on this object. The height
    # settles between them by their bias priors (the network's share of its height against the
    # toy's stated per-object part), as it does for the geometry.
    prior_n, prior_s = config.network_bias_share * 1.50, config.geometry_bias_factor * 0.02
    expected = (prior_n ** 2 * 1.80 + prior_s ** 2 * 1.50) / (prior_n ** 2 + prior_s ** 2)
    assert track.height_source == "fused"
    assert track.height_m == pytest.approx(expected, abs=0.01)
    floor = 1 / np.sqrt(1 / prior_n ** 2 + 1 / prior_s ** 2)       # frames do not average the biases
    assert floor <= track.height_std_m < 1.25 * floor
    # The filter grew a bias state of its own for the new channel.
    height = tracking.tracker.tracks[0].height
    assert height.channel_bias["stereo"] == 4 and height.updates["stereo"] == 30


def test_a_channel_measuring_alone_names_the_height_source():
    track = _run([StereoHeights(), TrackingStage(TrackingConfig(min_hits=1))], network_m=None).tracks[0]
    assert track.height_source == "stereo" and track.height_m == pytest.approx(1.80, abs=1e-6)


def test_a_damaged_frame_withholds_every_channel():
    stage, toy = TrackingStage(TrackingConfig(min_hits=1)), StereoHeights()
    image = np.zeros((240, 320, 3), np.uint8)
    packet = FramePacket(Frame(0, 0.0, image, damage="decoder flags it corrupt"), CameraInfo(320, 240),
                         detections=[Detection(box=(10.0, 10.0, 30.0, 80.0), cls="person")])
    track = stage.process(toy.process(packet)).tracks[0]
    assert track.height_source == "none" and np.isnan(track.height_m)


def test_a_copied_detection_keeps_its_own_measurements():
    first = Detection(box=(0.0, 0.0, 1.0, 1.0), heights={NETWORK: Measurement(1.7, 0.1, source="objects")})
    second = dataclasses.replace(first)
    second.add_height("stereo", Measurement(1.8, 0.05, source="stereo"))
    assert list(first.heights) == [NETWORK] and list(second.heights) == [NETWORK, "stereo"]
    assert np.isnan(first.height("stereo")) and second.height("stereo") == 1.8


def test_ignored_channels_are_not_fused():
    """tracking.ignore_channels: the network's heights alone, though another channel measures."""
    config = TrackingConfig(min_hits=1, stature_window=0, ignore_channels=["stereo"])
    track = _run([StereoHeights(), TrackingStage(config)], network_m=1.50).tracks[0]
    assert track.height_m == pytest.approx(1.50, abs=0.01)
    assert track.height_source != "fused"
