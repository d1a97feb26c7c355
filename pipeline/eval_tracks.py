"""``heightpipe eval-tracks DATA``: tracking quality and per-object height error on generator data.

For every sequence of a synthetic dataset (``synth.dataset``) the tracking pipeline runs as in
``heightpipe run`` (feature matching, object extraction, geometry, tracking) with heights from
the shipped network or, with ``--heights oracle``, from the ground-truth height map. Reported:

* HOTA, MOTA, IDF1 and ID switches over all sequences (class-agnostic boxes, IoU 0.5 for
  CLEAR / Identity). The metrics are computed by trackeval when the optional ``eval`` extra is
  installed and otherwise by the built-in implementation, which follows trackeval's code.
* Height error per ground-truth object: the final height of the track that followed it versus
  the truth, next to the single-frame estimates (detections) versus the truth; per class and
  per camera height.
* Occlusions: objects hidden for a while and seen again, whether their track kept its id and
  its height.
* Misses (``--misses``): every required box by what became of it (tracked, detected but not
  tracked, merged with other objects, box off, not detected), per class, size and scene; and
  every wrong detection by what lies under it (only don't-care objects, several objects, a
  required object with a box off, part of one, nothing).
* Detections before tracking: recall and precision of object extraction's boxes (IoU 0.5), of
  any class and with the class right, per class, box height, camera height, weather and time of
  day, printed after the HOTA/IDF1 table and under "detection" in ``--json``.
* Localisation (``--localisation``, ``eval_localisation``): the scores again with the boxes'
  horizontal extent, vertical extent or whole box taken from the objects they are about: how much
  of HOTA the boxes' fit loses, and in which direction.
* Against another run (``--against BASE.json``, ``eval_compare``): both runs' height errors over
  the objects both count, and their scores side by side.

Ground-truth boxes that are mostly hidden (``--min-visibility``) are "don't care": they are
neither required nor penalised, and a track box on one is dropped (as MOTChallenge does with
occluded and distractor boxes); so is a box no required object claims that lies mostly on a
parked vehicle, which the generator draws without a box (KITTI's DontCare areas).

This module is the command; the work is in five: ``eval_sequences`` (running the stages over a
sequence), ``eval_metrics`` (the scores), ``eval_localisation`` (the scores with boxes put right),
``eval_reports`` (the printed tables, the picture) and ``eval_compare`` (two reports side by side).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from core.config import Config
from core.errors import HeightpipeError
from pipeline.eval_compare import check_comparable, compare_reports, format_comparison
from pipeline.eval_localisation import localisation_headroom
from pipeline.eval_metrics import evaluate
from pipeline.eval_reports import (format_localisation, format_misses, format_report, format_wrong_detections,
                                   format_wrong_tracks, json_default, plot_height_series)
from pipeline.eval_sequences import CAMERA_KNOWN, run_sequence


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("data", help="synthetic dataset folder (manifest.json), from `heightpipe synth`")
    parser.add_argument("--split", choices=("test", "train", "all"), default="test",
                        help="which sequences (default: the held-out test split)")
    parser.add_argument("--sequences", nargs="+", metavar="NAME", help="only these sequences")
    parser.add_argument("--heights", choices=("model", "oracle"), default="model",
                        help="height maps from the network (default) or the ground truth (oracle)")
    parser.add_argument("--camera", choices=CAMERA_KNOWN, default="true",
                        help="what the run is told of each camera: its exact pose and lens (default), its "
                             "height only, as `heightpipe run --camera-height H` (most users' case), or its height "
                             "and the pose `heightpipe calibrate --camera-height H` reads from the scene")
    parser.add_argument("--no-geometry", action="store_true",
                        help="do not fuse the calibrated-camera geometry height")
    parser.add_argument("--max-frames", type=int, default=0, help="frames per sequence (0 = all)")
    parser.add_argument("--min-visibility", type=float, default=0.3,
                        help="ground-truth boxes less visible than this are don't-care (default 0.3)")
    parser.add_argument("--min-box-px", type=float, default=20.0,
                        help="ground-truth boxes shorter than this (pixels) are don't-care (default 20)")
    parser.add_argument("--min-frames", type=int, default=10,
                        help="objects matched in fewer frames are left out of the height errors")
    parser.add_argument("--misses", action="store_true",
                        help="also print why required objects were missed (not detected, merged, box off, "
                             "detected but not tracked) and what lies under wrong detections and wrong track "
                             "boxes, per class, size, time of day, weather")
    parser.add_argument("--localisation", action="store_true",
                        help="also score the runs again with the boxes' horizontal extent, vertical extent or "
                             "whole box taken from the objects they are about: how much of HOTA the boxes' fit "
                             "loses, and where")
    parser.add_argument("--json", metavar="FILE", help="write the full report as JSON")
    parser.add_argument("--against", metavar="BASE_JSON",
                        help="another run's --json report on the same data: heights compared over the objects "
                             "both runs count, scores side by side")
    parser.add_argument("--plot", metavar="PNG", help="picture of per-track height series (first sequence)")
    parser.add_argument("--record", metavar="RRD", help="rerun recording of the first sequence")


def main(args: argparse.Namespace, config: Config) -> int:
    from synth.dataset import list_sequences

    base = _read_base(Path(args.against)) if args.against else None
    root = Path(args.data)
    if not (root / "manifest.json").is_file():
        raise HeightpipeError(f"{root} is not a synthetic dataset (no manifest.json)")
    sequences = list_sequences(root, split=None if args.split == "all" else args.split)
    if args.sequences:
        wanted = set(args.sequences)
        sequences = [s for s in sequences if s.name in wanted]
        missing = wanted - {s.name for s in sequences}
        if missing:
            raise HeightpipeError(f"no such sequence in {root} ({args.split} split): {', '.join(sorted(missing))}")
    if not sequences:
        raise HeightpipeError(f"no {args.split} sequences in {root}")
    if base is not None:  # before the sequences run, not after
        check_comparable({"sequences": [s.name for s in sequences], "min_visibility": args.min_visibility,
                          "min_box_px": args.min_box_px, "min_frames": args.min_frames}, base)
    if args.plot:
        from core.extras import require

        require("matplotlib", "synth", "eval-tracks --plot")

    runs = []
    start = time.perf_counter()
    for index, sequence in enumerate(sequences):
        record_path = Path(args.record) if (args.record and index == 0) else None
        run = run_sequence(sequence, config, heights=args.heights, geometry=not args.no_geometry,
                           max_frames=args.max_frames, record=record_path, known=args.camera)
        runs.append(run)
        print(f"  {sequence.name}: {len(run.frames)} frames, {run.fps:.1f} fps", file=sys.stderr)
        if index == 0 and args.plot:
            plot_height_series(run, Path(args.plot), args.min_visibility)
    report = evaluate(runs, min_visibility=args.min_visibility, min_frames=args.min_frames,
                      min_box_px=args.min_box_px)
    report["heights"] = args.heights
    # Geometry needs the camera's pose: told its height alone, the run has none to fuse.
    report["geometry"] = not args.no_geometry and args.camera == "true"
    report["camera"] = args.camera
    report["wall_s"] = round(time.perf_counter() - start, 1)
    print(format_report(report))
    if args.misses:
        print(format_misses(report["misses"]))
        print(format_wrong_detections(report["wrong_detections"]))
        print(format_wrong_tracks(report["wrong_tracks"]))
    if args.localisation:
        report["localisation"] = localisation_headroom(runs, args.min_visibility, args.min_box_px)
        print(format_localisation(report["localisation"], report["mot"]))
    if base is not None:
        report["against"] = compare_reports(report, base)
        print(format_comparison(report["against"], args.against))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(report, indent=2, default=json_default))
    return 0


def _read_base(path: Path) -> dict:
    """The ``--against`` report, read before the sequences run (a wrong path fails at once)."""
    try:
        base = json.loads(path.read_text())
    except OSError as exc:
        raise HeightpipeError(f"--against: cannot read {path}: {exc.strerror or exc}") from None
    except json.JSONDecodeError as exc:
        raise HeightpipeError(f"--against: {path} is not JSON ({exc.msg}, line {exc.lineno})") from None
    if not isinstance(base, dict) or not {"objects", "mot", "sequences", "min_frames"} <= base.keys():
        raise HeightpipeError(f"--against: {path} is not an eval-tracks --json report")
    return base
