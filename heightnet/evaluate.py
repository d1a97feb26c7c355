"""The paper's Table 1 on held-out synth scenes: per camera height, for one or more ONNX models.

Writes ``table.md`` (Markdown), ``table.csv`` and ``figure4.png`` (input / ground truth /
prediction, one row per camera height, like the paper's Figure 4) into the output folder, and
returns the Markdown. A second model (e.g. trained without the consistency loss) gives the
ablation rows side by side.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from heightnet.metrics import RowMetrics, row_label
from heightnet.predict import HeightPredictor

TABLE_COLUMNS = [("rmse_cm", "RMSE cm", "{:.1f}"), ("mae_cm", "MAE cm", "{:.1f}"),
                 ("absrel", "AbsRel", "{:.3f}"), ("delta1", "δ<1.25", "{:.3f}"),
                 ("delta2", "δ<1.25²", "{:.3f}"), ("delta3", "δ<1.25³", "{:.3f}")]


@dataclass
class ModelResult:
    label: str
    rows: dict[int, RowMetrics] = field(default_factory=dict)
    total: RowMetrics = field(default_factory=RowMetrics)
    examples: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray, int]] = field(default_factory=dict)
    """camera-height row -> (rgb, true height, predicted height, movers) of its busiest frame."""


def evaluate_sequences(sequences: Sequence[Any], predictor: HeightPredictor, label: str,
                       every: int = 1, progress: bool = False) -> ModelResult:
    from tqdm import tqdm

    result = ModelResult(label)
    frames = [(seq, i) for seq in sequences for i in range(0, len(seq), every)]
    for seq, i in tqdm(frames, desc=f"eval {label}", disable=not progress):
        camera_height = float(seq.meta.camera.height_m)
        row = row_label(camera_height)
        frame = seq.frame(i)
        prediction = predictor.predict(frame.rgb, camera_height)
        visible = {o.id for o in seq.objects(i) if o.visible_fraction >= 0.8}
        for metrics in (result.rows.setdefault(row, RowMetrics()), result.total):
            metrics.add_frame(prediction.height_m, prediction.ground_probability, frame.height_m,
                              frame.ground, frame.instance, visible)
        movers = int((frame.instance > 0).sum())
        if row not in result.examples or movers > result.examples[row][3]:
            result.examples[row] = (frame.rgb, frame.height_m, prediction.height_m, movers)
    return result


def markdown_table(results: Sequence[ModelResult]) -> str:
    lines = []
    for selection, title in (("mover", "Mover pixels (true height > 0.1 m on a mover)"),
                             ("above", "All above-ground pixels (true height > 0.1 m)")):
        lines += [f"**{title}**", "",
                  "| model | camera height (cm) | frames | " + " | ".join(c[1] for c in TABLE_COLUMNS)
                  + " | ground IoU | objects | median top-height error (cm) |",
                  "|---" * (len(TABLE_COLUMNS) + 6) + "|"]
        for result in results:
            for row, metrics in [*sorted(result.rows.items()), ("all", result.total)]:
                s = metrics.summary()
                cells = [fmt.format(s[f"{selection}_{key}"]) for key, _, fmt in TABLE_COLUMNS]
                lines.append(f"| {result.label} | {row} | {s['frames']} | " + " | ".join(cells)
                             + f" | {s['ground_iou']:.3f} | {s['objects']} | "
                             f"{s['object_top_median_abs_cm']:.1f} |")
        lines.append("")
    return "\n".join(lines)


def write_csv(results: Sequence[ModelResult], path: Path) -> None:
    rows = []
    for result in results:
        for row, metrics in [*sorted(result.rows.items()), ("all", result.total)]:
            rows.append({"model": result.label, "camera_height_cm": row, **metrics.summary()})
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def write_figure(results: Sequence[ModelResult], path: Path, max_height_m: float = 3.0) -> None:
    """Figure 4: input / ground truth / prediction (one column per model) per camera height."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = sorted(results[0].examples)
    cols = 2 + len(results)
    fig, axes = plt.subplots(len(rows), cols, figsize=(3.2 * cols, 2.5 * len(rows)), squeeze=False)
    for r, row in enumerate(rows):
        rgb, truth, _, _ = results[0].examples[row]
        panels = [(rgb, f"input, camera {row} cm"), (truth, "ground truth")]
        panels += [(res.examples[row][2], f"prediction: {res.label}") for res in results
                   if row in res.examples]
        for c, (image, title) in enumerate(panels):
            ax = axes[r][c]
            if image.ndim == 3:
                ax.imshow(image)
            else:
                ax.imshow(np.nan_to_num(image), cmap="turbo", vmin=0, vmax=max_height_m)
            ax.set_title(title, fontsize=8)
            ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def run_evaluation(sequences: Sequence[Any], models: Sequence[tuple[str, Path]], out_dir: Path,
                   every: int = 1, threads: int = 2, progress: bool = False) -> str:
    out_dir.mkdir(parents=True, exist_ok=True)
    results = [evaluate_sequences(sequences, HeightPredictor(path, threads), label, every, progress)
               for label, path in models]
    table = markdown_table(results)
    (out_dir / "table.md").write_text(table)
    write_csv(results, out_dir / "table.csv")
    write_figure(results, out_dir / "figure4.png")
    return table
