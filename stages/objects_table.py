"""PREFIX.objects.csv: one row per confirmed track, the table a user hands on.

Per track: id, class, the height and its standard deviation at its last confirmed frame and
where that height came from, first and last time seen, frames in which it was confirmed (and
measured: not coasting), its mean ground position (calibrated cameras) and the height rules it
fired. ``heightpipe run`` prints its summary from these rows and ``heightpipe batch`` joins
every video's rows into the archive's tracks table, so the three always agree.

The file is rewritten whole (write to a temporary file, then rename) every ``rewrite_every_s``
of source time and on close, so a reader never sees half a table.
"""

from __future__ import annotations

import csv
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

from core.errors import HeightpipeError
from core.packets import FramePacket

OBJECTS_COLUMNS = ("track_id", "class", "height_m", "height_std_m", "height_source", "first_time_s",
                   "last_time_s", "frames_seen", "frames_measured", "ground_x_m", "ground_y_m",
                   "rules_fired")


@dataclass
class ObjectRow:
    track_id: int
    cls: str
    height_m: float
    """At the track's last confirmed frame (NaN: its top was never inside the frame)."""
    height_std_m: float
    height_source: str
    first_time_s: float
    last_time_s: float
    frames_seen: int = 1
    """Frames in which the track was confirmed (coasting ones included)."""
    frames_measured: int = 0
    """Of those, frames with a detection (not coasting)."""
    ground_x_m: float = math.nan
    ground_y_m: float = math.nan
    """Mean ground position of its measured frames (NaN: camera not calibrated)."""
    rules_fired: list[str] = field(default_factory=list)
    """Names of the rules it fired, in order (a rule firing twice is listed twice)."""

    def as_csv(self) -> list[str]:
        return [str(self.track_id), self.cls, _num(self.height_m), _num(self.height_std_m),
                self.height_source, f"{self.first_time_s:.4f}", f"{self.last_time_s:.4f}",
                str(self.frames_seen), str(self.frames_measured), _num(self.ground_x_m, 2),
                _num(self.ground_y_m, 2), ";".join(self.rules_fired)]

    @classmethod
    def from_csv(cls, record: dict[str, str]) -> ObjectRow:
        return cls(int(record["track_id"]), record["class"], _float(record["height_m"]),
                   _float(record["height_std_m"]), record["height_source"], float(record["first_time_s"]),
                   float(record["last_time_s"]), int(record["frames_seen"]), int(record["frames_measured"]),
                   _float(record["ground_x_m"]), _float(record["ground_y_m"]),
                   [name for name in record["rules_fired"].split(";") if name])


def _num(value: float, digits: int = 3) -> str:
    """Unknown (NaN, infinite) values are empty cells."""
    return f"{value:.{digits}f}" if math.isfinite(value) else ""


def _float(text: str) -> float:
    return float(text) if text else math.nan


class ObjectTable:
    """Folds each frame's confirmed tracks into one row per track."""

    def __init__(self) -> None:
        self.rows: dict[int, ObjectRow] = {}
        self._ground_sum: dict[int, tuple[float, float, int]] = {}

    def add(self, packet: FramePacket) -> None:
        now = packet.frame.time_s
        for track in packet.tracks:
            if not track.confirmed:
                continue
            row = self.rows.get(track.track_id)
            if row is None:
                row = self.rows[track.track_id] = ObjectRow(
                    track.track_id, track.cls, track.height_m, track.height_std_m, track.height_source,
                    now, now, frames_seen=0)
            row.cls, row.height_m, row.height_std_m = track.cls, track.height_m, track.height_std_m
            row.height_source, row.last_time_s = track.height_source, now
            row.frames_seen += 1
            if track.updated:
                row.frames_measured += 1
                if track.ground_xy_m is not None:
                    x, y, n = self._ground_sum.get(track.track_id, (0.0, 0.0, 0))
                    x, y, n = x + track.ground_xy_m[0], y + track.ground_xy_m[1], n + 1
                    self._ground_sum[track.track_id] = (x, y, n)
                    row.ground_x_m, row.ground_y_m = x / n, y / n
        for event in packet.events:
            if event.track_id in self.rows:
                self.rows[event.track_id].rules_fired.append(event.rule)

    def sorted_rows(self) -> list[ObjectRow]:
        return [self.rows[key] for key in sorted(self.rows)]


def write_objects_csv(path: Path, rows: list[ObjectRow]) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", newline="", encoding="utf-8") as f:
        writer = csv.writer(f)
        writer.writerow(OBJECTS_COLUMNS)
        writer.writerows(row.as_csv() for row in rows)
    os.replace(tmp, path)


def read_objects_csv(path: Path) -> list[ObjectRow]:
    with open(path, newline="", encoding="utf-8") as f:
        return [ObjectRow.from_csv(record) for record in csv.DictReader(f)]


class ObjectsSink:
    """Rewrites PREFIX.objects.csv from an ObjectTable now and then and on close.

    The runner folds each packet into the table (its summary is printed from it) before the
    sinks write; this sink only persists it.
    """

    def __init__(self, path: Path, table: ObjectTable, rewrite_every_s: float = 5.0):
        self.path = Path(path)
        self.table = table
        self.rewrite_every_s = rewrite_every_s
        self._written_at_s: float | None = None
        try:
            write_objects_csv(self.path, [])
        except OSError as exc:
            raise HeightpipeError(f"cannot write {self.path}: {exc.strerror}") from None

    def write(self, packet: FramePacket) -> None:
        now = packet.frame.time_s
        if self._written_at_s is None:
            self._written_at_s = now
        elif now - self._written_at_s >= self.rewrite_every_s:
            write_objects_csv(self.path, self.table.sorted_rows())
            self._written_at_s = now

    def close(self) -> None:
        write_objects_csv(self.path, self.table.sorted_rows())
