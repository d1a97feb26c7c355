"""The background model of object extraction: what moves in a fixed camera's view.

OpenCV's subtractors by name (KNN is the default: measured best here, see
``stages/object_extraction.py``) and the clean-up of their masks.
"""

from __future__ import annotations

import cv2
import numpy as np

from core.errors import ConfigError

BACKGROUND_METHODS = ("mog2", "cnt", "knn", "gsoc", "none")

# MOG2/KNN mark shadows as 127 in the foreground mask; only 255 is a moving object.
FOREGROUND_VALUE = 255


def make_background_subtractor(method: str):
    """OpenCV background subtractor by name (None for 'none').

    KNN and MOG2 draw from OpenCV's process-wide random generator: it is seeded here, so that a
    run's foreground does not depend on what ran before it in the same process (eval-tracks
    over many sequences, a batch worker's second file).
    """
    cv2.setRNGSeed(0)
    if method == "mog2":
        return cv2.createBackgroundSubtractorMOG2(history=500, varThreshold=16, detectShadows=True)
    if method == "knn":
        return cv2.createBackgroundSubtractorKNN(history=500, dist2Threshold=400.0, detectShadows=True)
    if method == "cnt":
        # CNT absorbs stopped objects quickly; a longer max stability keeps slow walkers.
        return cv2.bgsegm.createBackgroundSubtractorCNT(minPixelStability=15, useHistory=True,
                                                        maxPixelStability=15 * 60, isParallel=False)
    if method == "gsoc":
        return cv2.bgsegm.createBackgroundSubtractorGSOC()
    if method == "none":
        return None
    raise ConfigError(f"objects.background must be one of {', '.join(BACKGROUND_METHODS)}, "
                      f"got {method!r}")


def drop_small_pieces(mask: np.ndarray, min_px: float) -> np.ndarray:
    """The mask without its 8-connected pieces smaller than ``min_px`` pixels (all kept when <= 1).

    At dusk, at night and in rain the background model flags specks of sensor noise all over
    a low-resolution frame; grown by a few pixels they join into one blob with every walker
    near them, too sparse to pass the foreground test. A walker's one-pixel legs stay: they
    hang on to the body's piece.
    """
    if min_px <= 1 or not mask.any():
        return mask
    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    keep = stats[:, cv2.CC_STAT_AREA] >= min_px
    keep[0] = False
    return keep[labels]
