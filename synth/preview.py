"""A contact sheet: 12 random frames with their height maps, covering every layout family,
weather, time of day and the paper's five camera heights (``heightpipe synth --preview``)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from synth.camera import PAPER_HEIGHTS_M
from synth.dataset import ground_mask
from synth.scene import LAYOUT_FAMILIES
from synth.sequence import SequenceOptions, derive_seed, plan_sequence
from synth.weather import TIMES_OF_DAY, WEATHERS

CELLS = 12
MAX_HEIGHT_M = 4.0


def preview_options(options: SequenceOptions, k: int) -> SequenceOptions:
    """Cell k's forced conditions; over 12 cells every family, weather, time and height occurs."""
    return replace(options, layout=LAYOUT_FAMILIES[k % 5],
                   camera_height_m=PAPER_HEIGHTS_M[(k + k // 5) % 5],
                   weather=WEATHERS[k % 4], time_of_day=TIMES_OF_DAY[(k // 3) % 4],
                   scenario="", frames=max(options.frames, 20))


def colourise_height(height_m: np.ndarray) -> np.ndarray:
    """Turbo colour map over 0..4 m (RGB); sky (NaN) black."""
    import cv2

    scaled = np.clip(np.nan_to_num(height_m, nan=0.0) / MAX_HEIGHT_M * 255, 0, 255).astype(np.uint8)
    rgb = cv2.applyColorMap(scaled, cv2.COLORMAP_TURBO)[..., ::-1].copy()
    rgb[np.isnan(height_m)] = 0
    return rgb


def _cell(task) -> np.ndarray:
    import cv2

    from synth.generate import SequenceRenderer

    seed, k, options = task
    cell_options = preview_options(options, k)
    plan = plan_sequence(derive_seed(seed, "preview"), k * 5, cell_options)
    index = int(np.random.default_rng([seed, k]).integers(cell_options.frames // 3, cell_options.frames))
    with SequenceRenderer(plan) as renderer:
        frame = renderer.frame(index)
    height = plan.camera.height_map(frame.depth_m)
    height[ground_mask(frame.semantic)] = 0.0
    w, h = 320, 240
    rgb = cv2.resize(frame.rgb, (w, h), interpolation=cv2.INTER_AREA)
    hmap = cv2.resize(colourise_height(height), (w, h), interpolation=cv2.INTER_NEAREST)
    cell = np.hstack([rgb, hmap])
    label = (f"{plan.layout.family} | {plan.env.weather}, {plan.env.time_of_day} | "
             f"cam {plan.camera.height_m:.1f} m, pitch {plan.camera.pitch_deg:.0f}, fov {plan.camera.fov_deg:.0f}")
    bar = np.full((18, cell.shape[1], 3), 255, np.uint8)
    cv2.putText(bar, label, (4, 13), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (0, 0, 0), 1, cv2.LINE_AA)
    return np.vstack([bar, cell])


def contact_sheet(path: str | Path, seed: int, options: SequenceOptions, workers: int = 2,
                  progress: bool = True) -> Path:
    import multiprocessing

    import cv2
    from tqdm import tqdm

    tasks = [(seed, k, options) for k in range(CELLS)]
    if workers <= 1:
        cells = [_cell(t) for t in tqdm(tasks, desc="preview", disable=not progress)]
    else:
        with multiprocessing.get_context("spawn").Pool(workers) as pool:
            cells = list(tqdm(pool.imap(_cell, tasks), total=CELLS, desc="preview", disable=not progress))
    rows = [np.hstack(cells[r * 3:(r + 1) * 3]) for r in range(CELLS // 3)]
    sheet = np.vstack(rows)
    legend = np.full((26, sheet.shape[1], 3), 255, np.uint8)
    ramp = colourise_height(np.tile(np.linspace(0, MAX_HEIGHT_M, 300)[None, :], (12, 1)))
    legend[7:19, 200:500] = ramp
    cv2.putText(legend, "height 0 m", (110, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(legend, f"{MAX_HEIGHT_M:.0f}+ m   (sky black)", (506, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.42,
                (0, 0, 0), 1, cv2.LINE_AA)
    sheet = np.vstack([legend, sheet])
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), sheet[..., ::-1])
    return path
