"""`heightpipe run SOURCE [SOURCE ...]`: process videos, image folders, streams or webcams.

Several sources run side by side, one process each (tracking is sequential within a camera,
and processes share no GIL), and each writes its own recording set, named after its source.
"""

from __future__ import annotations

import argparse
import multiprocessing
import signal
import sys
from pathlib import Path

from core.config import Config


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("sources", nargs="+", metavar="SOURCE",
                        help="video file, image folder or glob, rtsp://… / http://… URL, or webcam index; "
                             "several run side by side, one recording set each")
    parser.add_argument("--out", metavar="PREFIX",
                        help="output prefix: writes PREFIX.rrd, PREFIX.mcap, PREFIX.tracks.csv "
                             "(default: recordings/<source name>; an existing folder means FOLDER/<source name>; "
                             "with several sources, a folder)")
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


def source_prefixes(sources: list[str], out: str | None, config: Config) -> list[Path]:
    """One output prefix per source; several sources go into one folder, names made unique."""
    if len(sources) == 1:
        return [default_prefix(sources[0], out, config)]
    folder = out if out is None or out.endswith("/") else out + "/"
    prefixes: list[Path] = []
    for source in sources:
        prefix = default_prefix(source, folder, config)
        stem, number = prefix.name, 2
        while prefix in prefixes:
            prefix, number = prefix.with_name(f"{stem}_{number}"), number + 1
        prefixes.append(prefix)
    return prefixes


def run_one(source: str, config: Config, prefix: Path) -> int:
    """Process one source and print its summary; the exit status of `heightpipe run SOURCE`."""
    from pipeline.runner import run_pipeline
    from pipeline.summary import format_summary

    if config.output.rerun != "web":
        summary = run_pipeline(source, config, prefix)
        print(format_summary(summary), file=sys.stderr)
        return 130 if summary.interrupted else 0

    from pipeline.web_view import WebViewer

    with WebViewer(config.web) as viewer:
        print(f"heightpipe: watch the run at {viewer.page_url}", file=sys.stderr, flush=True)
        summary = run_pipeline(source, config, prefix)
        print(format_summary(summary), file=sys.stderr, flush=True)
        if config.web.keep_serving and not summary.interrupted:
            viewer.wait_for_ctrl_c()
    return 130 if summary.interrupted else 0


def _camera_process(source: str, config: Config, prefix: Path) -> None:
    """One camera of several: its errors name the source, the other cameras carry on."""
    from core.errors import HeightpipeError

    try:
        code = run_one(source, config, prefix)
    except HeightpipeError as exc:
        print(f"heightpipe: error: {source}: {exc}", file=sys.stderr)
        code = exc.exit_code
    sys.exit(code)


def run_side_by_side(sources: list[str], config: Config, prefixes: list[Path]) -> int:
    """One process per source; Ctrl-C reaches them all (one process group), SIGTERM is passed on.

    The network's threads are shared out between the cameras (``height.threads`` in all), so
    two cameras on two cores do not fight over four threads.
    """
    from stages.heightnet_model import most_threads

    config.output.progress = False  # several bars on one terminal would overwrite each other
    config.height.threads = max(1, most_threads(config.height.threads) // len(sources))
    context = multiprocessing.get_context("spawn")
    processes = [context.Process(target=_camera_process, args=(source, config, prefix),
                                 name=f"heightpipe-run-{prefix.name}")
                 for source, prefix in zip(sources, prefixes)]
    for process in processes:
        process.start()

    def pass_on(_signum, _frame):
        for process in processes:
            if process.is_alive():
                process.terminate()  # SIGTERM: each run closes its outputs

    previous = signal.signal(signal.SIGTERM, pass_on)
    try:
        for process in processes:
            while True:
                try:
                    process.join()
                    break
                except KeyboardInterrupt:  # the children got it too and are closing their files
                    continue
    finally:
        signal.signal(signal.SIGTERM, previous)
    codes = [process.exitcode for process in processes]
    return next((code for code in codes if code), 0)


def main(args: argparse.Namespace, config: Config) -> int:
    from core.errors import ConfigError

    apply_flags(args, config)
    check_capture_limits(config)
    prefixes = source_prefixes(args.sources, args.out, config)
    if len(args.sources) == 1:
        return run_one(args.sources[0], config, prefixes[0])
    if config.output.rerun == "web":
        raise ConfigError("--rerun web serves one camera: run one heightpipe per camera, each with its own "
                          "web.web_port and web.grpc_port")
    return run_side_by_side(args.sources, config, prefixes)
