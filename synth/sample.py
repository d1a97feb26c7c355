"""Render the shipped sample clip: recordings/sample.mp4 and its truth in recordings/sample_gt/.

    python -m synth.sample [--out-dir recordings] [--seconds 12] [--fps 15]

A day scene at 640x360 from a camera 6.4 m up, with a few pedestrians and at least one car,
used by the README demo and by tests that need a real video file. The scene is the first
seed (from 0 up) whose plan keeps a car and several good-sized pedestrians in view, so the clip is the
same on every machine with the same Mesa version.

sample_gt/ holds meta.json (camera K, R, t, height, pitch, fov; layout, movers), gt.txt
(MOTChallenge + height column, as in the dataset), world.txt (ground positions) and
heights/NNNNNN.png: the height map of every 15th frame as uint16 millimetres (65535 = sky).
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import numpy as np

from synth.scene import CLASS_ID
from synth.sequence import SequenceOptions, plan_sequence

REPO_ROOT = Path(__file__).resolve().parent.parent
HEIGHT_EVERY = 15


def sample_options(seconds: float, fps: float) -> SequenceOptions:
    return SequenceOptions(frames=int(round(seconds * fps)), fps=fps, sizes=((640, 360),), layout="street_crossing",
                           time_of_day="day", weather="clear", camera_height_m=6.4,
                           pedestrians=(6, 9), vehicles=(2, 4), cyclists=(0, 1))


def _good_plan(options: SequenceOptions):
    """First plan with a car and >= 4 pedestrians (>= 45 px tall) in view mid-clip, >= 3 at both ends."""
    def counts(plan, t):
        seen = {"car": 0, "pedestrian": 0}
        for m in plan.movers:
            if m.cls in seen and m.present(t):
                xy, _ = m.ground_pose(t)
                uv, z = plan.camera.project(np.array([[xy[0], xy[1], 0.0], [xy[0], xy[1], m.nominal_height_m]]))
                inside = (z > 0).all() and (uv[:, 0] >= 0).all() and (uv[:, 0] < 640).all() \
                    and (uv[:, 1] >= 0).all() and (uv[:, 1] < 360).all()
                if inside and uv[0, 1] - uv[1, 1] >= 45:  # big enough to read in the demo
                    seen[m.cls] += 1
        return seen

    duration = options.frames / options.fps
    for seed in range(200):
        plan = plan_sequence(seed, 0, options)
        mid = counts(plan, duration / 2)
        if mid["car"] >= 1 and mid["pedestrian"] >= 4 and all(
                counts(plan, duration * f)["pedestrian"] >= 3 for f in (0.1, 0.9)):
            return plan
    raise RuntimeError("no seed below 200 gives a car and three pedestrians in view")


def render_sample(out_dir: Path, seconds: float = 12.0, fps: float = 15.0) -> Path:
    import cv2
    from tqdm import tqdm

    from synth.generate import SequenceRenderer

    options = sample_options(seconds, fps)
    plan = _good_plan(options)
    video_path = out_dir / "sample.mp4"
    gt_dir = out_dir / "sample_gt"
    if gt_dir.exists():
        shutil.rmtree(gt_dir)
    (gt_dir / "heights").mkdir(parents=True)
    writer = None
    for codec in ("avc1", "mp4v"):
        writer = cv2.VideoWriter(str(video_path), cv2.VideoWriter_fourcc(*codec), fps, (640, 360))
        if writer.isOpened():
            break
        writer.release()
    if writer is None or not writer.isOpened():
        raise RuntimeError("OpenCV cannot write MP4 here")
    gt, world = [], []
    with SequenceRenderer(plan) as renderer:
        for frame in tqdm(renderer.frames(), total=options.frames, desc="sample", unit="frame"):
            writer.write(np.ascontiguousarray(frame.rgb[..., ::-1]))
            for o in frame.objects:
                x, y, w, h = o.box
                gt.append(f"{frame.index + 1},{o.id},{x:.0f},{y:.0f},{w:.0f},{h:.0f},1,{CLASS_ID[o.cls]},"
                          f"{o.visible_fraction:.4f},{o.height_m:.4f}")
                world.append(f"{frame.index + 1},{o.id},{o.ground_xy_m[0]:.4f},{o.ground_xy_m[1]:.4f}")
            if frame.index % HEIGHT_EVERY == 0:
                from synth.dataset import heights_from_depth

                height = heights_from_depth(plan.camera, frame.depth_m, frame.semantic)
                mm = np.where(np.isnan(height), 65535, np.clip(np.round(np.nan_to_num(height) * 1000), 0, 65534))
                cv2.imwrite(str(gt_dir / "heights" / f"{frame.index:06d}.png"), mm.astype(np.uint16))
    writer.release()
    meta = plan.meta()
    meta.update(video="sample.mp4", frames_written=options.frames, height_every=HEIGHT_EVERY,
                gt_columns="frame,id,x,y,w,h,conf,class,visibility,height_m (class = index in class_names)",
                class_names=list(CLASS_ID))
    (gt_dir / "meta.json").write_text(json.dumps(meta, indent=1))
    (gt_dir / "gt.txt").write_text("\n".join(gt) + "\n")
    (gt_dir / "world.txt").write_text("\n".join(world) + "\n")
    check = cv2.VideoCapture(str(video_path))
    decoded = 0
    while check.read()[0]:
        decoded += 1
    check.release()
    if decoded != options.frames:
        raise RuntimeError(f"{video_path} decodes to {decoded} frames, expected {options.frames}")
    return video_path


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out-dir", type=Path, default=REPO_ROOT / "recordings")
    parser.add_argument("--seconds", type=float, default=12.0)
    parser.add_argument("--fps", type=float, default=15.0)
    args = parser.parse_args(argv)
    args.out_dir.mkdir(parents=True, exist_ok=True)
    path = render_sample(args.out_dir, args.seconds, args.fps)
    print(f"wrote {path} and {args.out_dir / 'sample_gt'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
