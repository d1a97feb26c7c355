"""The archive-wide result of a batch: every track of every video in one table.

Built from the manifest and each finished video's PREFIX.tracks.csv (one row per confirmed
track per frame), after every batch run, so the tables always describe exactly what the
manifest says is done. CSV is always written; Parquet too where pyarrow is installed.
"""

from __future__ import annotations

import csv
import os
from dataclasses import asdict, dataclass, fields
from pathlib import Path

from pipeline.batch_manifest import DONE, Manifest

TRACKS_NAME = "tracks"
VIDEOS_NAME = "videos"


@dataclass
class TrackRow:
    source: str
    video: str
    """The output name prefix: DIR/videos/<video>.{rrd,mcap,tracks.csv}."""
    track_id: int
    cls: str
    height_m: float
    """The filtered height at the track's last confirmed frame."""
    height_std_m: float
    height_source: str
    """Where the last height came from: 'network', 'geometry' or 'fused'."""
    first_time_s: float
    last_time_s: float
    frames_seen: int
    """Frames in which the track was confirmed."""


@dataclass
class VideoRow:
    source: str
    video: str
    status: str
    error: str
    frames: int
    failed_frames: int
    duration_s: float
    video_fps: float
    wall_s: float
    tracks: int
    camera: str
    size_bytes: int
    finished_at: str


def read_track_rows(tracks_csv: Path, source: str, video: str) -> list[TrackRow]:
    """Collapse a per-frame tracks CSV to one row per track."""
    rows: dict[int, TrackRow] = {}
    with open(tracks_csv, newline="", encoding="utf-8") as f:
        for record in csv.DictReader(f):
            track_id = int(record["track_id"])
            time_s, height, std = float(record["time_s"]), float(record["height_m"]), float(record["height_std_m"])
            row = rows.get(track_id)
            if row is None:
                rows[track_id] = TrackRow(source, video, track_id, record["class"], height, std,
                                          record["height_source"], time_s, time_s, 1)
                continue
            row.cls, row.height_m, row.height_std_m = record["class"], height, std
            row.height_source = record["height_source"]
            row.first_time_s = min(row.first_time_s, time_s)
            row.last_time_s = max(row.last_time_s, time_s)
            row.frames_seen += 1
    return sorted(rows.values(), key=lambda r: r.track_id)


def build_tables(manifest: Manifest, out_dir: Path) -> tuple[list[TrackRow], list[VideoRow]]:
    tracks: list[TrackRow] = []
    videos: list[VideoRow] = []
    for source, entry in sorted(manifest.entries.items()):
        videos.append(VideoRow(source, entry.output_name, entry.status, entry.error, entry.frames,
                               entry.failed_frames, round(entry.duration_s, 3), round(entry.video_fps, 3),
                               round(entry.wall_s, 3), entry.tracks, entry.camera, entry.identity.size,
                               entry.finished_at))
        if entry.status != DONE:
            continue
        for name in entry.outputs:
            if name.endswith(".tracks.csv") and (out_dir / name).is_file():
                tracks += read_track_rows(out_dir / name, source, entry.output_name)
    return tracks, videos


def _columns(row_type) -> list[str]:
    return ["class" if f.name == "cls" else f.name for f in fields(row_type)]


def _write_csv(path: Path, row_type, rows) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", newline="", encoding="utf-8") as f:
        writer = csv.writer(f)
        writer.writerow(_columns(row_type))
        for row in rows:
            writer.writerow(asdict(row).values())
    os.replace(tmp, path)


def _write_parquet(path: Path, row_type, rows) -> bool:
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return False
    types = {"int": pa.int64(), "float": pa.float64(), "str": pa.string()}  # annotations are strings
    schema = pa.schema([(name, types[f.type]) for name, f in zip(_columns(row_type), fields(row_type))])
    columns = {name: [getattr(row, f.name) for row in rows] for name, f in zip(_columns(row_type), fields(row_type))}
    tmp = path.with_name(path.name + ".tmp")
    pq.write_table(pa.table(columns, schema=schema), tmp)
    os.replace(tmp, path)
    return True


def write_tables(manifest: Manifest, out_dir: Path) -> tuple[list[Path], int]:
    """Write DIR/tracks.csv and DIR/videos.csv (+ .parquet); returns the files and the track count."""
    tracks, videos = build_tables(manifest, out_dir)
    written = []
    for name, row_type, rows in ((TRACKS_NAME, TrackRow, tracks), (VIDEOS_NAME, VideoRow, videos)):
        _write_csv(out_dir / f"{name}.csv", row_type, rows)
        written.append(out_dir / f"{name}.csv")
        if _write_parquet(out_dir / f"{name}.parquet", row_type, rows):
            written.append(out_dir / f"{name}.parquet")
    return written, len(tracks)
