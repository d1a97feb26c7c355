"""Benchmark inputs made from the shipped sample: an upscaled copy and a looped copy, in /tmp.

Neither is committed (a 1080p clip and an hour of video would not belong in a small repo);
they are made again when a benchmark needs them and is not handed one.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import cv2

REPO_ROOT = Path(__file__).resolve().parent.parent
SAMPLE = REPO_ROOT / "recordings" / "sample.mp4"


def add_clip_arguments(parser: argparse.ArgumentParser) -> None:
    """The options shared by the benchmarks that run the sample at several sizes: the clip, the
    sizes, frames per run, config overrides and where the upscaled clips are kept."""
    parser.add_argument("--clip", type=Path, default=SAMPLE, help="the 640x360 clip (default: the sample)")
    parser.add_argument("--sizes", default="640x360,1920x1080")
    parser.add_argument("--frames", type=int, default=0, help="frames per run (0 = the whole clip)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                        help="config override for every run (repeatable)")
    parser.add_argument("--tmp", type=Path, default=Path(tempfile.gettempdir()) / "heightpipe-bench",
                        help="where the upscaled clip is made and kept")


def upscaled_clip(source: Path, width: int, height: int, out_dir: Path) -> Path:
    """``source`` resized to width x height (OpenCV, mp4v), kept in ``out_dir`` for reuse."""
    out = out_dir / f"{source.stem}_{width}x{height}.mp4"
    if out.is_file():
        return out
    capture = cv2.VideoCapture(str(source))
    fps = capture.get(cv2.CAP_PROP_FPS) or 15.0
    partial = out.with_suffix(".partial.mp4")
    writer = cv2.VideoWriter(str(partial), cv2.VideoWriter_fourcc(*"mp4v"), fps, (width, height))
    while True:
        ok, image = capture.read()
        if not ok:
            break
        writer.write(cv2.resize(image, (width, height), interpolation=cv2.INTER_CUBIC))
    writer.release()
    capture.release()
    partial.rename(out)
    return out


def looped_clip(source: Path, minutes: float, out_dir: Path) -> Path:
    """``source`` repeated until it lasts ``minutes``, by copying its packets (no re-encoding).

    Time stamps keep increasing over the joins, so the pipeline sees one long video.
    """
    import av

    out = out_dir / f"{source.stem}_looped_{minutes:g}min{source.suffix}"
    if out.is_file():
        return out
    partial = out.with_suffix(".partial" + source.suffix)
    with av.open(str(source)) as probe:
        stream = probe.streams.video[0]
        clip_ticks = stream.duration or int(probe.duration / 1e6 / stream.time_base)
        clip_s = float(clip_ticks * stream.time_base)
    loops = max(1, int(minutes * 60.0 / clip_s + 0.999))
    with av.open(str(partial), "w") as output:
        with av.open(str(source)) as first:
            out_stream = output.add_stream_from_template(first.streams.video[0])
        for loop in range(loops):
            with av.open(str(source)) as clip:
                for packet in clip.demux(clip.streams.video[0]):
                    if packet.dts is None or packet.size == 0:
                        continue
                    packet.pts = None if packet.pts is None else packet.pts + loop * clip_ticks
                    packet.dts += loop * clip_ticks
                    packet.stream = out_stream
                    output.mux(packet)
    partial.rename(out)
    return out
