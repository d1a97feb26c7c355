"""Self-calibration from walking people: horizon (pitch, roll) and camera height.

With nothing known of the camera, pedestrians are the calibration object. Two facts carry it:

* a person does not change height while walking away from or towards the camera, and people
  are similar in height: only the right horizon makes the heights measured from head and foot
  points independent of where in the image they are (this fixes pitch, and roll across the
  image width);
* people stand upright: the head lies on the image of the vertical through the foot, a line
  through the vertical vanishing point (this fixes roll and, weakly, pitch).

Both only give heights *relative* to the camera height. The metric scale comes from a
population prior (people are 1.70 +- 0.09 m tall): the camera height is the one that makes
the mean tracked person as tall as the prior's mean. Its uncertainty is honest about that
assumption: the spread of people over the number of tracks, the uncertainty of the population
mean itself, and a bootstrap over tracks for everything the fit does.

The focal length is not estimated (it is nearly degenerate with pitch from this data); it comes
from the configured field of view or an intrinsic calibration. Relative heights depend mostly on
where the horizon is, so a wrong focal length costs little in height, more in ground distances.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from pipeline.errors import HeightpipeError
from pipeline.packets import CameraInfo
from stages.calibration import (camera_from_pose, heights_from_foot_top, horizon_line,
                                vertical_vanishing_point)


class SelfCalibrationError(HeightpipeError):
    """Too few or too poor pedestrian observations to calibrate from."""


@dataclass
class HeightPrior:
    """Statures of the people in view."""

    mean_m: float = 1.70
    std_m: float = 0.09
    """Spread between people."""
    mean_std_m: float = 0.04
    """How wrong ``mean_m`` may be for this crowd (shoes, region, children, sex ratio)."""


@dataclass
class FitSettings:
    point_noise_px: float = 2.0
    """Std of detected head and foot points."""
    posture_fraction: float = 0.03
    """Frame-to-frame variation of one person's measured height (gait, posture), relative."""
    lean_fraction: float = 0.05
    """Sideways offset of the head from the foot's vertical, relative to the person's image height."""
    roll_prior_deg: float = 10.0
    """CCTV cameras are mounted nearly level: a weak prior keeps roll sane with little data."""
    min_pixel_height: float = 20.0
    """People smaller than this in the image are too coarse to use."""
    min_tracks: int = 3
    min_observations: int = 20
    bootstrap: int = 60
    """Refits on tracks resampled with replacement, for the uncertainty."""
    seed: int = 0


@dataclass
class SelfCalibration:
    """The result: a camera pose with its uncertainty."""

    width: int
    height: int
    K: np.ndarray
    height_m: float
    height_std_m: float
    pitch_deg: float
    pitch_std_deg: float
    roll_deg: float
    roll_std_deg: float
    n_observations: int
    n_tracks: int
    prior: HeightPrior
    height_spread: float = 0.0
    """Std of the per-track relative heights (person height / camera height) after the fit."""
    residual_px: float = 0.0
    """Median sideways distance of heads from their foot's vertical."""
    notes: list[str] = field(default_factory=list)

    def camera(self) -> CameraInfo:
        return camera_from_pose(self.width, self.height, self.K, self.height_m, self.pitch_deg,
                                self.roll_deg, source="self")

    def horizon(self) -> np.ndarray:
        return horizon_line(self.camera())

    def config_snippet(self, calibration: str = "") -> str:
        """``[camera]`` lines for config.toml that reproduce this camera."""
        focal = self.K[0, 0]
        fov = math.degrees(2 * math.atan(self.width / 2 / focal))
        lines = [
            "[camera]",
            f"height_m = {self.height_m:.2f}            # self-calibrated: +- {self.height_std_m:.2f} m "
            f"({self.n_tracks} people, prior {self.prior.mean_m:.2f} +- {self.prior.std_m:.2f} m)",
            f"height_std_m = {self.height_std_m:.2f}",
            f"pitch_deg = {self.pitch_deg:.2f}           # +- {self.pitch_std_deg:.2f}",
            f"roll_deg = {self.roll_deg:.2f}            # +- {self.roll_std_deg:.2f}",
        ]
        if calibration:
            lines.append(f"calibration = {_toml_string(calibration)}   # intrinsics (its pose is not used)")
        else:
            lines.append(f"fov_deg = {fov:.1f}             # assumed, not estimated (focal {focal:.0f} px)")
        lines.append("self_calibrated = true")
        return "\n".join(lines)


def _toml_string(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def self_calibrate(foot_uv: np.ndarray, top_uv: np.ndarray, track_ids: np.ndarray,
                   width: int, height: int, K: np.ndarray, prior: HeightPrior | None = None,
                   settings: FitSettings | None = None) -> SelfCalibration:
    """Camera pose from head (top) and foot points of pedestrians, in undistorted pixels of K.

    ``track_ids`` groups observations of one person; give every observation its own id when
    there is no tracking (then only the population spread ties them together).
    """
    prior = prior or HeightPrior()
    settings = settings or FitSettings()
    observations = _Observations.select(foot_uv, top_uv, track_ids, settings)
    if observations.n_tracks < settings.min_tracks or len(observations) < settings.min_observations:
        raise SelfCalibrationError(
            f"self-calibration needs at least {settings.min_tracks} people and "
            f"{settings.min_observations} head/foot observations, got {observations.n_tracks} and "
            f"{len(observations)}")
    problem = _Problem(width, height, np.asarray(K, float), prior, settings)

    pitch, roll = problem.fit(observations)
    relative = problem.track_relative_heights(observations, pitch, roll)
    camera_height = prior.mean_m / float(np.mean(relative))

    # Bootstrap over people: refit on resampled tracks, starting from the solution.
    rng = np.random.default_rng(settings.seed)
    samples = []
    for _ in range(settings.bootstrap):
        resampled = observations.resample_tracks(rng)
        fitted = problem.fit(resampled, start=(pitch, roll))
        samples.append((*fitted, prior.mean_m / float(np.mean(problem.track_relative_heights(resampled, *fitted)))))
    samples = np.array(samples) if samples else np.zeros((0, 3))
    pitch_std, roll_std, height_boot_std = (samples.std(axis=0, ddof=1) if len(samples) > 1
                                            else (math.nan,) * 3)

    # Camera height: people's spread over the number of people (at least), and the prior's mean.
    spread_std = camera_height * prior.std_m / prior.mean_m / math.sqrt(observations.n_tracks)
    mean_std = camera_height * prior.mean_std_m / prior.mean_m
    height_std = math.sqrt(max(height_boot_std, spread_std) ** 2 + mean_std ** 2)

    result = SelfCalibration(
        width=width, height=height, K=problem.K, height_m=camera_height, height_std_m=height_std,
        pitch_deg=pitch, pitch_std_deg=float(pitch_std), roll_deg=roll, roll_std_deg=float(roll_std),
        n_observations=len(observations), n_tracks=observations.n_tracks, prior=prior,
        height_spread=float(np.std(relative * camera_height)),
        residual_px=float(np.median(np.abs(problem.lateral_px(observations, pitch, roll)))),
    )
    if pitch_std > 3.0:
        result.notes.append(f"pitch is poorly determined (+- {pitch_std:.1f} deg): people should "
                            "be seen over a wider range of distances")
    return result


@dataclass
class _Observations:
    foot: np.ndarray
    top: np.ndarray
    track: np.ndarray
    """0..n_tracks-1 per observation."""
    n_tracks: int

    def __len__(self) -> int:
        return len(self.foot)

    @classmethod
    def select(cls, foot_uv, top_uv, track_ids, settings: FitSettings) -> "_Observations":
        foot = np.asarray(foot_uv, float).reshape(-1, 2)
        top = np.asarray(top_uv, float).reshape(-1, 2)
        ids = np.asarray(track_ids).ravel()
        if not len(foot) == len(top) == len(ids):
            raise ValueError("foot_uv, top_uv and track_ids must have the same length")
        keep = (np.all(np.isfinite(foot), axis=1) & np.all(np.isfinite(top), axis=1)
                & (foot[:, 1] - top[:, 1] >= settings.min_pixel_height))
        _, track = np.unique(ids[keep], return_inverse=True)
        return cls(foot[keep], top[keep], track, int(track.max()) + 1 if track.size else 0)

    def resample_tracks(self, rng: np.random.Generator) -> "_Observations":
        chosen = rng.integers(0, self.n_tracks, self.n_tracks)
        parts = [np.flatnonzero(self.track == k) for k in chosen]
        index = np.concatenate(parts)
        track = np.concatenate([np.full(len(p), i) for i, p in enumerate(parts)])
        return _Observations(self.foot[index], self.top[index], track, self.n_tracks)


class _Problem:
    """Residuals of a candidate (pitch, roll) for a unit-height camera."""

    def __init__(self, width: int, height: int, K: np.ndarray, prior: HeightPrior, settings: FitSettings):
        self.width, self.height, self.K = width, height, K
        self.prior, self.settings = prior, settings

    def camera(self, pitch: float, roll: float) -> CameraInfo:
        return camera_from_pose(self.width, self.height, self.K, 1.0, pitch, roll)

    def lateral_px(self, obs: _Observations, pitch: float, roll: float) -> np.ndarray:
        """Signed distance of each head from the image line joining its foot and the vertical VP."""
        vp = vertical_vanishing_point(self.camera(pitch, roll))
        foot_h = np.column_stack([obs.foot, np.ones(len(obs))])
        lines = np.cross(foot_h, vp)
        return (lines[:, 0] * obs.top[:, 0] + lines[:, 1] * obs.top[:, 1] + lines[:, 2]) / \
            np.hypot(lines[:, 0], lines[:, 1])

    def residuals(self, params: np.ndarray, obs: _Observations) -> np.ndarray:
        pitch, roll = float(params[0]), float(params[1])
        s = self.settings
        relative, _ = heights_from_foot_top(self.camera(pitch, roll), obs.foot, obs.top)
        pixel_height = obs.foot[:, 1] - obs.top[:, 1]
        valid = np.isfinite(relative) & (relative > 0)
        log_h = np.where(valid, np.log(np.where(valid, relative, 1.0)), 0.0)
        sigma = np.hypot(s.point_noise_px * math.sqrt(2) / pixel_height, s.posture_fraction)
        weight = valid / sigma ** 2
        track_weight = np.bincount(obs.track, weight, obs.n_tracks)
        track_mean = np.bincount(obs.track, weight * log_h, obs.n_tracks) / np.maximum(track_weight, 1e-12)
        within = np.where(valid, (log_h - track_mean[obs.track]) / sigma, 10.0)
        # Between people: track means scatter by the population spread (plus their own noise).
        seen = track_weight > 0
        pop = self.prior.std_m / self.prior.mean_m
        between = np.zeros(obs.n_tracks)
        if seen.sum() > 1:
            between[seen] = (track_mean[seen] - track_mean[seen].mean()) / np.sqrt(pop ** 2 + 1.0 / track_weight[seen])
        lateral_sigma = np.hypot(s.point_noise_px, s.lean_fraction * pixel_height)
        lateral = self.lateral_px(obs, pitch, roll) / lateral_sigma
        return np.concatenate([within, between, lateral, [roll / s.roll_prior_deg]])

    def cost(self, params, obs) -> float:
        r = self.residuals(np.asarray(params, float), obs)
        return float(np.sum(2.0 * (np.sqrt(1.0 + r * r) - 1.0)))     # soft-L1, as in the fit

    def fit(self, obs: _Observations, start: tuple[float, float] | None = None) -> tuple[float, float]:
        from scipy.optimize import least_squares

        if start is None:
            # Coarse search over pitch (the fit is not convex over the whole range).
            grid = np.arange(1.0, 86.0, 1.0)
            costs = [self.cost((p, 0.0), obs) for p in grid]
            start = (float(grid[int(np.argmin(costs))]), 0.0)
        result = least_squares(self.residuals, np.array(start, float), args=(obs,), loss="soft_l1",
                               bounds=([0.1, -45.0], [89.5, 45.0]), x_scale=[1.0, 1.0], diff_step=1e-4)
        return float(result.x[0]), float(result.x[1])

    def track_relative_heights(self, obs: _Observations, pitch: float, roll: float) -> np.ndarray:
        """Each person's median height over camera height."""
        relative, _ = heights_from_foot_top(self.camera(pitch, roll), obs.foot, obs.top)
        out = []
        for k in range(obs.n_tracks):
            values = relative[(obs.track == k) & np.isfinite(relative)]
            if values.size:
                out.append(np.median(values))
        return np.array(out)
