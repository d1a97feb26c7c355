"""Input normalisation shared by training, export metadata and ONNX inference (no torch)."""

from __future__ import annotations

import numpy as np

# ImageNet statistics: the usual choice, kept although the encoders train from scratch, so a
# later pretrained encoder drops in without changing the contract.
MEAN = (0.485, 0.456, 0.406)
STD = (0.229, 0.224, 0.225)


def normalise(rgb: np.ndarray, mean=MEAN, std=STD) -> np.ndarray:
    """uint8 H x W x 3 RGB -> float32 3 x H x W, (pixel/255 - mean) / std."""
    x = rgb.astype(np.float32) * (1.0 / 255.0)
    x = (x - np.asarray(mean, np.float32)) / np.asarray(std, np.float32)
    return np.ascontiguousarray(x.transpose(2, 0, 1))
