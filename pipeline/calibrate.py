"""`heightpipe calibrate SOURCE`: self-calibrate a camera from the people walking in its video,
or, told its mounting height, from the scene's straight lines.

Without ``--camera-height``: runs the stages of ``heightpipe run`` for an uncalibrated camera
(the same tracks; the network's metres are not used, they need the camera height this command
is looking for), collects the head and foot points of upright tracked people and fits horizon
and camera height with a population height prior (stages/self_calibration.py). Prints a
``[camera]`` snippet for config.toml on stdout and the fit's report on stderr; ``--out
FILE.json`` also writes a complete calibration JSON (intrinsics, distortion, pose) that
``heightpipe run --calibration`` reads.

With ``--camera-height M`` (``scene_camera``): no people needed. HeightNet v2's camera heads
guess pitch, roll and focal length from each frame, and the scene's straight lines sharpen the
guess (``stages/vertical_edges.py``: walls and poles meet at the vertical vanishing point,
parallel kerbs and markings on the horizon, families crossing square). The ``[camera]`` snippet
it prints makes the next run a posed one (HeightNet v1, moving objects, the geometry channel): on
40 held-out generator sequences tracked people 12.4 cm off against 25.0 for a run told only the
height, on Oxford Town Centre 11.4 against 11.6 (docs/results.md, 2026-12-04 tenth session and
2026-12-05). A run told only the
height now reads its camera this way by itself (``pipeline/scene_camera.py``, from its first
frames or a stream's first seconds); this command reads one once to keep, from a recording's
frames spread over all of it (``[camera] calibrate_frames``, 300) or a stream's first minutes.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("source", help="video file, image folder or glob, stream URL, or webcam index")
    parser.add_argument("--calibration", metavar="JSON",
                        help="intrinsic calibration (K, distortion) to calibrate with; a pose in the "
                             "file is not used, only reported beside the estimate")
    parser.add_argument("--out", metavar="FILE.json",
                        help="also write the result as a complete calibration JSON (intrinsics, "
                             "distortion and pose) for `heightpipe run --calibration`")
    parser.add_argument("--camera-height", type=float, metavar="M",
                        help="the camera's mounting height: pitch, roll and focal length then come from the "
                             "network's camera heads and the scene's straight lines, not from people")
    parser.add_argument("--picture", metavar="IMAGE",
                        help="with --camera-height: also draw the camera read (the lines that agreed, the horizon, "
                             "1.70 m bars on the ground) on the scene, to check it by eye")
    parser.add_argument("--fov", type=float, metavar="DEG",
                        help="horizontal field of view, when there is no calibration (default: camera.fov_deg)")
    parser.add_argument("--prior-mean", type=float, default=1.70, metavar="M",
                        help="mean height of the people in view (default 1.70)")
    parser.add_argument("--prior-std", type=float, default=0.09, metavar="M",
                        help="spread of people's heights (default 0.09)")
    parser.add_argument("--min-track-frames", type=int, default=5, metavar="N",
                        help="use people seen upright in at least N frames (default 5)")
    parser.add_argument("--max-frames", type=int, metavar="N",
                        help="stop after N processed frames (0, the default: all)")
    parser.add_argument("--stride", type=int, metavar="N", help="process every Nth frame")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def main(args: argparse.Namespace, config) -> int:
    from tqdm import tqdm

    from core.errors import ConfigError, HeightpipeError
    from pipeline.run_command import apply_flags, check_capture_limits
    from pipeline.stage_chain import build_stage_chain
    from stages.calibration import CONSTANTS, camera_for_run
    from stages.capture import open_source
    from stages.self_calibration import HeadFootCollector, HeightPrior, self_calibrate

    apply_flags(args, config)
    check_capture_limits(config)
    if args.camera_height is not None:
        return scene_camera(args, config)
    if args.picture:
        raise ConfigError("--picture draws the camera read from the scene: give --camera-height too")
    if not (0.5 < args.prior_mean < 2.5 and 0.0 < args.prior_std < 0.5):
        raise ConfigError("--prior-mean must be in metres (0.5-2.5) and --prior-std in (0, 0.5)")

    source = open_source(args.source, config.capture)
    width, height = source.size
    # Only the intrinsics are used: the pose is what this command estimates.
    intrinsics_config = dataclasses.replace(config.camera, height_m=0.0, pitch_deg=0.0, roll_deg=0.0,
                                            self_calibrated=False)
    try:
        camera = camera_for_run(intrinsics_config, width, height)
        # A calibration file's pose is dropped too; the network's scale-free heights are taken
        # at an assumed camera height: they only tell what stands above the ground.
        camera = dataclasses.replace(camera, R=None, t=None, height_m=CONSTANTS.assumed_camera_height_m,
                                     source="none", pose_from="")
        chain = build_stage_chain(config, camera, assumed_camera_ok=True)
    except HeightpipeError:
        source.close()
        raise
    chain.prime(source.background_sample(config.objects.background_prime_frames,
                                         config.objects.background_prime_s))
    collector = HeadFootCollector(width, height)
    progress = tqdm(total=source.stats.expected, unit="frame", disable=args.no_progress or not config.output.progress,
                    desc="collecting people", dynamic_ncols=True, file=sys.stderr)
    try:
        for packet in chain.run(source.frames(), camera):
            collector.add(packet.tracks)
            progress.update(1)
    except KeyboardInterrupt:
        print("heightpipe: interrupted, calibrating from the frames so far", file=sys.stderr)
    finally:
        progress.close()
        chain.close()
        source.close()

    foot, top, track_ids = collector.arrays(args.min_track_frames)
    prior = HeightPrior(mean_m=args.prior_mean, std_m=args.prior_std)
    result = self_calibrate(foot, top, track_ids, width, height, camera.K,
                            focal_known=bool(config.camera.calibration), prior=prior,
                            settings=None)
    print(result.config_snippet(calibration=config.camera.calibration))
    _report(result, config.camera.calibration, width, height)
    if args.out:
        write_calibration_json(args.out, result, config.camera.calibration)
        print(f"heightpipe: wrote {args.out} (use it with `heightpipe run --calibration {args.out}`)",
              file=sys.stderr)
    return 0


def scene_camera(args: argparse.Namespace, config) -> int:
    """``--camera-height``: the camera from v2's heads and the scene's lines, as a snippet."""
    from tqdm import tqdm

    from core.errors import ConfigError, HeightpipeError
    from stages.calibration import camera_for_run, fov_from_focal
    from stages.capture import open_source
    from stages.contact_heights import read_scene
    from stages.heightnet_model import HeightNetModel
    from stages.self_calibration import toml_string
    from stages.sink_common import lines_text
    from stages.vertical_edges import FIRST_FIT_FRAME

    if not args.camera_height > 0:
        raise ConfigError(f"--camera-height must be the mounting height in metres, got {args.camera_height}")
    if args.out:
        raise ConfigError("--out writes the people fit's calibration JSON; with --camera-height save the "
                          "[camera] snippet instead: heightpipe calibrate SOURCE --camera-height M > camera.toml")
    model = HeightNetModel(config.height.model or "v2", config.height.threads, mirror=config.height.mirror)
    if not model.info.contact:
        raise ConfigError(f"calibrate --camera-height needs a HeightNet v2 model (camera heads); "
                          f"{model.path} is a v1 model")
    source = open_source(args.source, config.capture)
    width, height = source.size
    try:
        lens = camera_for_run(dataclasses.replace(config.camera, pitch_deg=0.0, roll_deg=0.0), width, height)
    except HeightpipeError:
        source.close()
        raise
    camera = dataclasses.replace(lens, R=None, t=None, height_m=float(args.camera_height), source="camera-height",
                                 pose_from="")
    spread = spread_count(config, source.stats.expected)
    progress = tqdm(total=spread or source.stats.expected, unit="frame",
                    disable=args.no_progress or not config.output.progress,
                    desc="reading the scene", dynamic_ncols=True, file=sys.stderr)

    def images():
        for image in (source.spread_sample(spread) if spread else (frame.image for frame in source.frames())):
            yield image
            progress.update(1)

    used = None
    try:
        used, reader = read_scene(model, images(), camera)
    except KeyboardInterrupt:
        print("heightpipe: interrupted before the camera was read", file=sys.stderr)
        return 130
    finally:
        progress.close()
        source.close()
    if used is None:
        raise HeightpipeError(f"{args.source}: no frames to read the camera from")
    if args.picture:   # before the snippet: a picture that cannot be written leaves no half output
        write_scene_picture(args.picture, reader, used, width)
    fov = fov_from_focal(width, used.focal_px)
    lines_note = (lines_text(used) if used.edges else
                  f"too few frames for the scene's lines ({FIRST_FIT_FRAME} needed): the heads alone, worth checking"
                  if used.frames < FIRST_FIT_FRAME else "no straight lines agreed: the heads alone, worth checking")
    print("\n".join([
        "[camera]",
        f"height_m = {used.height_m:.2f}            # given",
        f"pitch_deg = {used.pitch_deg:.2f}           # network heads, {lines_note}",
        f"pitch_std_deg = {used.pitch_std_deg:.2f}",
        f"roll_deg = {used.roll_deg:.2f}",
        f"roll_std_deg = {used.roll_std_deg:.2f}",
        *([f"calibration = {toml_string(config.camera.calibration)}   # intrinsics (its pose is not used)"]
          if config.camera.calibration else
          [f"fov_deg = {fov:.1f}             # focal {used.focal_px:.0f} px",
           f"focal_std_pct = {used.focal_std_pct:.1f}"]),
        "self_calibrated = true",
    ]))
    read = f"{used.frames} frames spread over its {source.stats.expected}" if spread else f"{used.frames} frames"
    print(f"heightpipe: camera from {read}: pitch {used.pitch_deg:.1f} +- {used.pitch_std_deg:.1f} deg, "
          f"roll {used.roll_deg:.1f} +- {used.roll_std_deg:.1f} deg, focal {used.focal_px:.0f} px; {lines_note}; "
          f"run with it: heightpipe run {args.source} --config THIS_FILE", file=sys.stderr)
    return 0


def spread_count(config, total: int | None) -> int:
    """How many frames ``--camera-height`` reads spread over a recording of ``total`` frames
    (``[camera] calibrate_frames``), or 0 to read every frame from the start: a recording no longer
    than that, one of unknown length (a stream), or ``--max-frames`` / ``--stride`` given."""
    count = config.camera.calibrate_frames
    if count <= 0 or not total or total <= count or config.capture.max_frames or config.capture.stride > 1:
        return 0
    return count


def write_scene_picture(path: str, reader, used, frame_width: int) -> None:
    """``--picture``: the camera read, drawn on the scene it was read from (``stages/scene_picture.py``)."""
    import cv2

    from core.errors import HeightpipeError
    from stages.scene_picture import scene_camera_picture

    picture = scene_camera_picture(reader.samples.median(), used, frame_width, reader.edge_fit)
    try:
        written = cv2.imwrite(path, picture)
    except cv2.error:
        written = False
    if not written:
        raise HeightpipeError(f"cannot write the picture {path} (a .jpg or .png in a folder that exists)")
    print(f"heightpipe: wrote {path}", file=sys.stderr)


def write_calibration_json(path: str, result, calibration: str) -> None:
    """The fitted camera in the calibration JSON layout of stages/calibration.py, complete: image
    size, K, the distortion of ``calibration`` (if one was given) and the pose as camera height,
    pitch and roll. Extra keys record where it came from and how sure the fit is."""
    import json
    from pathlib import Path

    from core.errors import HeightpipeError
    from stages.calibration import load_calibration

    data = {
        "image_size": [int(result.width), int(result.height)],
        "K": [[float(v) for v in row] for row in result.K],
        "camera_height_m": round(float(result.height_m), 4),
        "pitch_deg": round(float(result.pitch_deg), 3),
        "roll_deg": round(float(result.roll_deg), 3),
        "camera_height_std_m": round(float(result.height_std_m), 4),
        "source": f"heightpipe calibrate: self-calibrated from {result.n_tracks} people "
                  f"(prior {result.prior.mean_m:.2f} +- {result.prior.std_m:.2f} m), focal {result.focal_source}",
    }
    if calibration:
        dist = load_calibration(calibration).dist
        if dist is not None:
            data["dist"] = [float(v) for v in dist]
    try:
        Path(path).write_text(json.dumps(data, indent=2) + "\n")
    except OSError as exc:
        raise HeightpipeError(f"cannot write {path}: {exc.strerror}") from None


def _report(result, calibration: str, width: int, height: int) -> None:
    from stages.calibration import angles_from_rotation, load_calibration, rescale_camera

    a, b, c = result.horizon()
    lines = [
        f"heightpipe: self-calibrated from {result.n_tracks} upright tracked objects taken as people "
        f"({result.n_observations} head/foot points)",
        f"  camera height {result.height_m:.2f} +- {result.height_std_m:.2f} m, pitch "
        f"{result.pitch_deg:.1f} +- {result.pitch_std_deg:.1f} deg, roll {result.roll_deg:.1f} +- "
        f"{result.roll_std_deg:.1f} deg, focal {result.K[0, 0]:.0f} px ({result.focal_source})",
        f"  horizon: {a:.4f} u + {b:.4f} v + {c:.1f} = 0 (v = {-(c + a * width / 2) / b:.0f} at the image centre)",
        f"  people's heights with this camera: spread {result.person_height_spread_m:.2f} m "
        f"(prior {result.prior.mean_m:.2f} +- {result.prior.std_m:.2f} m)",
    ]
    if calibration:
        reference = rescale_camera(load_calibration(calibration), width, height)
        if reference.R is not None:
            pitch, roll, _ = angles_from_rotation(reference.R)
            lines.append(f"  the calibration file's own pose: height {reference.height_m:.2f} m, "
                         f"pitch {pitch:.1f} deg, roll {roll:.1f} deg")
    lines.append("  heights from this camera are flagged as self-calibrated (self_calibrated = true)")
    print("\n".join(lines), file=sys.stderr)
