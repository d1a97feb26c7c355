"""The ``heightpipe`` command: one sub-command per job, each living in its own module.

A command module exposes ``add_arguments(parser)`` and ``main(args, config) -> int`` and
imports nothing heavy at module level, so ``heightpipe --help`` stays instant and the
run path never imports torch.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from core.config import load_config
from core.errors import HeightpipeError

# (command, module, one-line help)
COMMANDS = [
    ("run", "pipeline.run_command", "process a video, image folder, stream or webcam"),
    ("recover", "pipeline.recover", "make valid files of what a killed run left (PREFIX or FILE.mcap / FILE.rrd)"),
    ("replay", "pipeline.replay", "show an MCAP recording in the rerun viewer (or convert it to .rrd)"),
    ("synth", "synth.cli", "render a synthetic CCTV dataset with exact height ground truth"),
    ("train", "heightnet.cli_train", "train the height network on a synth dataset (resumable)"),
    ("export", "heightnet.cli_export", "export a training checkpoint to ONNX (checked against PyTorch)"),
    ("eval", "heightnet.cli_eval", "the paper's Table 1 on held-out synth scenes"),
    ("predict", "heightnet.cli_predict", "height maps (uint16 PNG, mm) for images, a folder or a video"),
    ("batch", "pipeline.batch", "process an archive of videos, resumable"),
    ("eval-tracks", "pipeline.eval_tracks", "tracking (HOTA, MOTA, IDF1) and per-object height error on synth sequences"),
    ("calibrate", "pipeline.calibrate", "self-calibrate the camera from walking people; prints a [camera] config snippet"),
]


def build_parser() -> argparse.ArgumentParser:
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--config", metavar="FILE", help="config TOML (default: ./config.toml)")
    common.add_argument("--set", metavar="SECTION.KEY=VALUE", action="append", default=[],
                        dest="overrides", help="override one config value (repeatable)")
    parser = argparse.ArgumentParser(
        prog="heightpipe",
        description="Monocular object-height measurement for fixed cameras.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, module_name, help_text in COMMANDS:
        module = importlib.import_module(module_name)
        command = sub.add_parser(name, parents=[common], help=help_text, description=help_text)
        module.add_arguments(command)
        command.set_defaults(_module=module)
    return parser


def main(argv: list[str] | None = None) -> int:
    # FFmpeg and OpenCV print their own multi-line warnings for bad input; our one-line
    # errors say what went wrong, so keep theirs quiet unless the user asks for them.
    os.environ.setdefault("OPENCV_LOG_LEVEL", "ERROR")
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")
    # rerun warns that an .rrd without its index seeks slowly; output.rrd_index chose that (a
    # live stream's run would otherwise grow without bound), so the warning says nothing new.
    os.environ.setdefault("RUST_LOG", "warn,re_log_encoding::rrd::file_sink=error")
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        config = load_config(args.config, args.overrides)
        return int(args._module.main(args, config) or 0)
    except HeightpipeError as exc:
        print(f"heightpipe: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("heightpipe: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
