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

The focal length is estimated too when no intrinsic calibration gives it (``fit_focal``): the
head-foot lines of people across the image converge on the vertical vanishing point, whose
distance below the image centre is f / tan(pitch). It is only well determined for a camera that
looks clearly down; a weak prior around the configured field of view holds it otherwise.
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
    """Spread between people of the head's sideways offset from the foot's vertical, relative to
    the person's image height (lean, carried bags, how the detector boxes them)."""
    sway_fraction: float = 0.02
    """Frame-to-frame variation of that offset along one track."""
    roll_prior_deg: float = 10.0
    fit_focal: bool = True
    """Estimate the focal length (False: keep K's, e.g. from an intrinsic calibration)."""
    focal_prior_log_std: float = 0.5
    """Weak log-normal prior of the focal length around K's."""
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
    focal_std_px: float
    """0 where the focal length was given, not estimated."""
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
        elif self.focal_std_px > 0:
            fov_std = math.degrees(2 * self.width / 2 * self.focal_std_px / (focal ** 2 + (self.width / 2) ** 2))
            lines.append(f"fov_deg = {fov:.1f}             # +- {fov_std:.1f} (focal {focal:.0f} px, estimated)")
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

    params = problem.fit(observations)
    relative = problem.track_relative_heights(observations, params)
    camera_height = prior.mean_m / float(np.mean(relative))

    # Bootstrap over people: refit on resampled tracks, starting from the solution.
    rng = np.random.default_rng(settings.seed)
    samples = []
    for _ in range(settings.bootstrap):
        resampled = observations.resample_tracks(rng)
        fitted = problem.fit(resampled, start=params)
        relative_sample = problem.track_relative_heights(resampled, fitted)
        samples.append((*fitted, prior.mean_m / float(np.mean(relative_sample))))
    samples = np.array(samples)
    if len(samples) > 1:
        pitch_std, roll_std, log_focal_std, height_boot_std = samples.std(axis=0, ddof=1)
    else:
        pitch_std = roll_std = log_focal_std = height_boot_std = math.nan

    # Camera height: people's spread over the number of people (at least), and the prior's mean.
    spread_std = camera_height * prior.std_m / prior.mean_m / math.sqrt(observations.n_tracks)
    mean_std = camera_height * prior.mean_std_m / prior.mean_m
    height_std = math.sqrt(np.fmax(height_boot_std, spread_std) ** 2 + mean_std ** 2)

    pitch, roll, _ = params
    K_fit = problem.intrinsics(params)
    result = SelfCalibration(
        width=width, height=height, K=K_fit, height_m=camera_height, height_std_m=height_std,
        pitch_deg=pitch, pitch_std_deg=float(pitch_std), roll_deg=roll, roll_std_deg=float(roll_std),
        focal_std_px=float(K_fit[0, 0] * log_focal_std) if settings.fit_focal else 0.0,
        n_observations=len(observations), n_tracks=observations.n_tracks, prior=prior,
        height_spread=float(np.std(relative * camera_height)),
        residual_px=float(np.median(np.abs(problem.lateral_px(observations, params)))),
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
    """Residuals of candidate parameters (pitch deg, roll deg, log focal scale), unit camera height."""

    def __init__(self, width: int, height: int, K: np.ndarray, prior: HeightPrior, settings: FitSettings):
        self.width, self.height, self.K = width, height, K
        self.prior, self.settings = prior, settings

    def intrinsics(self, params) -> np.ndarray:
        K = self.K.copy()
        K[0, 0] *= math.exp(params[2])
        K[1, 1] *= math.exp(params[2])
        return K

    def camera(self, params) -> CameraInfo:
        return camera_from_pose(self.width, self.height, self.intrinsics(params), 1.0, params[0], params[1])

    def lateral_px(self, obs: _Observations, params) -> np.ndarray:
        """Signed distance of each head from the image line joining its foot and the vertical VP."""
        vp = vertical_vanishing_point(self.camera(params))
        foot_h = np.column_stack([obs.foot, np.ones(len(obs))])
        lines = np.cross(foot_h, vp)
        return (lines[:, 0] * obs.top[:, 0] + lines[:, 1] * obs.top[:, 1] + lines[:, 2]) / \
            np.hypot(lines[:, 0], lines[:, 1])

    def residuals(self, params: np.ndarray, obs: _Observations) -> np.ndarray:
        s = self.settings
        relative, _ = heights_from_foot_top(self.camera(params), obs.foot, obs.top)
        pixel_height = obs.foot[:, 1] - obs.top[:, 1]
        valid = np.isfinite(relative) & (relative > 0)
        log_h = np.where(valid, np.log(np.where(valid, relative, 1.0)), 0.0)
        sigma = np.hypot(s.point_noise_px * math.sqrt(2) / pixel_height, s.posture_fraction)
        weight = valid / sigma ** 2
        track_weight = np.bincount(obs.track, weight, obs.n_tracks)
        track_mean = np.bincount(obs.track, weight * log_h, obs.n_tracks) / np.maximum(track_weight, 1e-12)
        # One person keeps one height wherever they walk.
        within = np.where(valid, (log_h - track_mean[obs.track]) / sigma, 10.0)
        # Between people: track means scatter by the population spread (plus their own noise).
        seen = track_weight > 0
        pop = self.prior.std_m / self.prior.mean_m
        between = np.zeros(obs.n_tracks)
        if seen.sum() > 1:
            between[seen] = (track_mean[seen] - track_mean[seen].mean()) / np.sqrt(pop ** 2 + 1.0 / track_weight[seen])
        # People stand upright: heads on the image of their foot's vertical. A person's own lean
        # (and the detector's habit on their shape) persists along the track, so like height it
        # is split into a per-person mean, scattered by the lean spread, and the sway around it.
        lean = self.lateral_px(obs, params) / pixel_height
        lean_sigma = np.hypot(s.point_noise_px * math.sqrt(2) / pixel_height, s.sway_fraction)
        lean_weight = 1.0 / lean_sigma ** 2
        lean_track_weight = np.bincount(obs.track, lean_weight, obs.n_tracks)
        lean_mean = np.bincount(obs.track, lean_weight * lean, obs.n_tracks) / np.maximum(lean_track_weight, 1e-12)
        lean_within = (lean - lean_mean[obs.track]) / lean_sigma
        lean_between = lean_mean / np.sqrt(s.lean_fraction ** 2 + 1.0 / np.maximum(lean_track_weight, 1e-12))
        priors = [params[1] / s.roll_prior_deg, params[2] / s.focal_prior_log_std]
        return np.concatenate([within, between, lean_within, lean_between, priors])

    def cost(self, params, obs) -> float:
        r = self.residuals(np.asarray(params, float), obs)
        return float(np.sum(2.0 * (np.sqrt(1.0 + r * r) - 1.0)))     # soft-L1, as in the fit

    def fit(self, obs: _Observations, start=None) -> tuple[float, float, float]:
        from scipy.optimize import least_squares

        if start is None:
            # Coarse search over pitch (the fit is not convex over the whole range).
            grid = np.arange(1.0, 86.0, 1.0)
            costs = [self.cost((p, 0.0, 0.0), obs) for p in grid]
            start = (float(grid[int(np.argmin(costs))]), 0.0, 0.0)
        if self.settings.fit_focal:
            free, residuals = np.array(start, float), self.residuals
            lower, upper, scale = [0.1, -45.0, -2.0], [89.5, 45.0, 2.0], [1.0, 1.0, 0.05]
        else:
            free = np.array(start[:2], float)
            residuals = lambda x, o: self.residuals(np.append(x, 0.0), o)   # noqa: E731
            lower, upper, scale = [0.1, -45.0], [89.5, 45.0], [1.0, 1.0]
        result = least_squares(residuals, np.clip(free, lower, upper), args=(obs,), loss="soft_l1",
                               bounds=(lower, upper), x_scale=scale, diff_step=1e-4)
        x = [float(v) for v in result.x]
        return x[0], x[1], x[2] if len(x) == 3 else 0.0

    def track_relative_heights(self, obs: _Observations, params) -> np.ndarray:
        """Each person's median height over camera height."""
        relative, _ = heights_from_foot_top(self.camera(params), obs.foot, obs.top)
        out = []
        for k in range(obs.n_tracks):
            values = relative[(obs.track == k) & np.isfinite(relative)]
            if values.size:
                out.append(np.median(values))
        return np.array(out)
