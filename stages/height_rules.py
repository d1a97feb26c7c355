"""Height rules: "tell me when a vehicle over 3.8 m enters this lane".

Each ``[[rules]]`` entry of config.toml names a class, a height range, an optional zone (a
polygon in image pixels or in ground metres) and how long the condition must hold. The stage
runs after tracking and looks at every confirmed track:

    condition = class matches, height known and in range (and settled: std <= max_std_m),
                foot point (bottom centre of the box, or the ground position) inside the zone
                (an image zone holds no track whose box the frame's bottom edge cuts: its foot
                is out of the picture)

A rule fires for a track once the condition has held for ``min_frames`` processed frames in a
row and ``min_duration_s`` of source time. It then stays quiet for that track while the
condition holds; after it breaks off, it may fire again once ``cooldown_s`` has passed since
the last firing (``cooldown_s = 0``: once per track). A frame in which the track coasts (no
detection, its box predicted) neither counts nor breaks the run. Each firing is a
``RuleEvent`` on ``packet.events``; the sinks write it out (JSONL, MCAP, rerun, webhook).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from core.config import RuleConfig
from core.errors import ConfigError
from core.packets import OBJECT_CLASSES, Frame, FramePacket, Track

ZONE_FRAMES = ("image", "ground")
EVENT_JSON_SCHEMA = {
    "title": "heightpipe.RuleEvent",
    "description": "A height rule fired for a confirmed track (stages/height_rules.py)",
    "type": "object",
    "properties": {
        "rule": {"type": "string"}, "track_id": {"type": "integer"}, "class": {"type": "string"},
        "frame": {"type": "integer"}, "time_s": {"type": "number"},
        "height_m": {"type": "number"}, "height_std_m": {"type": "number"},
        "height_source": {"type": "string"},
        "box": {"type": "array", "items": {"type": "number"}, "description": "x, y, w, h in source pixels"},
        "source_scale": {"type": "array", "items": {"type": "number"},
                         "description": "source pixels per pixel of the recorded images, x and y"},
        "ground_xy_m": {"type": ["array", "null"], "items": {"type": "number"}},
    },
}
"""Schema of ``RuleEvent.to_dict()``: the MCAP /events channel's."""


@dataclass
class RuleEvent:
    """One firing of one rule for one track."""

    rule: str
    track_id: int
    cls: str
    frame: int
    time_s: float
    height_m: float
    height_std_m: float
    height_source: str
    box: tuple[float, float, float, float]
    """x, y, w, h in source pixels."""
    ground_xy_m: tuple[float, float] | None
    source_scale: tuple[float, float] = (1.0, 1.0)
    """Source pixels per pixel of the processed (and recorded) frame: ``box`` / this is the box on
    the recorded image."""

    def to_dict(self) -> dict:
        """The JSON object written to PREFIX.events.jsonl, MCAP /events and the webhook."""
        return {"rule": self.rule, "track_id": self.track_id, "class": self.cls,
                "frame": self.frame, "time_s": round(self.time_s, 4),
                "height_m": round(self.height_m, 3), "height_std_m": round(self.height_std_m, 3),
                "height_source": self.height_source, "box": [round(float(v), 1) for v in self.box],
                "ground_xy_m": (None if self.ground_xy_m is None
                                else [round(float(v), 3) for v in self.ground_xy_m]),
                "source_scale": [round(float(v), 6) for v in self.source_scale]}

    def text(self) -> str:
        """One line for a log: 'tall_vehicle: #12 vehicle 3.95 m ±6 cm'."""
        return f"{self.rule}: #{self.track_id} {self.cls} {self.height_m:.2f} m \u00b1{self.height_std_m * 100:.0f} cm"


def check_rules(rules: list[RuleConfig], calibrated: bool) -> None:
    """Every rule must be complete and consistent; ground zones need a calibrated camera."""
    names = set()
    for rule in rules:
        where = f"rule {rule.name!r}" if rule.name else "a [[rules]] entry"
        if not rule.name:
            raise ConfigError("every [[rules]] entry needs a name")
        if rule.name in names:
            raise ConfigError(f"two [[rules]] entries are named {rule.name!r}")
        names.add(rule.name)
        if rule.cls and rule.cls not in OBJECT_CLASSES:
            raise ConfigError(f"{where}: class must be one of {', '.join(OBJECT_CLASSES)} or \"\", "
                              f"got {rule.cls!r}")
        if rule.min_height_m < 0 or rule.max_height_m < 0 or rule.max_std_m < 0:
            raise ConfigError(f"{where}: heights must be >= 0 (0 = no bound)")
        if rule.max_height_m and rule.max_height_m < rule.min_height_m:
            raise ConfigError(f"{where}: max_height_m {rule.max_height_m} is below min_height_m "
                              f"{rule.min_height_m}")
        if rule.zone_frame not in ZONE_FRAMES:
            raise ConfigError(f"{where}: zone_frame must be 'image' or 'ground', got {rule.zone_frame!r}")
        if rule.zone and (len(rule.zone) < 3 or any(len(point) != 2 for point in rule.zone)):
            raise ConfigError(f"{where}: zone must be a polygon of at least 3 [x, y] points")
        if rule.zone and rule.zone_frame == "ground" and not calibrated:
            raise ConfigError(f"{where}: a zone in ground metres needs a calibrated camera "
                              "(--calibration, or camera height and pitch); use zone_frame = 'image'")
        if rule.min_frames < 1 or rule.min_duration_s < 0 or rule.cooldown_s < 0:
            raise ConfigError(f"{where}: min_frames must be >= 1, min_duration_s and cooldown_s >= 0")


def inside_polygon(point: tuple[float, float], polygon: np.ndarray) -> bool:
    """Even-odd ray casting; a point on an edge may count either way."""
    x, y = point
    xs, ys = polygon[:, 0], polygon[:, 1]
    xs_next, ys_next = np.roll(xs, -1), np.roll(ys, -1)
    crosses = (ys > y) != (ys_next > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        x_at_y = xs + (y - ys) * (xs_next - xs) / (ys_next - ys)
    return bool(np.count_nonzero(crosses & (x < x_at_y)) % 2)


def foot_point(track: Track) -> tuple[float, float]:
    """Bottom centre of the box: where the object stands, in image pixels."""
    x, y, w, h = track.box
    return x + w / 2.0, y + h


@dataclass
class _RunState:
    """One rule on one track: the current run of frames meeting the condition."""

    started_s: float | None = None
    frames: int = 0
    fired_in_run: bool = False
    last_fired_s: float | None = None


class HeightRules:
    """The stage: adds a ``RuleEvent`` to ``packet.events`` for every firing this frame."""

    def __init__(self, rules: list[RuleConfig], calibrated: bool):
        check_rules(rules, calibrated)
        self.rules = list(rules)
        self._zones = [np.asarray(rule.zone, dtype=np.float64) if rule.zone else None for rule in rules]
        self._state: dict[tuple[int, int], _RunState] = {}

    def condition(self, index: int, track: Track, frame: Frame | None = None) -> bool:
        """Does ``track`` meet rule ``index`` now? Image zones are in source pixels, so the foot
        point is taken there through ``frame`` (None: the frame is the source's size)."""
        rule, zone = self.rules[index], self._zones[index]
        if rule.cls and track.cls != rule.cls:
            return False
        height = track.height_m
        if not math.isfinite(height) or height < rule.min_height_m:
            return False
        if rule.max_height_m and height > rule.max_height_m:
            return False
        if rule.max_std_m and not track.height_std_m <= rule.max_std_m:
            return False
        if zone is None:
            return True
        if rule.zone_frame == "ground":
            return track.ground_xy_m is not None and inside_polygon(track.ground_xy_m, zone)
        if not track.foot_in_view:     # the foot is below the picture: in no zone drawn on it
            return False
        foot = foot_point(track)
        return inside_polygon(frame.to_source(foot) if frame is not None else foot, zone)

    def process(self, packet: FramePacket) -> FramePacket:
        now = packet.frame.time_s
        alive = set()
        for track in packet.tracks:
            if not track.confirmed:
                continue
            for index, rule in enumerate(self.rules):
                key = (index, track.track_id)
                alive.add(key)
                state = self._state.setdefault(key, _RunState())
                if not track.updated:  # coasting: a predicted box proves nothing either way
                    continue
                if not self.condition(index, track, packet.frame):
                    state.started_s, state.frames, state.fired_in_run = None, 0, False
                    continue
                if state.started_s is None:
                    state.started_s = now
                state.frames += 1
                if state.fired_in_run or state.frames < rule.min_frames:
                    continue
                if now - state.started_s < rule.min_duration_s - 1e-9:
                    continue
                if state.last_fired_s is not None and (
                        rule.cooldown_s == 0 or now - state.last_fired_s < rule.cooldown_s):
                    continue
                state.fired_in_run, state.last_fired_s = True, now
                packet.events.append(RuleEvent(
                    rule=rule.name, track_id=track.track_id, cls=track.cls, frame=packet.frame.index,
                    time_s=now, height_m=track.height_m, height_std_m=track.height_std_m,
                    height_source=track.height_source,
                    box=tuple(float(v) for v in packet.frame.to_source(track.box)),
                    ground_xy_m=track.ground_xy_m, source_scale=packet.frame.source_scale))
        for key in set(self._state) - alive:  # the track is gone (or no longer confirmed)
            del self._state[key]
        return packet

    def close(self) -> None:
        """Nothing to release (the Stage contract, core/stage.py)."""
