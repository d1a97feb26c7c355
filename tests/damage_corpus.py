"""Damaged-footage corpus: builds it, runs heightpipe on every case, prints the table.

    python tests/damage_corpus.py table [--out DIR]          # must-show 1 and 2 of issue 24
    python tests/damage_corpus.py fuzz [--out DIR] [--cases 210]   # must-show 4: bit-flip fuzz

Sources: the shipped sample (MPEG-4 part 2, 180 frames, index at the end) and the first
``TRAFFIC_FRAMES`` frames of the traffic-bridge clip in ../shared/real (H.264 with B-frames),
each remuxed (stream copy, no re-encoding) into MP4 (index at the end, as cameras write it),
MKV and AVI. Damage: truncation to 10/50/90 % of the bytes, 20 deleted bytes, the first 4
bytes zeroed, 10 bit flips.

For each case: frames present (clean frames whose bytes all lie before the cut; all of
them otherwise), frames recovered (what capture yields), damaged frames inserted (recovered
frames whose picture differs from the clean decode of the same file, or frames of the clean
decode missing), reported (frames capture marks damaged, plus frames counted as lost), and the
exit code of a full ``heightpipe run`` (tiny stand-in height model from tests/media.py: the
capture does not depend on the model; the shipped one runs at ~5 frames/s on this box). A
run's output "differs" when its height maps, tracks or CSV rows differ from the clean file's.
MP4s cut before their index run with ``--reference`` (the clean file); the table also shows
what the user gets without one.
"""

from __future__ import annotations

import argparse
import csv
import io
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from damage import damaged_against, delete_bytes, flip_bits, truncate, zero_header  # noqa: E402
from media import REPO_ROOT, SHARED_REAL, make_tiny_height_model  # noqa: E402

SAMPLE = REPO_ROOT / "recordings" / "sample.mp4"
TRAFFIC = SHARED_REAL / "traffic_bridge" / "car_traffic_small.mp4"
TRAFFIC_FRAMES = 200
"""Frames of the traffic clip in the corpus: one key-frame interval (160 frames) and the next
key frame, in a run short enough for this shared box."""
FUZZ_FRAMES = 36
"""Frames of the sample in the fuzz clips (three key-frame intervals): 200+ full runs stay short."""
CONTAINERS = {"mp4": "mp4", "mkv": "matroska", "avi": "avi"}
DAMAGES = {
    "cut 10 %": lambda data: truncate(data, 0.10),
    "cut 50 %": lambda data: truncate(data, 0.50),
    "cut 90 %": lambda data: truncate(data, 0.90),
    "20 bytes deleted": lambda data: delete_bytes(data, 20, seed=1),
    "header zeroed": lambda data: zero_header(data, 4),
    "10 bit flips": lambda data: flip_bits(data, 10, seed=2),
}
RUN_TIMEOUT_S = 300


def remux(source: Path, target: Path, container: str, max_frames: int | None = None) -> Path:
    """Stream copy of ``source``'s video into ``container`` (AVI: Annex B H.264, one tick a frame)."""
    import av
    from av.bitstream import BitStreamFilterContext

    with av.open(str(source)) as inp, av.open(str(target), "w", format=CONTAINERS[container]) as out:
        in_stream = inp.streams.video[0]
        out_stream = out.add_stream_from_template(in_stream)
        avi = container == "avi"
        if avi:  # AVI has no time stamps, only a frame rate
            out_stream.time_base = 1 / Fraction(in_stream.average_rate)
        # Stream formats carry the codec set-up in band: H.264 as Annex B, MPEG-4 with its VOL header.
        in_band = {"h264": "h264_mp4toannexb", "mpeg4": "dump_extra"}.get(in_stream.codec_context.name)
        needs_in_band = container in ("ts", "h264") or (avi and in_band == "h264_mp4toannexb")
        annex_b = BitStreamFilterContext(in_band, in_stream, out_stream) if in_band and needs_in_band else None
        count = 0
        for packet in inp.demux(in_stream):
            if packet.dts is None:
                continue
            if max_frames is not None and count >= max_frames:
                break
            for out_packet in (annex_b.filter(packet) if annex_b else [packet]):
                if avi:
                    out_packet.time_base, out_packet.dts, out_packet.pts = out_stream.time_base, count, None
                    out_packet.duration = 1
                out_packet.stream = out_stream
                out.mux(out_packet)
            count += 1
    return target


def packet_ends(path: Path) -> list[int]:
    """Byte offset where each video packet of a clean file ends, in decode order."""
    import av

    with av.open(str(path)) as container:
        return [packet.pos + packet.size for packet in container.demux(video=0)
                if packet.size and packet.pos is not None and packet.pos >= 0]


@dataclass
class Capture:
    images: dict
    damaged: set
    lost: int
    error: str


def capture(path: Path, reference: Path | None) -> Capture:
    """What heightpipe's capture makes of a file: images by index, damaged indices, lost count."""
    from core.config import CaptureConfig
    from core.errors import HeightpipeError
    from stages.capture import open_source

    try:
        source = open_source(str(path), CaptureConfig(reference=str(reference or "")))
    except HeightpipeError as exc:
        return Capture({}, set(), 0, str(exc))
    try:
        images, damaged = {}, set()
        for frame in source.frames():
            images[frame.index] = frame.image
            if frame.damage:
                damaged.add(frame.index)
        return Capture(images, damaged, source.stats.failed, "")
    finally:
        source.close()


def run_heightpipe(video: Path, prefix: Path, model: Path, reference: Path | None) -> tuple[int, str, list]:
    """A full ``heightpipe run`` in-process: (exit code, stderr, what it measured per frame).

    What it measured: frame index, time, a digest of the height map and the tracks (id, class,
    box, height) of every frame in the MCAP, and the CSV rows (without ``frame_damaged``, so that
    marking damage does not itself count as a different output). Exit code 1 with "Traceback"
    in place of stderr means an exception escaped the command."""
    import contextlib
    import traceback

    from pipeline import cli

    args = ["run", str(video), "--out", str(prefix), "--rerun", "off", "--no-progress",
            "--set", f'height.model="{model}"']
    if reference is not None:
        args += ["--reference", str(reference)]
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err):
            code = cli.main(args)
    except BaseException:  # noqa: BLE001 (anything escaping main is what a user sees as a traceback)
        return 1, "Traceback\n" + traceback.format_exc(), []
    measured = []
    mcap_path, csv_path = Path(f"{prefix}.mcap"), Path(f"{prefix}.tracks.csv")
    if code == 0:
        measured = _measured(mcap_path)
        with open(csv_path, newline="") as stream:
            rows = list(csv.reader(stream))
        damaged = rows[0].index("frame_damaged") if rows else 0
        measured += [tuple(value for i, value in enumerate(row) if i != damaged) for row in rows]
    mcap_path.unlink(missing_ok=True)
    csv_path.unlink(missing_ok=True)
    return code, err.getvalue(), measured


def _measured(mcap_path: Path) -> list:
    import hashlib

    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    from stages.track_record import tracks_from_record

    frames = []
    with open(mcap_path, "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, _, decoded in reader.iter_decoded_messages(topics=["/tracks", "/camera/height"]):
            if channel.topic == "/tracks":
                frames.append((decoded.frame_index, round(decoded.time_s, 4), [
                    (t.track_id, t.cls, tuple(round(v, 1) for v in t.box), round(t.height_m, 3))
                    for t in tracks_from_record(decoded)]))
            else:
                frames.append(hashlib.sha1(bytes(decoded.data)).hexdigest())
    return frames


def _run_case(args):
    return run_heightpipe(*args)


def _pool() -> ProcessPoolExecutor:
    import multiprocessing

    return ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn"))


class Runner:
    """Runs cases in a worker process (imports paid once; a crash in FFmpeg costs one case)."""

    def __init__(self):
        self.pool = _pool()

    def run(self, *args) -> tuple[int, str, list]:
        future = self.pool.submit(_run_case, args)
        try:
            return future.result(timeout=RUN_TIMEOUT_S)
        except TimeoutError:
            self.pool.shutdown(wait=False, cancel_futures=True)
            self.pool = _pool()
            return -1, "hang", []
        except BrokenProcessPool:
            self.pool = _pool()
            return -2, "crash", []

    def close(self):
        self.pool.shutdown()


def build_sources(out: Path) -> list[tuple[str, Path]]:
    """Clean files: (label, path) for each source in each container."""
    sources = [("sample", SAMPLE, None)]
    if TRAFFIC.exists():
        sources.append(("traffic", TRAFFIC, TRAFFIC_FRAMES))
    built = []
    for label, path, frames in sources:
        for container in CONTAINERS:
            target = out / f"{label}.{container}"
            if not target.exists():
                remux(path, target, container, frames)
            built.append((f"{label} {container}", target))
    return built


def reports_damage(code: int, stderr: str) -> bool:
    return code == 2 or "damaged" in stderr or "failed to decode" in stderr


def describe_run(code: int, stderr: str, measured: list, clean: list, cut: bool) -> str:
    if code in (-1, -2) or "Traceback" in stderr:
        return {-1: "HANG", -2: "CRASH"}.get(code, "TRACEBACK")
    if code != 0:
        return f"exit {code}: " + stderr.strip().splitlines()[-1].removeprefix("heightpipe: error: ")[:70] + "…"
    if cut:  # fewer frames, and a different background model primed from them: not comparable
        return "ran to the cut" + (", damage reported" if reports_damage(code, stderr) else "")
    if measured == clean:
        return "same as clean"
    return "differs, damage reported" if reports_damage(code, stderr) else "DIFFERS, NOTHING REPORTED"


def table(out: Path, only: str = "") -> None:
    model = make_tiny_height_model(out / "tiny.onnx")
    runner = Runner()
    print("| file | damage | frames present | recovered | lost (reported) | damaged inserted | reported | "
          "missed | false alarms | exit | run output |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    totals = dict(present=0, recovered=0, inserted=0, reported=0, missed=0, false_alarms=0)
    for label, clean_path in build_sources(out):
        if only and only not in label:
            continue
        clean = capture(clean_path, None)
        clean_code, _, clean_rows = runner.run(clean_path, out / "clean", model, None)
        ends = sorted(packet_ends(clean_path))
        data = clean_path.read_bytes()
        for name, damage in DAMAGES.items():
            stem = f"{label.replace(' ', '_')}_{name.replace(' ', '_').replace('%', 'pc')}"
            damaged_path = out / f"{stem}{clean_path.suffix}"
            damaged_path.write_bytes(damage(data))
            cut = len(damaged_path.read_bytes()) if name.startswith("cut") else None
            present = (sum(end <= cut for end in ends) if cut is not None else len(clean.images))
            reference = clean_path if clean_path.suffix == ".mp4" else None
            got = capture(damaged_path, reference)
            recovered = len(got.images)
            differing = damaged_against(clean.images, got.images)
            lost = max(0, present - recovered)
            inserted, reported = len(differing), len(got.damaged)
            missed = len(differing - got.damaged)
            false_alarms = len(got.damaged - differing)
            code, stderr, rows = runner.run(damaged_path, out / "run", model, reference)
            outcome = describe_run(code, stderr, rows, clean_rows, cut is not None)
            print(f"| {label} | {name} | {present} | {recovered} | {lost} ({got.lost}) | {inserted} | {reported} | "
                  f"{missed} | {false_alarms} | {code} | {outcome} |", flush=True)
            if reference is not None and got.error == "" and name.startswith("cut") and recovered:
                no_ref_code, no_ref_err, _ = runner.run(damaged_path, out / "run", model, None)
                if no_ref_code != 0:
                    print(f"| {label} | {name}, no --reference | {present} | 0 | {present} | | | | | {no_ref_code} | "
                          f"{describe_run(no_ref_code, no_ref_err, [], [], True)} |", flush=True)
            totals["present"] += present
            totals["recovered"] += min(recovered, present)
            totals["inserted"] += inserted
            totals["reported"] += reported
            totals["missed"] += missed
            totals["false_alarms"] += false_alarms
    runner.close()
    print(f"\ntotals: {totals}; clean runs exit {clean_code}")


def fuzz(out: Path, cases: int) -> None:
    """Bit flips (1 to 20, anywhere in the file) in 60-frame clips of the sample, each container."""
    import numpy as np

    model = make_tiny_height_model(out / "tiny.onnx")
    runner = Runner()
    clips = []
    for container in CONTAINERS:
        clip = out / f"fuzz_clean.{container}"
        if not clip.exists():
            remux(SAMPLE, clip, container, FUZZ_FRAMES)
        code, _, rows = runner.run(clip, out / "fuzz_clean", model, None)
        assert code == 0, f"the clean {container} clip does not run"
        clips.append((container, clip, clip.read_bytes(), rows))
    counts = dict(same=0, differs_reported=0, differs_silent=0, error_exit=0, traceback=0, hang=0, crash=0)
    silent = []
    start = time.monotonic()
    for case in range(cases):
        container, clip, data, clean_rows = clips[case % len(clips)]
        rng = np.random.default_rng(case)
        damaged = flip_bits(data, int(rng.integers(1, 21)), seed=case, low=0.0, high=1.0)
        path = out / f"fuzz.{container}"
        path.write_bytes(damaged)
        code, stderr, rows = runner.run(path, out / "fuzz", model, None)
        if code == -1:
            counts["hang"] += 1
        elif code == -2:
            counts["crash"] += 1
        elif "Traceback" in stderr:
            counts["traceback"] += 1
            silent.append((case, container, stderr.strip().splitlines()[-1]))
        elif code == 2:
            counts["error_exit"] += 1
        elif rows == clean_rows:
            counts["same"] += 1
        elif reports_damage(code, stderr):
            counts["differs_reported"] += 1
        else:
            counts["differs_silent"] += 1
            silent.append((case, container, stderr.strip().splitlines()[1] if stderr else ""))
        if (case + 1) % 10 == 0:
            print(f"  {case + 1} cases, {time.monotonic() - start:.0f} s: {counts}", flush=True)
    runner.close()
    print(f"{cases} bit-flip cases in {time.monotonic() - start:.0f} s: {counts}")
    for case in silent:
        print("  case", *case)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("what", choices=["table", "fuzz"])
    parser.add_argument("--out", type=Path, help="corpus folder (default: a temporary one)")
    parser.add_argument("--cases", type=int, default=210, help="fuzz cases")
    parser.add_argument("--only", default="", metavar="TEXT", help="table: only the files whose label holds TEXT")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="heightpipe-damage-") as scratch:
        out = args.out or Path(scratch)
        out.mkdir(parents=True, exist_ok=True)
        table(out, args.only) if args.what == "table" else fuzz(out, args.cases)


if __name__ == "__main__":
    main()
