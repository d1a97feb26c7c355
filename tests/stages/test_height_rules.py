"""Height rules: when they fire, when they do not, and what a bad rule says."""

from __future__ import annotations

import math

import numpy as np
import pytest

from core.config import RuleConfig
from core.errors import ConfigError
from core.packets import CameraInfo, Frame, FramePacket, Track
from stages.height_rules import HeightRules, inside_polygon

FPS = 10.0
LANE = [[100, 200], [300, 200], [300, 400], [100, 400]]


def packet(index: int, tracks: list[Track]) -> FramePacket:
    return FramePacket(frame=Frame(index, index / FPS, np.zeros((4, 4, 3), np.uint8)),
                       camera=CameraInfo(640, 480), tracks=tracks)


def track(track_id: int = 1, height: float = 4.0, std: float = 0.05, cls: str = "vehicle",
          box=(150.0, 250.0, 40.0, 100.0), confirmed: bool = True, updated: bool = True,
          ground=None, foot_in_view: bool = True) -> Track:
    return Track(track_id, box, cls, height, std, confirmed=confirmed, updated=updated, ground_xy_m=ground,
                 foot_in_view=foot_in_view)


def run(rules: list[RuleConfig], frames: list[list[Track]], calibrated: bool = False) -> list[tuple[int, str, int]]:
    """(frame, rule, track) of every firing."""
    stage = HeightRules(rules, calibrated)
    fired = []
    for index, tracks in enumerate(frames):
        for event in stage.process(packet(index, tracks)).events:
            fired.append((event.frame, event.rule, event.track_id))
    return fired


def test_fires_once_after_min_frames_and_duration_and_not_again_without_cooldown():
    rule = RuleConfig(name="tall", cls="vehicle", min_height_m=3.8, min_frames=3, min_duration_s=0.3)
    # Frames 0-2 meet the condition, but 0.2 s < 0.3 s; frame 3 is the first to qualify.
    assert run([rule], [[track()]] * 10) == [(3, "tall", 1)]
    rule.min_duration_s = 0.0
    assert run([rule], [[track()]] * 10) == [(2, "tall", 1)]


@pytest.mark.parametrize("change, fires", [
    ({"height": 3.7}, False),                     # below the threshold
    ({"height": 3.8}, True),                      # at it
    ({"height": math.nan, "std": math.inf}, False),  # no height (top cut)
    ({"cls": "person"}, False),                   # another class
    ({"confirmed": False}, False),                # tentative tracks never fire
    ({"std": 0.5}, False),                        # not settled (max_std_m = 0.2)
    ({"box": (400.0, 250.0, 40.0, 100.0)}, False),  # foot point outside the lane
    ({"foot_in_view": False}, False),             # the box cut by the frame's bottom: its foot is below it
])
def test_condition(change, fires):
    rule = RuleConfig(name="tall", cls="vehicle", min_height_m=3.8, max_std_m=0.2, zone=LANE)
    fired = run([rule], [[track(**change)]] * 3)
    assert bool(fired) == fires


def test_max_height_bounds_the_range():
    rule = RuleConfig(name="van", min_height_m=1.8, max_height_m=2.5)
    assert run([rule], [[track(height=2.0)]]) and not run([rule], [[track(height=3.0)]])


def test_coasting_frames_neither_count_nor_break_a_run():
    rule = RuleConfig(name="tall", min_height_m=3.8, min_frames=3)
    frames = [[track()], [track(updated=False)], [track(updated=False)], [track()], [track()]]
    assert run([rule], frames) == [(4, "tall", 1)]
    broken = [[track()], [track()], [track(height=2.0)], [track()], [track()]]
    assert run([rule], broken) == [], "a frame below the threshold restarts the count"


def test_cooldown_lets_a_track_fire_again_only_after_a_break_and_the_cooldown():
    rule = RuleConfig(name="tall", min_height_m=3.8, cooldown_s=1.0)
    low = [track(height=2.0)]
    frames = [[track()], low, [track()], low] + [low] * 8 + [[track()]] * 3
    # Fired at 0; back above at 2 (0.2 s later: cooling down); again at 12 (1.2 s): fires.
    assert run([rule], frames) == [(0, "tall", 1), (12, "tall", 1)]


def test_each_track_and_rule_fires_on_its_own():
    rules = [RuleConfig(name="tall", min_height_m=3.8), RuleConfig(name="any_vehicle", cls="vehicle")]
    frames = [[track(1), track(2, height=1.5)], [track(1), track(2, height=1.5), track(3, height=1.7, cls="person")]]
    assert run(rules, frames) == [(0, "tall", 1), (0, "any_vehicle", 1), (0, "any_vehicle", 2)]


def test_image_zones_and_event_boxes_are_in_source_pixels_when_frames_are_scaled():
    """A 1280x960 source processed at 640x480: the lane is drawn on the source's pixels."""
    stage = HeightRules([RuleConfig(name="tall", zone=LANE)], calibrated=False)
    fired = []
    for index in range(3):
        frame_packet = packet(index, [track(track_id=1, box=(75.0, 125.0, 20.0, 50.0)),
                                      track(track_id=2, box=(160.0, 125.0, 20.0, 50.0))])
        frame_packet.frame.source_scale = (2.0, 2.0)
        fired += stage.process(frame_packet).events
    # Foot points (85, 175) and (170, 175) in frame pixels are (170, 350) and (340, 350) in the
    # source's: only the first is in the lane (and in frame pixels neither is).
    assert [event.track_id for event in fired] == [1]
    record = fired[0].to_dict()
    assert record["box"] == [150.0, 250.0, 40.0, 100.0] and record["source_scale"] == [2.0, 2.0]


def test_ground_zone_uses_the_ground_position():
    rule = RuleConfig(name="lane", zone=[[0, 0], [3.5, 0], [3.5, 50], [0, 50]], zone_frame="ground")
    assert run([rule], [[track(ground=(1.0, 20.0))]], calibrated=True)
    assert not run([rule], [[track(ground=(5.0, 20.0))]], calibrated=True)
    assert not run([rule], [[track(ground=None)]], calibrated=True)


def test_polygon():
    square = np.array(LANE, float)
    assert inside_polygon((200, 300), square) and not inside_polygon((50, 300), square)
    concave = np.array([[0, 0], [10, 0], [10, 10], [5, 2], [0, 10]], float)
    assert inside_polygon((2, 3), concave) and not inside_polygon((5, 6), concave)


@pytest.mark.parametrize("rule, calibrated, message", [
    (RuleConfig(), False, "needs a name"),
    (RuleConfig(name="a", cls="truck"), False, "class must be one of"),
    (RuleConfig(name="a", min_height_m=3, max_height_m=2), False, "below min_height_m"),
    (RuleConfig(name="a", zone=[[0, 0], [1, 1]]), False, "at least 3"),
    (RuleConfig(name="a", zone=[[0, 0], [1, 1], [1, 0]], zone_frame="ground"), False, "calibrated camera"),
    (RuleConfig(name="a", zone_frame="world"), True, "zone_frame"),
    (RuleConfig(name="a", min_frames=0), False, "min_frames"),
])
def test_bad_rules_are_config_errors(rule, calibrated, message):
    with pytest.raises(ConfigError, match=message):
        HeightRules([rule], calibrated)


def test_rule_names_are_unique():
    with pytest.raises(ConfigError, match="two"):
        HeightRules([RuleConfig(name="a"), RuleConfig(name="a")], False)
