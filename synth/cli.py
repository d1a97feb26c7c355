"""``heightpipe synth``: render a synthetic CCTV dataset (or a preview contact sheet)."""

from __future__ import annotations

import argparse
from pathlib import Path

from core.errors import ConfigError

TIMES = ("day", "low_sun", "dusk", "night")
WEATHER = ("clear", "overcast", "fog", "rain")
FAMILIES = ("street_crossing", "plaza", "parking_lot", "sidewalk_road", "campus_path")


def parse_sizes(text: str) -> tuple[tuple[int, int], ...]:
    """'320x240' or '320x240,640x360' -> ((320, 240), (640, 360))."""
    sizes = []
    for part in text.split(","):
        w, sep, h = part.strip().lower().partition("x")
        if not sep or not w.isdigit() or not h.isdigit():
            raise ConfigError(f"--size {text!r}: expected WxH, e.g. 320x240 (comma-separate several)")
        width, height = int(w), int(h)
        if not (32 <= width <= 4096 and 32 <= height <= 4096):
            raise ConfigError(f"--size {part}: width and height must be 32..4096 pixels")
        sizes.append((width, height))
    return tuple(sizes)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", metavar="DIR", default="data/synth",
                        help="output directory (with --preview: the PNG path, default DIR/preview.png)")
    parser.add_argument("--preset", choices=["paper"], default=None,
                        help="paper: the five camera heights 3.5/5.0/6.4/7.8/9.2 m in turn")
    parser.add_argument("--sequences", type=int, metavar="N", help="number of sequences [synth.sequences]")
    parser.add_argument("--frames", type=int, metavar="N", help="frames per sequence [synth.frames]")
    parser.add_argument("--size", metavar="WxH[,WxH...]", help="resolution(s), one drawn per sequence")
    parser.add_argument("--seed", type=int, metavar="S", help="root seed [synth.seed]")
    parser.add_argument("--workers", type=int, metavar="N", help="render processes [synth.workers]")
    parser.add_argument("--fps", type=float, help="frame rate of the sequences [synth.fps]")
    parser.add_argument("--split", choices=["all", "train", "test"], default="all",
                        help="only sequences whose layout seed falls in this split (default: all)")
    parser.add_argument("--scenario", choices=["occlusion"], default=None,
                        help="occlusion: a bus/truck hides a walking pedestrian for ~2 s mid-sequence")
    parser.add_argument("--layout", choices=FAMILIES, help="force one layout family")
    parser.add_argument("--time-of-day", choices=TIMES, help="force the time of day")
    parser.add_argument("--weather", choices=WEATHER, help="force the weather")
    parser.add_argument("--camera-height", type=float, metavar="M", help="force the camera height")
    parser.add_argument("--no-shadows", action="store_true", help="no sun shadows (about 2x faster)")
    parser.add_argument("--no-post", action="store_true", help="no noise/blur/rain/JPEG post effects")
    parser.add_argument("--msaa", type=int, default=None, metavar="N", help="MSAA samples for RGB (0 = off)")
    parser.add_argument("--png", action="store_true", help="store RGB as PNG instead of JPEG")
    parser.add_argument("--preview", action="store_true",
                        help="write a contact sheet of 12 random frames with height maps instead")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def options_from(args, config) -> tuple:
    from synth.sequence import SequenceOptions

    synth = config.synth
    sizes = parse_sizes(args.size) if args.size else parse_sizes(f"{synth.width}x{synth.height}")
    frames = args.frames if args.frames is not None else synth.frames
    sequences = args.sequences if args.sequences is not None else synth.sequences
    workers = args.workers if args.workers is not None else synth.workers
    fps = args.fps if args.fps is not None else synth.fps
    seed = args.seed if args.seed is not None else synth.seed
    msaa = args.msaa if args.msaa is not None else synth.msaa
    if frames < 1:
        raise ConfigError(f"--frames must be at least 1, got {frames}")
    if sequences < 1:
        raise ConfigError(f"--sequences must be at least 1, got {sequences}")
    if workers < 1:
        raise ConfigError(f"--workers must be at least 1, got {workers}")
    if not fps > 0:
        raise ConfigError(f"--fps must be positive, got {fps}")
    if msaa not in (0, 2, 4, 8):
        raise ConfigError(f"--msaa must be 0, 2, 4 or 8, got {msaa}")
    if not 0.0 <= synth.test_fraction < 1.0:
        raise ConfigError(f"synth.test_fraction must be in [0, 1), got {synth.test_fraction}")
    if args.camera_height is not None and not 0.5 <= args.camera_height <= 50:
        raise ConfigError(f"--camera-height must be 0.5..50 m, got {args.camera_height}")
    if args.scenario == "occlusion" and frames / fps < 6.0:
        raise ConfigError(f"--scenario occlusion needs at least 6 s per sequence, got {frames / fps:.1f} s")
    preset = args.preset if args.preset is not None else synth.preset
    if preset not in ("", "paper"):
        raise ConfigError(f"synth.preset must be '' or 'paper', got {preset!r}")
    options = SequenceOptions(
        frames=frames, fps=fps, sizes=sizes, preset=preset, scenario=args.scenario or "",
        test_fraction=synth.test_fraction, shadows=not args.no_shadows and synth.shadows, msaa=msaa,
        post_effects=not args.no_post, layout=args.layout or "", time_of_day=args.time_of_day or "",
        weather=args.weather or "", camera_height_m=args.camera_height or 0.0)
    return options, sequences, workers, seed


def main(args, config) -> int:
    from core.extras import require

    require("mujoco", "synth", "heightpipe synth")
    options, sequences, workers, seed = options_from(args, config)
    if args.preview:
        from synth.preview import contact_sheet

        out = Path(args.out)
        path = out if out.suffix.lower() == ".png" else out / "preview.png"
        contact_sheet(path, seed=seed, options=options, workers=workers, progress=not args.no_progress)
        print(f"wrote {path}")
        return 0
    from synth.writer import generate_dataset

    out = Path(args.out)
    results = generate_dataset(out, seed, sequences, options, workers=workers, split=args.split,
                               rgb_format="png" if args.png else "jpg", progress=not args.no_progress)
    rendered = [r for r in results if not r.skipped]
    frames = sum(r.frames for r in rendered)
    seconds = sum(r.seconds for r in rendered)
    skipped = len(results) - len(rendered)
    print(f"wrote {len(rendered)} sequences ({frames} frames, {seconds:.0f} s of render time) to {out}"
          + (f"; {skipped} already complete" if skipped else ""))
    return 0
