"""Write rendered sequences to disk (format: synth/README.md) with a process pool.

Each worker process renders whole sequences with its own EGL context. A sequence's
meta.json is written last, so a directory without it is incomplete and gets redone; a
complete one with the same seed and frame count is skipped, which makes runs resumable.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from synth.dataset import CLASS_NAMES, FORMAT
from synth.scene import CLASS_ID
from synth.sequence import SequenceOptions, layout_split, plan_sequence, sequence_layout

GENERATOR_VERSION = 4
"""Bumped whenever the same seed would render different pixels; older sequences are redone."""


@dataclass
class WriteResult:
    name: str
    frames: int
    seconds: float
    skipped: bool = False


def write_sequence(plan, out_root: Path, rgb_format: str = "jpg", jpeg_quality: int = 92) -> WriteResult:
    import cv2

    from synth.generate import SequenceRenderer

    start = time.perf_counter()
    seq_dir = Path(out_root) / plan.name
    if seq_dir.exists():
        shutil.rmtree(seq_dir)
    for sub in ("rgb", "instance", "semantic", "depth", "gt"):
        (seq_dir / sub).mkdir(parents=True)
    gt_lines, world_lines = [], []
    rgb_params = [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality] if rgb_format == "jpg" else [cv2.IMWRITE_PNG_COMPRESSION, 3]
    with SequenceRenderer(plan) as renderer:
        bg = renderer.background()
        np.savez_compressed(seq_dir / "bg_depth.npz", depth=bg.depth_m)
        cv2.imwrite(str(seq_dir / "bg_semantic.png"), bg.semantic)
        bg_flat = bg.depth_m.reshape(-1)
        for frame in renderer.frames():
            stem = f"{frame.index:06d}"
            cv2.imwrite(str(seq_dir / "rgb" / f"{stem}.{rgb_format}"), frame.rgb[..., ::-1], rgb_params)
            cv2.imwrite(str(seq_dir / "instance" / f"{stem}.png"), frame.instance)
            cv2.imwrite(str(seq_dir / "semantic" / f"{stem}.png"), frame.semantic)
            flat = frame.depth_m.reshape(-1)
            changed = np.flatnonzero(flat != bg_flat).astype(np.uint32)
            np.savez_compressed(seq_dir / "depth" / f"{stem}.npz", index=changed, depth=flat[changed])
            for o in frame.objects:
                x, y, w, h = o.box
                gt_lines.append(f"{frame.index + 1},{o.id},{x:.0f},{y:.0f},{w:.0f},{h:.0f},1,{CLASS_ID[o.cls]},"
                                f"{o.visible_fraction:.4f},{o.height_m:.4f}")
                world_lines.append(f"{frame.index + 1},{o.id},{o.ground_xy_m[0]:.4f},{o.ground_xy_m[1]:.4f}")
    (seq_dir / "gt" / "gt.txt").write_text("\n".join(gt_lines) + ("\n" if gt_lines else ""))
    (seq_dir / "gt" / "world.txt").write_text("\n".join(world_lines) + ("\n" if world_lines else ""))
    meta = plan.meta()
    meta.update(format=FORMAT, generator_version=GENERATOR_VERSION, frames_written=plan.options.frames,
                rgb_format=rgb_format,
                class_names=list(CLASS_NAMES),
                options=_options_json(plan.options))
    tmp = seq_dir / "meta.json.tmp"
    tmp.write_text(json.dumps(meta, indent=1))
    tmp.rename(seq_dir / "meta.json")
    return WriteResult(plan.name, plan.options.frames, time.perf_counter() - start)


def select_indices(root_seed: int, count: int, options: SequenceOptions, split: str) -> list[int]:
    """The first ``count`` sequence indices whose layout falls in ``split`` ('all' takes all)."""
    if split == "all":
        return list(range(count))
    chosen, index = [], 0
    while len(chosen) < count:
        _, layout_seed = sequence_layout(root_seed, index, options)
        if layout_split(layout_seed, options.test_fraction) == split:
            chosen.append(index)
        index += 1
        if index > 1000 * (count + 10):
            raise RuntimeError(f"no layouts fall in split {split!r} (test_fraction={options.test_fraction})")
    return chosen


def _options_json(options: SequenceOptions) -> dict:
    return json.loads(json.dumps({k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(options).items()}))


def _is_complete(seq_dir: Path, seed: int, options: SequenceOptions) -> bool:
    meta = seq_dir / "meta.json"
    if not meta.is_file():
        return False
    try:
        raw = json.loads(meta.read_text())
    except json.JSONDecodeError:
        return False
    return (raw.get("seed") == seed and raw.get("generator_version") == GENERATOR_VERSION
            and raw.get("options") == _options_json(options))


def _worker_init(threads: int) -> None:
    # llvmpipe starts one raster thread per core by default; with several worker processes
    # that oversubscribes the CPU, so give each its share. Must happen before GL loads.
    os.environ["LP_NUM_THREADS"] = str(threads)
    os.environ.setdefault("MUJOCO_GL", "egl")


def _render_task(task) -> WriteResult:
    root_seed, index, options, out_root, rgb_format, jpeg_quality = task
    plan = plan_sequence(root_seed, index, options)
    if _is_complete(Path(out_root) / plan.name, plan.seed, options):
        return WriteResult(plan.name, options.frames, 0.0, skipped=True)
    return write_sequence(plan, Path(out_root), rgb_format, jpeg_quality)


def write_manifest(out_root: Path, root_seed: int, extra: dict | None = None) -> None:
    names = sorted(p.parent.name for p in out_root.glob("*/meta.json"))
    manifest = {"format": FORMAT, "seed": root_seed, "sequences": names, **(extra or {})}
    tmp = out_root / "manifest.json.tmp"
    tmp.write_text(json.dumps(manifest, indent=1))
    tmp.rename(out_root / "manifest.json")


def generate_dataset(out_root: Path, root_seed: int, count: int, options: SequenceOptions, workers: int = 2,
                     split: str = "all", rgb_format: str = "jpg", jpeg_quality: int = 92,
                     progress: bool = True) -> list[WriteResult]:
    """Render ``count`` sequences into ``out_root`` with a pool of ``workers`` processes."""
    import multiprocessing

    from tqdm import tqdm

    out_root = Path(out_root)
    out_root.mkdir(parents=True, exist_ok=True)
    indices = select_indices(root_seed, count, options, split)
    tasks = [(root_seed, i, options, str(out_root), rgb_format, jpeg_quality) for i in indices]
    extra = {"split": split, "generator_options": {k: (list(v) if isinstance(v, tuple) else v)
                                                   for k, v in asdict(options).items()}}
    results: list[WriteResult] = []
    bar = tqdm(total=count * options.frames, unit="frame", desc="synth", disable=not progress, smoothing=0.05)
    try:
        if workers <= 1:
            for task in tasks:
                results.append(_render_task(task))
                bar.update(results[-1].frames)
                write_manifest(out_root, root_seed, extra)
        else:
            threads = max(1, (os.cpu_count() or 2) // workers)
            ctx = multiprocessing.get_context("spawn")
            with ctx.Pool(workers, initializer=_worker_init, initargs=(threads,), maxtasksperchild=20) as pool:
                for result in pool.imap_unordered(_render_task, tasks):
                    results.append(result)
                    bar.update(result.frames)
                    write_manifest(out_root, root_seed, extra)
    finally:
        bar.close()
    write_manifest(out_root, root_seed, extra)
    return results
