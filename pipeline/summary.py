"""The short report `heightpipe run` prints at the end."""

from __future__ import annotations

import math
import statistics
from collections import defaultdict

from pipeline.runner import RunSummary

CAMERA_SOURCES = {
    "calibration": "calibrated (full pose: a calibration file, or camera height and pitch)",
    "camera-height": "camera height given, no full calibration",
    "self": "self-calibrated from walking people: heights carry its uncertainty",
    "none": "UNCALIBRATED: no camera height or calibration given, an assumed height is used, "
            "heights are indicative only",
}


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


def format_summary(summary: RunSummary) -> str:
    lines = [f"heightpipe: processed {summary.frames} frames of {summary.source} in "
             f"{summary.wall_s:.1f} s ({summary.fps:.1f} frames/s)"]
    if summary.interrupted:
        lines.append(f"  stopped by {summary.interrupted}: the outputs hold the {summary.frames} frames processed")
    lines.append(f"  capture: {summary.capture.summary()}")
    if summary.dropped_frames:
        lines.append(f"  live source: {summary.dropped_frames} frames dropped while the pipeline was busy")
    lines.append(f"  camera: {CAMERA_SOURCES.get(summary.camera_source, summary.camera_source)}")
    by_class: dict[str, list[float]] = defaultdict(list)
    for cls, height, _std in summary.confirmed_tracks.values():
        by_class[cls].append(height)
    if by_class:
        lines.append(f"  tracks: {len(summary.confirmed_tracks)} confirmed: "
                     + ", ".join(_class_summary(cls, h) for cls, h in sorted(by_class.items())))
    else:
        lines.append("  tracks: none confirmed")
    if summary.frames:
        per_frame = ", ".join(f"{name} {ms / summary.frames:.1f}" for name, ms in summary.stage_ms.items())
        lines.append(f"  ms per frame: {per_frame}")
    if summary.outputs is not None:
        files = [f"{p} ({_size(p)})" for p in summary.outputs.existing()]
        lines.append("  outputs: " + (", ".join(files) if files else "none"))
    return "\n".join(lines)
