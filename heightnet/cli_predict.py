"""`heightpipe predict`: height maps (uint16 PNG, millimetres) for images, a folder or a video."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("source", metavar="IMAGE_OR_DIR", help="an image, a folder of images or a video")
    parser.add_argument("--out", required=True, metavar="DIR", help="output folder")
    parser.add_argument("--camera-height", type=float, default=0.0, metavar="M",
                        help="camera height above the ground in metres (default: camera.height_m)")
    parser.add_argument("--calibration", metavar="JSON", default="",
                        help="calibration JSON, as for `heightpipe run` (default: camera.calibration)")
    parser.add_argument("--model", default="", help="ONNX model (default: height.model or the shipped one)")
    parser.add_argument("--every", type=int, default=1, metavar="N", help="every Nth frame of a video")


def main(args: argparse.Namespace, config) -> int:
    from heightnet.predict import HeightPredictor, model_path_from_config, predict_to_folder
    from stages.heightnet_model import most_threads
    from stages.sink_common import height_camera_text

    model = model_path_from_config(args.model or config.height.model)
    # The network is all this command runs: it takes the most threads its setting allows (a run's
    # v1 takes one and leaves the other core to the stages beside it).
    predictor = HeightPredictor(model, most_threads(config.height.threads), config.height.input_width)
    camera = dataclasses.replace(config.camera, height_m=args.camera_height or config.camera.height_m,
                                 calibration=args.calibration or config.camera.calibration)
    written = predict_to_folder(Path(args.source), Path(args.out), predictor, every=max(1, args.every),
                                camera_config=camera)
    print(f"wrote {len(written)} height maps (uint16 PNG, mm) and colour views to {args.out}")
    if predictor.height_camera is not None:
        print(f"heightpipe: {height_camera_text(predictor.height_camera)}", file=sys.stderr)
    return 0
