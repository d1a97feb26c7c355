"""Per-track Kalman filters (filterpy), built by a factory so the tracker never touches matrices.

Two independent filters per track:

* ``MotionFilter``: the box in the image, constant velocity, state
  ``[cx, cy, w, h, vcx, vcy, vw, vh]`` (pixels, pixels per frame). Noise scales with the box
  size as in DeepSORT / BoT-SORT (``std_weight_position = 1/20``, ``std_weight_velocity =
  1/160``): a 20 px box and a 200 px box are equally sure in relative terms. Camera shake is
  applied to this state (``warp``), never to the height.
* ``HeightFilter``: the object's height in metres, a random walk with near-zero process noise
  (objects do not grow), so every frame is one more measurement of the same number; beside it,
  each channel's (network, foot/top geometry, vehicle box, any other) bias on this object,
  which frames do not average away.
  A second measurement channel (geometry) is just a second ``update`` in the same frame
  (sequential update: independent measurements may be applied one after the other); a channel
  the filter has not seen before gets a bias state of its own at its first measurement.

The algebra is filterpy's ``KalmanFilter`` (Joseph-form covariance update); only the
matrices are set here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from filterpy.kalman import KalmanFilter

from core.config import TrackingConfig
from core.packets import BOX, GEOMETRY, NETWORK

Box = tuple[float, float, float, float]


@dataclass(frozen=True)
class KalmanConstants:
    """The box filter's noise: DeepSORT's weights (a 20 px and a 200 px box are equally sure
    in relative terms)."""

    # DeepSORT / BoT-SORT: position noise 1/20 of the box size, velocity noise 1/160 of it per frame.
    std_weight_position: float = 1.0 / 20.0
    std_weight_velocity: float = 1.0 / 160.0


CONSTANTS = KalmanConstants()


def box_to_z(box: Box) -> np.ndarray:
    x, y, w, h = box
    return np.array([[x + w / 2.0], [y + h / 2.0], [w], [h]], dtype=float)


def z_to_box(z: np.ndarray) -> Box:
    cx, cy, w, h = (float(v) for v in np.asarray(z).ravel()[:4])
    w, h = max(w, 1.0), max(h, 1.0)
    return (cx - w / 2.0, cy - h / 2.0, w, h)


@dataclass
class MotionSnapshot:
    """Filter state saved at an observation, for the OC-SORT re-update after a gap."""

    x: np.ndarray
    P: np.ndarray


class MotionFilter:
    """Constant-velocity box filter in image pixels."""

    def __init__(self, box: Box):
        kf = KalmanFilter(dim_x=8, dim_z=4)
        kf.F = np.eye(8)
        kf.F[:4, 4:] = np.eye(4)          # position += velocity (one frame)
        kf.H = np.eye(4, 8)
        kf.x = np.zeros((8, 1))
        kf.x[:4] = box_to_z(box)
        w, h = kf.x[2, 0], kf.x[3, 0]
        std = np.array([2 * CONSTANTS.std_weight_position * w, 2 * CONSTANTS.std_weight_position * h,
                        2 * CONSTANTS.std_weight_position * w, 2 * CONSTANTS.std_weight_position * h,
                        10 * CONSTANTS.std_weight_velocity * w, 10 * CONSTANTS.std_weight_velocity * h,
                        10 * CONSTANTS.std_weight_velocity * w, 10 * CONSTANTS.std_weight_velocity * h])
        kf.P = np.diag(std ** 2)
        self.kf = kf

    @property
    def box(self) -> Box:
        return z_to_box(self.kf.x[:4])

    @property
    def velocity(self) -> np.ndarray:
        return self.kf.x[4:6, 0].copy()

    def predict(self) -> None:
        w, h = max(self.kf.x[2, 0], 1.0), max(self.kf.x[3, 0], 1.0)
        std = np.array([CONSTANTS.std_weight_position * w, CONSTANTS.std_weight_position * h,
                        CONSTANTS.std_weight_position * w, CONSTANTS.std_weight_position * h,
                        CONSTANTS.std_weight_velocity * w, CONSTANTS.std_weight_velocity * h,
                        CONSTANTS.std_weight_velocity * w, CONSTANTS.std_weight_velocity * h])
        self.kf.predict(Q=np.diag(std ** 2))
        # A box cannot shrink below a pixel; a negative size would flip the box.
        self.kf.x[2:4] = np.maximum(self.kf.x[2:4], 1.0)

    def hold_size(self) -> None:
        """Stop the box's size from changing (while the object is not seen).

        Extrapolated, a size velocity learnt from a few noisy frames shrinks a coasting box to one
        pixel or stretches it over the frame within a second; an unseen object keeps its size.
        """
        self.kf.x[6:8] = 0.0

    def measurement_noise(self, noise_scale: float = 1.0) -> np.ndarray:
        w, h = max(self.kf.x[2, 0], 1.0), max(self.kf.x[3, 0], 1.0)
        std = np.array([CONSTANTS.std_weight_position * w, CONSTANTS.std_weight_position * h,
                        CONSTANTS.std_weight_position * w, CONSTANTS.std_weight_position * h]) * noise_scale
        return np.diag(std ** 2)

    def update(self, box: Box, noise_scale: float = 1.0) -> None:
        self.kf.update(box_to_z(box), R=self.measurement_noise(noise_scale))

    def mahalanobis_sq(self, boxes: list[Box]) -> np.ndarray:
        """Squared Mahalanobis distance of each box from the prediction (chi-square, 4 dof)."""
        if len(boxes) == 0:
            return np.zeros(0)
        measured = np.hstack([box_to_z(box) for box in boxes]).T          # N x 4
        residual = measured - (self.kf.H @ self.kf.x).T
        innovation = self.kf.H @ self.kf.P @ self.kf.H.T + self.measurement_noise()
        return np.einsum("ni,ij,nj->n", residual, np.linalg.inv(innovation), residual)

    def warp(self, affine: np.ndarray) -> None:
        """Move the state by the background's 2x3 affine (camera shake) from the last frame."""
        affine = np.asarray(affine, dtype=float)
        linear, shift = affine[:, :2], affine[:, 2]
        scale = float(np.sqrt(abs(np.linalg.det(linear))))
        transform = np.zeros((8, 8))
        transform[0:2, 0:2] = linear
        transform[2, 2] = transform[3, 3] = scale
        transform[4:6, 4:6] = linear
        transform[6, 6] = transform[7, 7] = scale
        self.kf.x = transform @ self.kf.x
        self.kf.x[0:2, 0] += shift
        self.kf.P = transform @ self.kf.P @ transform.T

    def snapshot(self) -> MotionSnapshot:
        return MotionSnapshot(self.kf.x.copy(), self.kf.P.copy())

    def restore(self, snapshot: MotionSnapshot) -> None:
        self.kf.x = snapshot.x.copy()
        self.kf.P = snapshot.P.copy()


class HeightFilter:
    """Object height in metres: a constant with a tiny random walk, plus each channel's bias on it.

    Measurements come through named channels ("network", "geometry" from a person's foot and
    crown, "box" from a vehicle's outline, or any channel a stage adds); several in one frame are
    applied one after the other (sequential update of independent measurements), and the
    filter remembers which channels have contributed (``source``).

    Neither channel's error on one object is white noise. The network reads a given walker 20 cm
    low in every frame (its colours, its pose, the scene behind it stay the same); the geometry
    takes the same hair for the crown and the same shoes for the soles, a pixel or two off in
    every frame. Averaging frames converges on the wrong number with a shrinking std. The state
    therefore holds each channel's bias beside the height, ``[H, b_n, b_g, b_box, ...]``: a network
    height measures ``H + b_n``, a geometry height ``H + b_g``; a channel first seen later is
    appended to the state then. Each bias starts at 0 with its own prior std (the network's
    ``bias_share`` of the height; any other channel's ``geometry_bias_factor`` times the per-object
    part of its first measurement's noise, for the geometry its pixels, which shrinks with the
    object's size in pixels) and stays constant.
    Frames then average only the white noise: the std never falls below what the biases allow,
    and where both channels measure, the height settles between them by their bias priors (the
    shipped network's 20 % against a few pixels: nearly the geometry), while a frame with only a
    network height (feet cut by the frame) is corrected by the learnt difference.
    """

    CHANNEL_BIAS = {NETWORK: 1, GEOMETRY: 2, BOX: 3}
    """State index of the shipped channels' biases; other channels' follow as they come."""

    def __init__(self, height_m: float, std_m: float, process_noise_m: float, channel: str = NETWORK,
                 bias_share: float = 0.0, geometry_bias_factor: float = 0.0, bias_std_m: float | None = None):
        kf = KalmanFilter(dim_x=4, dim_z=1)
        kf.x = np.array([[height_m], [0.0], [0.0], [0.0]])
        kf.P = np.diag([std_m ** 2, (bias_share * max(height_m, 0.0)) ** 2, 0.0, 0.0])
        kf.F = np.eye(4)
        # The biases are constants of the object; the height's own random walk lets readings drift.
        kf.Q = np.diag([process_noise_m ** 2, 0.0, 0.0, 0.0])
        self.kf = kf
        self.geometry_bias_factor = geometry_bias_factor
        self.channel_bias = dict(self.CHANNEL_BIAS)
        """State index of each channel's bias."""
        self.updates: dict[str, int] = {}
        self._start_bias(channel, std_m if bias_std_m is None else bias_std_m)
        kf = self.kf                      # grown by a bias state if the channel is a new one
        bias = self.channel_bias.get(channel)
        if bias is not None:
            # z = H + b: the height is as unsure as the measurement and the bias together.
            variance = kf.P[bias, bias]
            kf.P[0, 0] += variance
            kf.P[0, bias] = kf.P[bias, 0] = -variance
        self.updates[channel] = 1

    def _start_bias(self, channel: str, bias_std_m: float) -> None:
        """Any channel but the network's sets its bias prior with its first measurement: it scales
        with the part of its noise that repeats on this object (the geometry's pixels, a vehicle's
        shape; not the camera height that every object and the network's scale share)"""
        if channel != NETWORK and not self.updates.get(channel):
            if channel not in self.channel_bias:
                self._add_bias_state(channel)
            bias = self.channel_bias[channel]
            self.kf.P[bias, :] = self.kf.P[:, bias] = 0.0
            self.kf.P[bias, bias] = (self.geometry_bias_factor * bias_std_m) ** 2

    def _add_bias_state(self, channel: str) -> None:
        """One more state, a new channel's bias: 0, uncorrelated, constant (its prior comes next)."""
        n = self.kf.dim_x
        grown = KalmanFilter(dim_x=n + 1, dim_z=1)
        grown.x = np.vstack([self.kf.x, [[0.0]]])
        grown.P = np.pad(self.kf.P, ((0, 1), (0, 1)))
        grown.F = np.eye(n + 1)
        grown.Q = np.pad(self.kf.Q, ((0, 1), (0, 1)))
        self.kf = grown
        self.channel_bias[channel] = n

    @property
    def source(self) -> str:
        """'network', 'geometry', 'box' or 'fused': which channels this height is made of."""
        used = [name for name, count in self.updates.items() if count > 0]
        return used[0] if len(used) == 1 else "fused"

    @property
    def height_m(self) -> float:
        return float(self.kf.x[0, 0])

    @property
    def std_m(self) -> float:
        return float(np.sqrt(self.kf.P[0, 0]))

    def _row(self, channel: str) -> np.ndarray:
        """What the channel reads: the height plus its bias (no bias state yet: the height)."""
        row = np.zeros((1, self.kf.dim_x))
        row[0, 0] = 1.0
        if channel in self.channel_bias:
            row[0, self.channel_bias[channel]] = 1.0
        return row

    def predict(self) -> None:
        self.kf.predict()

    def expected_std_m(self, channel: str = NETWORK) -> float:
        """Std of what the state says this channel reads (height plus the channel's bias)."""
        row = self._row(channel)
        return float(np.sqrt((row @ self.kf.P @ row.T)[0, 0]))

    def normalized_residual(self, height_m: float, std_m: float, channel: str = NETWORK) -> float:
        """How many innovation standard deviations a measurement lies from the state."""
        row = self._row(channel)
        expected = float((row @ self.kf.x)[0, 0])
        variance = self.expected_std_m(channel) ** 2 + std_m ** 2
        if channel != NETWORK and not self.updates.get(channel):
            variance += (self.geometry_bias_factor * std_m) ** 2
        return abs(height_m - expected) / float(np.sqrt(variance))

    def update(self, height_m: float, std_m: float, channel: str = NETWORK,
               bias_std_m: float | None = None) -> None:
        """One measurement; ``bias_std_m``: its per-object systematic part (default: all of ``std_m``)."""
        self._start_bias(channel, std_m if bias_std_m is None else bias_std_m)
        self.kf.update(np.array([[height_m]]), R=np.array([[std_m ** 2]]), H=self._row(channel))
        self.updates[channel] = self.updates.get(channel, 0) + 1


class StatureWindow:
    """Stature of a walker from its recent single-frame heights, not the gait's mean dip.

    Walking lowers the head at every double support (the hip drops a few centimetres), so a
    walker's single-frame heights are the stature minus a one-sided dip, plus noise. Their
    mean (what a Kalman filter converges to) is the stature minus the mean dip. The upper
    quantile ``q`` over a window of about one gait cycle sits near the top of the oscillation
    instead, but noise pushes it up too, by about ``z_q`` standard deviations (``z_q`` the
    normal quantile of ``q``). That share is taken off again with the window's own measurement
    noise, and the result is never below the window's median: when noise dominates the gait,
    the estimate falls back to the median rather than trusting a noisy upper tail.
    """

    def __init__(self, size: int, quantile: float):
        from scipy.stats import norm

        self.size = max(1, size)
        self.quantile = quantile
        self.noise_quantile = float(norm.ppf(quantile))
        self.heights: list[float] = []
        self.noises: list[float] = []

    def add(self, height_m: float, noise_m: float) -> float:
        """Adds one frame; returns the stature estimate to feed the height filter."""
        self.heights.append(height_m)
        self.noises.append(noise_m)
        del self.heights[:-self.size], self.noises[:-self.size]
        if len(self.heights) < 3:
            return height_m
        upper = float(np.quantile(self.heights, self.quantile))
        noise = float(np.sqrt(np.mean(np.square(self.noises))))
        return max(upper - self.noise_quantile * noise, float(np.median(self.heights)))


class FilterFactory:
    """Builds the per-track filters; swap it to change filtering without touching association."""

    def __init__(self, config: TrackingConfig):
        self.height_process_noise_m = config.height_process_noise_m
        self.network_bias_share = config.network_bias_share
        self.geometry_bias_factor = config.geometry_bias_factor

    def create_motion_filter(self, box: Box) -> MotionFilter:
        return MotionFilter(box)

    def create_height_filter(self, height_m: float, std_m: float, channel: str = NETWORK,
                             bias_std_m: float | None = None) -> HeightFilter:
        return HeightFilter(height_m, std_m, self.height_process_noise_m, channel, self.network_bias_share,
                            self.geometry_bias_factor, bias_std_m)
