"""The paper's Table 1 metrics (NumPy only), accumulated per camera-height row.

Pixel metrics compare predicted and true height in metres on a pixel selection:
RMSE and MAE (reported in cm), AbsRel = mean |p - g| / g, and the threshold accuracies
delta_k = fraction of pixels with max(p/g, g/p) < 1.25^k, a fraction in [0, 1]. Two selections:
*mover pixels* (instance id > 0 and true height > 0.1 m) and *above-ground pixels* (every pixel
with true height > 0.1 m, static objects too). Ground IoU compares the predicted ground mask
(probability > 0.5) with the true ground plane. Per-object top height: for each mover with at
least ``min_object_pixels`` pixels and a visible fraction of at least 0.8, the 98th percentile of
its predicted heights against the highest true height on its pixels (the visible top).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

PAPER_CAMERA_HEIGHTS_CM = (350, 500, 640, 780, 920)
ABOVE_GROUND_M = 0.1
MIN_PREDICTION_M = 1e-3  # ratios need a positive prediction


def row_label(camera_height_m: float) -> int:
    """The paper's camera height (cm) within 35 cm, else the height rounded to 10 cm."""
    cm = camera_height_m * 100
    nearest = min(PAPER_CAMERA_HEIGHTS_CM, key=lambda h: abs(h - cm))
    return nearest if abs(nearest - cm) <= 35 else int(round(cm / 10) * 10)


@dataclass
class PixelErrors:
    pixels: int = 0
    sum_sq: float = 0.0
    sum_abs: float = 0.0
    sum_rel: float = 0.0
    within: list[int] = field(default_factory=lambda: [0, 0, 0])

    def add(self, pred_m: np.ndarray, true_m: np.ndarray) -> None:
        pred = np.maximum(pred_m.astype(np.float64), MIN_PREDICTION_M)
        true = true_m.astype(np.float64)
        err = pred - true
        self.pixels += err.size
        self.sum_sq += float((err ** 2).sum())
        self.sum_abs += float(np.abs(err).sum())
        self.sum_rel += float((np.abs(err) / true).sum())
        ratio = np.maximum(pred / true, true / pred)
        for k in range(3):
            self.within[k] += int((ratio < 1.25 ** (k + 1)).sum())

    def summary(self) -> dict[str, float]:
        if self.pixels == 0:
            return {"pixels": 0, "rmse_cm": float("nan"), "mae_cm": float("nan"),
                    "absrel": float("nan"), "delta1": float("nan"), "delta2": float("nan"),
                    "delta3": float("nan")}
        n = self.pixels
        return {"pixels": n, "rmse_cm": 100 * np.sqrt(self.sum_sq / n), "mae_cm": 100 * self.sum_abs / n,
                "absrel": self.sum_rel / n, "delta1": self.within[0] / n,
                "delta2": self.within[1] / n, "delta3": self.within[2] / n}


@dataclass
class RowMetrics:
    """Everything for one camera-height row of the table."""

    frames: int = 0
    movers: PixelErrors = field(default_factory=PixelErrors)
    above_ground: PixelErrors = field(default_factory=PixelErrors)
    ground_intersection: int = 0
    ground_union: int = 0
    object_errors_m: list[float] = field(default_factory=list)

    def add_frame(self, pred_m: np.ndarray, ground_probability: np.ndarray, true_m: np.ndarray,
                  true_ground: np.ndarray, instance: np.ndarray,
                  visible_ids: set[int] | None = None, min_object_pixels: int = 20) -> None:
        self.frames += 1
        defined = np.isfinite(true_m)
        above = defined & (true_m > ABOVE_GROUND_M)
        movers = above & (instance > 0)
        self.movers.add(pred_m[movers], true_m[movers])
        self.above_ground.add(pred_m[above], true_m[above])
        pred_ground = ground_probability > 0.5
        self.ground_intersection += int((pred_ground & true_ground).sum())
        self.ground_union += int((pred_ground | true_ground).sum())
        for obj in np.unique(instance[movers]):
            if visible_ids is not None and int(obj) not in visible_ids:
                continue
            pixels = movers & (instance == obj)
            if pixels.sum() < min_object_pixels:
                continue
            top_pred = float(np.percentile(pred_m[pixels], 98))
            self.object_errors_m.append(top_pred - float(true_m[pixels].max()))

    def summary(self) -> dict[str, float]:
        errors = np.abs(np.asarray(self.object_errors_m))
        return {
            "frames": self.frames,
            **{f"mover_{k}": v for k, v in self.movers.summary().items()},
            **{f"above_{k}": v for k, v in self.above_ground.summary().items()},
            "ground_iou": self.ground_intersection / self.ground_union if self.ground_union else float("nan"),
            "objects": len(errors),
            "object_top_median_abs_cm": 100 * float(np.median(errors)) if len(errors) else float("nan"),
        }
