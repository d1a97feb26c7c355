"""The archive-wide result of a batch: every track of every video in one table.

Built from the manifest and each finished video's PREFIX.objects.csv (one row per confirmed
track, the same table `heightpipe run` writes and prints its summary from), after every batch
run, so the tables always describe exactly what the manifest says is done. CSV is always
written; Parquet too where pyarrow is installed.
"""

from __future__ import annotations

import csv
import math
import os
from dataclasses import asdict, dataclass, fields
from pathlib import Path

from pipeline.batch_manifest import DONE, Manifest
from stages.objects_table import read_objects_csv

TRACKS_NAME = "tracks"
VIDEOS_NAME = "videos"


@dataclass
class TrackRow:
    """A row of a video's PREFIX.objects.csv (see ``stages.objects_table.ObjectRow``) with its video."""

    source: str
    video: str
    """The output name prefix: DIR/videos/<video>.{rrd,mcap,tracks.csv,objects.csv}."""
    track_id: int
    cls: str
    height_m: float
    """The filtered height at the track's last confirmed frame."""
    height_std_m: float
    height_source: str
    """Where the last height came from: 'network', 'geometry', 'box' or 'fused'."""
    first_time_s: float
    last_time_s: float
    frames_seen: int
    """Frames in which the track was confirmed."""
    frames_measured: int
    ground_x_m: float
    ground_y_m: float
    rules_fired: str
    """Rule names separated by ';'."""


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


def read_track_rows(objects_csv: Path, source: str, video: str) -> list[TrackRow]:
    return [TrackRow(source, video, row.track_id, row.cls, row.height_m, row.height_std_m, row.height_source,
                     row.first_time_s, row.last_time_s, row.frames_seen, row.frames_measured, row.ground_x_m,
                     row.ground_y_m, ";".join(row.rules_fired))
            for row in read_objects_csv(objects_csv)]


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
            if name.endswith(".objects.csv") and (out_dir / name).is_file():
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
            writer.writerow("" if isinstance(v, float) and not math.isfinite(v) else v
                            for v in asdict(row).values())
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
