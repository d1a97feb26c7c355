"""HeightNet v2's camera heads at run time: one fixed camera's pitch, roll and focal length.

The heads (heightnet/contact_model.py) guess, from one image, the pitch and roll (radians) and
the log of the vertical focal length in image heights, each with a log-variance. A CCTV camera
does not move, so every frame is one more noisy reading of the same three numbers, and the run
averages them (``HeadsAverage``). With the mounting height, which the user gives, that is a
whole camera (``camera_from_heads``).
"""

from __future__ import annotations

import math

import numpy as np

from stages.ground_contact import PinholeCamera, camera_from_angles

HEAD_VALUES = 3
"""pitch (rad), roll (rad), log(vertical focal length / image height); then their log-variances."""
MAX_ABS_LOG_VAR = 20.0
"""Log-variances are clipped to +-20 before exponentiating, so one wild frame cannot own or
vanish from the average through an overflowing weight."""


class HeadsAverage:
    """Running mean of the camera heads' outputs, each frame weighted by its inverse variance.

    Why weighted: every frame of a fixed camera reads the same pitch, roll and focal length, and
    for readings with Gaussian noise of known variance the most likely common value is the
    inverse-variance-weighted mean. Frames the heads are unsure of (dark, empty, a bus filling
    the view) then count for less, as they should, instead of one vote each.

    Why the reported spread is not the standard error of that mean: the frames of one camera
    show the same scene, so the heads' error on it is largely shared between frames rather than
    independent, and 1/sqrt(sum of weights) would shrink towards 0 while the bias stays. ``std``
    is the heads' typical per-frame standard deviation instead (the square root of the harmonic
    mean of their variances): what one frame's reading is worth, never improved by repetition.
    """

    def __init__(self) -> None:
        self._weight = np.zeros(HEAD_VALUES)
        self._weighted = np.zeros(HEAD_VALUES)
        self.frames = 0

    def add(self, outputs: np.ndarray) -> None:
        """One frame's six head outputs; a frame with non-finite outputs is skipped."""
        outputs = np.asarray(outputs, np.float64).ravel()
        if outputs.size != 2 * HEAD_VALUES or not np.all(np.isfinite(outputs)):
            return
        weight = np.exp(-np.clip(outputs[HEAD_VALUES:], -MAX_ABS_LOG_VAR, MAX_ABS_LOG_VAR))
        self._weight += weight
        self._weighted += weight * outputs[:HEAD_VALUES]
        self.frames += 1

    @property
    def mean(self) -> np.ndarray:
        """pitch, roll, log focal: the weighted mean so far (NaN before the first frame)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return self._weighted / self._weight

    @property
    def std(self) -> np.ndarray:
        """Typical per-frame standard deviation of each of the three (see the class docstring)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.sqrt(self.frames / self._weight)


def camera_from_heads(values: np.ndarray, width: int, height: int, source_size: tuple[int, int],
                      camera_height_m: float, K: np.ndarray | None = None) -> PinholeCamera:
    """The camera the heads describe, at the network's input size ``width`` x ``height``.

    The input is the source frame squashed to that size, so its pixels are not square when the
    aspect ratios differ; the heads' focal length is the vertical one, in image heights, which
    the squash leaves alone, and the horizontal one follows from the squash. ``K`` (input-size
    intrinsics from a calibration file) replaces the heads' focal length and principal point
    when the lens is known.
    """
    pitch, roll, log_focal = (float(v) for v in np.asarray(values)[:HEAD_VALUES])
    src_w, src_h = source_size
    aspect = (width / src_w) / (height / src_h)
    camera = camera_from_angles(width, height, camera_height_m, pitch, roll, math.exp(log_focal) * height, aspect)
    if K is not None:
        camera = PinholeCamera(np.asarray(K, np.float64), camera.R, camera.C)
    return camera
