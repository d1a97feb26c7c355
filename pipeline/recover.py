"""``heightpipe recover PREFIX | FILE.mcap | FILE.rrd``: valid files back from a killed run.

A run killed hard (kill -9, power loss, out of memory) cannot close its outputs:

- the MCAP has no summary or index and ends in an unfinished chunk. The mcap library's
  default reader orders messages by log time, meets that chunk first and yields nothing;
  a *linear* read (file order) gets every message of every complete chunk. Recovery reads
  linearly and writes the same schemas, channels, metadata and messages into a new MCAP with
  a summary and index, which every reader opens.
- the ``.rrd`` has no footer, so ``rerun rrd verify`` fails although its rows are readable.
  Recovery re-saves it through rerun's own reader (``rerun rrd merge --continue-on-error``).
- the CSV is flushed after every frame; a line cut mid-write is dropped.

The damaged original is kept beside the recovered file as ``FILE.unfinished``: a forensic user
may want the bytes as they were. ``heightpipe replay`` reads an unfinished MCAP through the
same linear reader (``linear_records``), so it replays what recovery would keep.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from core.config import Config
from core.errors import HeightpipeError

IMAGE_TOPIC = "/camera/image"
"""One message per processed frame: recovered frames are counted on it."""
ORIGINAL_SUFFIX = ".unfinished"
"""Appended to a damaged file's name when its recovered version takes its place."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("target", metavar="PREFIX|FILE.mcap|FILE.rrd",
                        help="what a killed `heightpipe run` left: the output prefix (recovers "
                             "PREFIX.mcap, PREFIX.rrd and PREFIX.tracks.csv, those that exist) or one file")


def main(args: argparse.Namespace, config: Config) -> int:
    paths = files_to_recover(Path(args.target))
    for path in paths:
        print(recover_file(path).describe(), file=sys.stderr)
    return 0


def files_to_recover(target: Path) -> list[Path]:
    if target.suffix in (".mcap", ".rrd", ".csv"):
        if not target.is_file():
            raise HeightpipeError(f"no such file: {target}")
        return [target]
    found = [target.with_name(target.name + suffix) for suffix in (".mcap", ".rrd", ".tracks.csv")]
    found = [path for path in found if path.is_file()]
    if not found:
        raise HeightpipeError(f"nothing to recover: no {target}.mcap, {target}.rrd or {target}.tracks.csv")
    return found


@dataclass
class Recovery:
    path: Path
    frames: int
    """Frames in the recovered (or already complete) file."""
    complete: bool
    """The file was already valid: nothing was rewritten."""
    lost: str = ""
    """What stopped the linear read ("" = nothing was cut off)."""
    counted: str = "frames"
    """What ``frames`` counts (a CSV only has rows for frames with confirmed tracks)."""

    def describe(self) -> str:
        if self.complete:
            return f"{self.path}: complete, {self.frames} {self.counted}; nothing to recover"
        text = (f"{self.path}: recovered {self.frames} {self.counted} "
                f"(original kept as {self.path.name}{ORIGINAL_SUFFIX})")
        if self.lost:
            text += f"; lost after them: {self.lost}"
        return text


def recover_file(path: Path) -> Recovery:
    if path.suffix == ".mcap":
        return recover_mcap(path)
    if path.suffix == ".rrd":
        return recover_rrd(path)
    return recover_csv(path)


# --- MCAP --------------------------------------------------------------------------------------

class UnreadableTail(Exception):
    """A linear read stopped before the end of the file: cut off or corrupt from here on."""


def linear_records(stream) -> Iterator[object]:
    """MCAP records in file order (chunks opened), raising ``UnreadableTail`` where reading fails.

    File order, unlike the readers' default log-time order, reaches every complete chunk of
    a file whose writer died before writing its summary.
    """
    from mcap.stream_reader import StreamReader

    records = StreamReader(stream, skip_magic=False, validate_crcs=True).records
    while True:
        try:
            record = next(records)
        except StopIteration:
            return
        except Exception as exc:  # mcap, zstd, lz4 and struct errors on bad bytes
            raise UnreadableTail(describe_read_error(exc)) from None
        yield record


def describe_read_error(exc: Exception) -> str:
    import struct

    from mcap.exceptions import EndOfFile, InvalidMagic, RecordLengthLimitExceeded

    if isinstance(exc, InvalidMagic):
        return "not an MCAP file (wrong magic bytes)"
    if isinstance(exc, (EndOfFile, struct.error)):
        return "the file is cut off mid-record"
    if isinstance(exc, RecordLengthLimitExceeded):  # foxglove-sdk sets a chunk's length on closing it
        return "it ends in an unfinished chunk"
    return f"{type(exc).__name__}: {exc}"


def mcap_is_complete(path: Path) -> bool:
    """The summary section is there and readable (what the default reader needs)."""
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as stream:
            return make_reader(stream).get_summary() is not None
    except Exception:  # any failure to read the summary means: not complete
        return False


def recover_mcap(path: Path) -> Recovery:
    if mcap_is_complete(path):
        return Recovery(path, _summary_frames(path), complete=True)
    temporary = path.with_name(path.name + ".recovering")
    try:
        frames, lost = _rewrite_mcap(path, temporary)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
    if frames == 0 and lost:
        temporary.unlink(missing_ok=True)
        raise HeightpipeError(f"cannot recover {path}: {lost} before its first frame")
    _replace_keeping_original(path, temporary)
    return Recovery(path, frames, complete=False, lost=lost)


def _rewrite_mcap(source: Path, target: Path) -> tuple[int, str]:
    """Copies every readable record of ``source`` into a finished MCAP; (frames, why it stopped)."""
    from mcap.records import Attachment, Channel, Header, Message, Metadata, Schema
    from mcap.writer import Writer

    schema_ids: dict[int, int] = {0: 0}
    channel_ids: dict[int, int] = {}
    image_channels: set[int] = set()
    frames, lost = 0, ""
    with open(source, "rb") as stream, open(target, "wb") as out:
        writer = Writer(out)
        started = False
        try:
            for record in linear_records(stream):
                if isinstance(record, Header):
                    writer.start(profile=record.profile, library=record.library)
                    started = True
                    continue
                if not started:
                    writer.start()
                    started = True
                if isinstance(record, Schema) and record.id not in schema_ids:
                    schema_ids[record.id] = writer.register_schema(record.name, record.encoding, record.data)
                elif isinstance(record, Channel) and record.id not in channel_ids:
                    channel_ids[record.id] = writer.register_channel(
                        record.topic, record.message_encoding, schema_ids.get(record.schema_id, 0),
                        dict(record.metadata))
                    if record.topic == IMAGE_TOPIC:
                        image_channels.add(channel_ids[record.id])
                elif isinstance(record, Message) and record.channel_id in channel_ids:
                    channel = channel_ids[record.channel_id]
                    writer.add_message(channel, record.log_time, record.data, record.publish_time,
                                       record.sequence)
                    frames += channel in image_channels
                elif isinstance(record, Metadata):
                    writer.add_metadata(record.name, dict(record.metadata))
                elif isinstance(record, Attachment):
                    writer.add_attachment(record.create_time, record.log_time, record.name,
                                          record.media_type, record.data)
        except UnreadableTail as exc:
            lost = str(exc)
        if not started:
            writer.start()
        writer.finish()
    return frames, lost


def _summary_frames(path: Path) -> int:
    from mcap.reader import make_reader

    with open(path, "rb") as stream:
        summary = make_reader(stream).get_summary()
    if summary is None or summary.statistics is None:
        return 0
    return sum(count for channel_id, count in summary.statistics.channel_message_counts.items()
               if channel_id in summary.channels and summary.channels[channel_id].topic == IMAGE_TOPIC)


def _replace_keeping_original(path: Path, recovered: Path) -> None:
    os.replace(path, path.with_name(path.name + ORIGINAL_SUFFIX))
    os.replace(recovered, path)


# --- .rrd --------------------------------------------------------------------------------------

def rerun_cli(*args: str) -> subprocess.CompletedProcess:
    """rerun's command-line tool, the binary shipped inside rerun-sdk.

    Called directly: ``python -m rerun_cli`` (0.41) drops the binary's exit status.
    """
    import rerun_cli as package

    binary = Path(package.__file__).with_name("rerun")
    return subprocess.run([str(binary), *args], capture_output=True, text=True, timeout=600)


def rrd_is_complete(path: Path) -> bool:
    return rerun_cli("rrd", "verify", str(path)).returncode == 0


def rrd_frames(path: Path) -> int:
    """Distinct frames with a camera image in an .rrd (what a viewer can step through)."""
    import warnings

    from rerun.chunk import RrdReader

    frames: set[int] = set()
    with warnings.catch_warnings():  # "no footer": expected of the file being recovered
        warnings.simplefilter("ignore")
        chunks = list(RrdReader(path).stream())
    for chunk in chunks:
        if chunk.entity_path == IMAGE_TOPIC and not chunk.is_static:
            frames.update(chunk.to_record_batch().column("frame").to_pylist())
    return len(frames)


def recover_rrd(path: Path) -> Recovery:
    if rrd_is_complete(path):
        return Recovery(path, rrd_frames(path), complete=True)
    temporary = path.with_name(path.name + ".recovering.rrd")
    result = rerun_cli("rrd", "merge", "--continue-on-error", "-o", str(temporary), str(path))
    if result.returncode != 0 or not temporary.is_file() or not rrd_is_complete(temporary):
        temporary.unlink(missing_ok=True)
        reason = (result.stderr.strip().splitlines() or ["rerun could not re-save it"])[-1]
        raise HeightpipeError(f"cannot recover {path}: {reason}")
    _replace_keeping_original(path, temporary)
    return Recovery(path, rrd_frames(path), complete=False)


# --- CSV ---------------------------------------------------------------------------------------

def recover_csv(path: Path) -> Recovery:
    """Drops a last line cut off mid-write (the sink flushes whole frames, so rarely needed)."""
    data = path.read_bytes()
    rows = data.count(b"\n")
    frames = len({line.split(b",", 1)[0] for line in data.splitlines()[1:rows] if line})
    if not data or data.endswith(b"\n"):
        return Recovery(path, frames, complete=True, counted="frames with tracks")
    path.with_name(path.name + ORIGINAL_SUFFIX).write_bytes(data)
    path.write_bytes(data[:data.rfind(b"\n") + 1])
    return Recovery(path, frames, complete=False, lost="a row cut off mid-write",
                    counted="frames with tracks")
