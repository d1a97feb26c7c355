"""`heightpipe run SOURCE`: process one video, image folder, stream or webcam."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from core.config import Config


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("source", help="video file, image folder or glob, rtsp://… / http://… URL, or webcam index")
    parser.add_argument("--out", metavar="PREFIX",
                        help="output prefix: writes PREFIX.rrd, PREFIX.mcap, PREFIX.tracks.csv "
                             "(default: recordings/<source name>; an existing folder means FOLDER/<source name>)")
    parser.add_argument("--camera-height", type=float, metavar="M",
                        help="camera height above the ground in metres; left out (and no --calibration "
                             "pose): heights use an assumed camera height and are indicative only")
    parser.add_argument("--calibration", metavar="JSON",
                        help="calibration JSON: intrinsics K, distortion, optionally the pose (format in the README)")
    parser.add_argument("--reference", metavar="GOOD.mp4",
                        help="a complete recording from the same camera and settings: lets an MP4 cut off "
                             "before its index was written (power loss, full disk) be salvaged")
    parser.add_argument("--max-frames", type=int, metavar="N",
                        help="stop after N processed frames (0, the default: all)")
    parser.add_argument("--stride", type=int, metavar="N", help="process every Nth frame (default 1)")
    parser.add_argument("--rerun", choices=["spawn", "save", "web", "serve", "off"],
                        help="rerun output (default: save); web: serve rerun's web viewer as set in [web] "
                             "(loopback, ports 9090/9876 by default) and keep serving after the run until Ctrl-C")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


# Dedicated command-line flags and the config value each one sets (commands define some of them).
FLAG_TO_CONFIG = {
    "camera_height": ("camera", "height_m"),
    "calibration": ("camera", "calibration"),
    "fov": ("camera", "fov_deg"),
    "max_frames": ("capture", "max_frames"),
    "reference": ("capture", "reference"),
    "stride": ("capture", "stride"),
    "rerun": ("output", "rerun"),
}


def apply_flags(args: argparse.Namespace, config: Config) -> None:
    """Dedicated flags win over config.toml and --set (flags a command lacks are skipped)."""
    for flag, (section, key) in FLAG_TO_CONFIG.items():
        value = getattr(args, flag, None)
        if value is not None:
            setattr(getattr(config, section), key, value)
    if getattr(args, "no_progress", False):
        config.output.progress = False


def check_capture_limits(config: Config) -> None:
    from core.errors import ConfigError

    if config.capture.stride < 1:
        raise ConfigError("capture.stride (--stride) must be at least 1")
    if config.capture.max_frames < 0:
        raise ConfigError(f"capture.max_frames (--max-frames) must be 0 (all frames) or more, "
                          f"got {config.capture.max_frames}")


def default_prefix(source: str, out: str | None, config: Config) -> Path:
    name = Path(source.rstrip("/")).stem or "stream"
    if source.isdigit():
        name = f"webcam{source}"
    elif "://" in source:
        name = "".join(c if c.isalnum() else "_" for c in source.split("://", 1)[1]).strip("_")[:60] or "stream"
    if out is None:
        return Path(config.output.directory) / name
    out_path = Path(out)
    if out.endswith("/") or out_path.is_dir():
        return out_path / name
    return out_path


def main(args: argparse.Namespace, config: Config) -> int:
    from pipeline.runner import run_pipeline
    from pipeline.summary import format_summary

    apply_flags(args, config)
    check_capture_limits(config)
    prefix = default_prefix(args.source, args.out, config)
    if config.output.rerun != "web":
        summary = run_pipeline(args.source, config, prefix)
        print(format_summary(summary), file=sys.stderr)
        return 130 if summary.interrupted else 0

    from pipeline.web_view import WebViewer

    with WebViewer(config.web) as viewer:
        print(f"heightpipe: watch the run at {viewer.page_url}", file=sys.stderr, flush=True)
        summary = run_pipeline(args.source, config, prefix)
        print(format_summary(summary), file=sys.stderr, flush=True)
        if config.web.keep_serving and not summary.interrupted:
            viewer.wait_for_ctrl_c()
    return 130 if summary.interrupted else 0
