"""The short report `heightpipe run` prints at the end."""

from __future__ import annotations

import math
import statistics
from collections import defaultdict

from pipeline.runner import RunSummary
from stages.objects_table import ObjectRow
from stages.sink_common import camera_state_text, estimate_text

HEIGHT_ONLY_HINT = ("with only the camera height, HeightNet v2 (the default for it) measures about twice as close "
                    "(held-out scenes: people 25 cm off against 61; README, 'Your own camera'): leave height.model "
                    "empty, or --set height.model=v2 --set objects.source=network")
"""Said when a v1 model was named for a run told only the camera height: the case v2's camera
heads were built for (docs/results.md, 2026-12-04 eighth session)."""
HEADS_HINT = ("the camera's pitch and focal length above are the network's guess frame by frame, not read from "
              "the first frames; `heightpipe calibrate SOURCE --camera-height H --max-frames 300 > camera.toml` "
              "reads them from the scene's straight lines, then `heightpipe run SOURCE --config camera.toml` "
              "(held-out scenes: people 12.4 cm off against 25; README, 'Your own camera'), or give --calibration FILE")
"""Said when a v2 run decoded with its camera heads: their pitch is good to about 3-4 degrees on
cameras they never saw (docs/results.md, 2026-12-04 ninth session), and the scene's lines read
it to about one (tenth session). A run reads them itself first unless told not to
(``pipeline/scene_camera.py``)."""


def _size(path) -> str:
    size = path.stat().st_size if path.exists() else 0
    return f"{size / 1e6:.1f} MB" if size >= 1e5 else f"{size / 1e3:.0f} kB"


def _class_summary(cls: str, heights: list[float]) -> str:
    """'person 5 (median 1.74 m)'; tracks with no measurable height (top cut by the frame) are counted apart."""
    known = [h for h in heights if math.isfinite(h)]
    text = f"{cls} {len(heights)}"
    if known:
        text += f" (median {statistics.median(known):.2f} m"
        text += f", {len(heights) - len(known)} without a height)" if len(known) < len(heights) else ")"
    else:
        text += " (no height: tops outside the frame)"
    return text


def tracks_line(rows: list[ObjectRow]) -> str:
    """'13 confirmed: person 13 (median 1.73 m)', from the rows of PREFIX.objects.csv."""
    by_class: dict[str, list[float]] = defaultdict(list)
    for row in rows:
        by_class[row.cls].append(row.height_m)
    if not by_class:
        return "none confirmed"
    return (f"{len(rows)} confirmed: "
            + ", ".join(_class_summary(cls, h) for cls, h in sorted(by_class.items())))


def format_summary(summary: RunSummary) -> str:
    lines = [f"heightpipe: processed {summary.frames} frames of {summary.source} in "
             f"{summary.wall_s:.1f} s ({summary.fps:.1f} frames/s)"]
    if summary.interrupted:
        lines.append(f"  stopped by {summary.interrupted}: the outputs hold the {summary.frames} frames processed")
    lines.append(f"  capture: {summary.capture.summary()}")
    if summary.reused_network_frames:
        lines.append(f"  live source: {summary.reused_network_frames} frames given the previous frame's network "
                     "outputs while the network was behind (tracked, no heights measured on them)")
    if summary.dropped_frames:
        lines.append(f"  live source: {summary.dropped_frames} frames dropped while the pipeline was busy")
    lines.append(f"  camera: {camera_state_text(summary.camera_source, summary.height_camera)}")
    if summary.scene_camera is not None:
        read = summary.scene_camera
        lines.append(f"  camera read from {read.frames} early frames: height {read.height_m:.2f} m given, "
                     f"{estimate_text(read)}")
    if summary.camera_source == "camera-height" and summary.height_camera is None:
        lines.append(f"  hint: {HEIGHT_ONLY_HINT}")
    elif summary.height_camera is not None and summary.height_camera.source == "heads":
        lines.append(f"  hint: {HEADS_HINT}")
    lines.append(f"  tracks: {tracks_line(summary.objects.sorted_rows())}")
    if summary.events or summary.webhook:
        lines.append(f"  events: {summary.events} height-rule firings"
                     + (f"; webhook: {summary.webhook}" if summary.webhook else ""))
    if summary.frames:
        per_frame = ", ".join(f"{name} {ms:.1f}" for name, ms in summary.ms_per_frame().items())
        over = " (the network's stages: over the frames it ran on)" if summary.reused_network_frames else ""
        lines.append(f"  ms per frame{over}: {per_frame}")
    if summary.outputs is not None:
        files = [f"{p} ({_size(p)})" for p in summary.outputs.existing()]
        lines.append("  outputs: " + (", ".join(files) if files else "none"))
    return "\n".join(lines)
