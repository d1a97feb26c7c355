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

The focal length can be estimated from the second cue (``FitSettings.use_lean``: head-foot
lines converge on the vertical vanishing point, f / tan(pitch) below the image centre), but that
needs head points independent of foot points and was misled by real annotations, so by default
it is taken from the intrinsic calibration or assumed from the field of view, and then the
assumption's effect (refits at +- ``assumed_fov_std_deg``) is part of the uncertainty.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from core.errors import HeightpipeError
from core.packets import CameraInfo, Track
from stages.calibration import (camera_from_pose, fov_from_focal, heights_from_foot_top, horizon_line,
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
    """Noise model and robustness settings of the fit."""

    point_noise_px: float = 20.0
    """Std of detected head and foot points: box tops and bottoms of tracked people on Oxford Town
    Centre lie ~20 px from the labelled head-top and foot points (median 23 px, 2-D). At 2 px
    every box wobble was a contradiction, and the fit kept 5 of 11 people and a 23 deg roll."""
    posture_fraction: float = 0.03
    """Frame-to-frame variation of one person's measured height (gait, posture), relative."""
    lean_fraction: float = 0.05
    """Spread between people of the head's sideways offset from the foot's vertical, relative to
    the person's image height (lean, carried bags, how the detector boxes them)."""
    sway_fraction: float = 0.02
    """Frame-to-frame variation of that offset along one track."""
    use_lean: bool = False
    """Use the upright-people cue (and estimate the focal length from it). Off by default: on
    the Oxford Town Centre annotations (head-box and body-box centres) it pulled the focal
    length to 4260 px against the calibrated 2696 px, and box-based points (top and foot in
    the box's centre column, as the object extractor gives) carry no such cue at all."""
    roll_prior_deg: float = 10.0
    """CCTV cameras are mounted nearly level: a weak prior keeps roll sane with little data."""
    fit_focal: bool = True
    """Estimate the focal length where upright-people cues allow (and K is not calibrated)."""
    assumed_fov_std_deg: float = 15.0
    """How wrong an assumed field of view may be (CCTV lenses span about 30 to 90 degrees)."""
    focal_prior_log_std: float = 0.5
    """Weak log-normal prior of the focal length around K's."""
    min_pixel_height: float = 20.0
    """People smaller than this in the image are too coarse to use."""
    outlier_sigmas: float = 2.5
    """A track whose height is further than this many crowd spreads from the median is not a person."""
    max_track_scatter: float = 0.15
    """A track whose height varies more than this (relative, robust std) is not one whole person."""
    min_tracks: int = 5
    min_agreeing_fraction: float = 0.4
    """Refuse when fewer of the tracked upright objects than this agree on one height: then the
    few that agree are as likely to be matching parts of people as people (a confident wrong
    camera is worse than none)."""
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
    focal_source: str
    """'given' (intrinsic calibration), 'estimated' (from upright people) or 'assumed' (fov)."""
    focal_std_px: float
    height_m: float
    height_std_m: float
    pitch_deg: float
    pitch_std_deg: float
    roll_deg: float
    roll_std_deg: float
    n_observations: int
    n_tracks: int
    prior: HeightPrior
    person_height_spread_m: float = 0.0
    """Std of the per-person heights with the fitted camera (the prior's std if people vary)."""
    lean_residual_px: float = math.nan
    """Median sideways distance of heads from their foot's vertical (NaN: cue not used)."""
    notes: list[str] = field(default_factory=list)

    def camera(self) -> CameraInfo:
        return camera_from_pose(self.width, self.height, self.K, self.height_m, self.pitch_deg,
                                self.roll_deg, source="self")

    def horizon(self) -> np.ndarray:
        return horizon_line(self.camera())

    def config_snippet(self, calibration: str = "") -> str:
        """``[camera]`` lines for config.toml that reproduce this camera."""
        focal = self.K[0, 0]
        fov = fov_from_focal(self.width, focal)
        lines = [
            "[camera]",
            f"height_m = {self.height_m:.2f}            # self-calibrated: +- {self.height_std_m:.2f} m "
            f"({self.n_tracks} people, prior {self.prior.mean_m:.2f} +- {self.prior.std_m:.2f} m)",
            f"height_std_m = {self.height_std_m:.2f}",
            f"pitch_deg = {self.pitch_deg:.2f}",
            f"pitch_std_deg = {self.pitch_std_deg:.2f}",
            f"roll_deg = {self.roll_deg:.2f}",
            f"roll_std_deg = {self.roll_std_deg:.2f}",
        ]
        if calibration:
            lines.append(f"calibration = {toml_string(calibration)}   # intrinsics (its pose is not used)")
        elif self.focal_source == "estimated":
            fov_std = math.degrees(self.width * self.focal_std_px / (focal ** 2 + (self.width / 2) ** 2))
            lines.append(f"fov_deg = {fov:.1f}             # +- {fov_std:.1f} (focal {focal:.0f} px, estimated)")
            lines.append(f"focal_std_pct = {100.0 * self.focal_std_px / focal:.1f}")
        else:
            lines.append(f"fov_deg = {fov:.1f}             # assumed, not estimated (focal {focal:.0f} px)")
        lines.append("self_calibrated = true")
        lines += [f"# note: {note}" for note in self.notes]
        return "\n".join(lines)


def toml_string(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def self_calibrate(foot_uv: np.ndarray, top_uv: np.ndarray, track_ids: np.ndarray,
                   width: int, height: int, K: np.ndarray, focal_known: bool = False,
                   prior: HeightPrior | None = None, settings: FitSettings | None = None) -> SelfCalibration:
    """Camera pose from head (top) and foot points of pedestrians, in undistorted pixels of K.

    ``track_ids`` groups observations of one person; give every observation its own id when
    there is no tracking (then only the population spread ties them together). ``focal_known``:
    K comes from a calibration; otherwise its focal length is estimated where the data allows,
    or else assumed, and the assumption's effect is part of the uncertainty.
    """
    prior = prior or HeightPrior()
    settings = settings or FitSettings()
    observations = _Observations.select(foot_uv, top_uv, track_ids, settings)
    if observations.n_tracks < settings.min_tracks or len(observations) < settings.min_observations:
        raise SelfCalibrationError(
            f"self-calibration needs at least {settings.min_tracks} people and "
            f"{settings.min_observations} head/foot observations, got {observations.n_tracks} and "
            f"{len(observations)}")
    # Points from boxes (top and foot at the box's centre column) say nothing about verticals.
    use_lean = settings.use_lean and bool(
        np.mean(np.abs(observations.top[:, 0] - observations.foot[:, 0]) > 0.25) > 0.5)
    fit_focal = settings.fit_focal and use_lean and not focal_known
    K = np.asarray(K, float)
    problem = _Problem(width, height, K, prior, settings, use_lean, fit_focal)

    # Not every upright blob is a whole person (heads, legs, bags, two people merged): fit, keep
    # the tracks whose heights agree with the crowd's, refit, until the set stops changing.
    all_tracks = observations.n_tracks
    params = problem.fit(observations)
    people = np.ones(all_tracks, bool)
    for _ in range(4):
        agreeing = problem.agreeing_tracks(observations, params)
        if np.array_equal(agreeing, people):
            break
        people = agreeing
        if people.sum() < max(settings.min_tracks, settings.min_agreeing_fraction * all_tracks):
            raise SelfCalibrationError(
                f"only {people.sum()} of {all_tracks} tracked upright objects look like people of one "
                f"height: too few to self-calibrate (at least {settings.min_tracks} and "
                f"{settings.min_agreeing_fraction:.0%}); a longer video with more people may do")
        params = problem.fit(observations.subset_tracks(people), start=params)
    observations = observations.subset_tracks(people)
    camera_height = problem.camera_height(observations, params)

    # Bootstrap over people: refit on resampled tracks, starting from the solution.
    rng = np.random.default_rng(settings.seed)
    samples = []
    for _ in range(settings.bootstrap):
        resampled = observations.resample_tracks(rng)
        fitted = problem.fit(resampled, start=params)
        samples.append((*fitted, problem.camera_height(resampled, fitted)))
    if len(samples) > 1:
        pitch_std, roll_std, log_focal_std, height_boot_std = np.std(samples, axis=0, ddof=1)
    else:
        pitch_std = roll_std = log_focal_std = height_boot_std = math.nan

    # Camera height: people's spread over the number of people (at least), and the prior's mean.
    spread_std = camera_height * prior.std_m / prior.mean_m / math.sqrt(observations.n_tracks)
    mean_std = camera_height * prior.mean_std_m / prior.mean_m
    height_std = math.hypot(np.fmax(height_boot_std, spread_std), mean_std)

    focal_source = "given" if focal_known else ("estimated" if fit_focal else "assumed")
    notes = []
    if observations.n_tracks < all_tracks:
        notes.append(f"{all_tracks - observations.n_tracks} of {all_tracks} tracked upright objects "
                     "left out: their heights disagree with the crowd's (not whole people)")
    if pitch_std > 3.0:
        notes.append(f"pitch is poorly determined (+- {pitch_std:.1f} deg): people should be seen "
                     "over a wider range of distances")
    if focal_source == "assumed":
        # Refit with the field of view one assumed std either side: pitch and camera height trade
        # against the focal length, so its ignorance is part of their uncertainty.
        fov = fov_from_focal(width, K[0, 0])
        refits = []
        for sign in (-1.0, 1.0):
            other_fov = float(np.clip(fov + sign * settings.assumed_fov_std_deg, 5.0, 150.0))
            other_K = K.copy()
            other_K[0, 0] = other_K[1, 1] = width / 2 / math.tan(math.radians(other_fov) / 2)
            other = _Problem(width, height, other_K, prior, settings, use_lean, False)
            other_params = other.fit(observations)
            refits.append((other_params[0], other.camera_height(observations, other_params)))
        focal_pitch_std = abs(refits[1][0] - refits[0][0]) / 2
        focal_height_std = abs(refits[1][1] - refits[0][1]) / 2
        pitch_std = math.hypot(pitch_std, focal_pitch_std)
        height_std = math.hypot(height_std, focal_height_std)
        notes.append(f"field of view assumed ({fov:.0f} +- {settings.assumed_fov_std_deg:.0f} deg): "
                     f"+- {focal_height_std:.2f} m of the camera height's uncertainty; give --fov or "
                     "an intrinsic calibration to remove it")

    if height_std > 0.2 * camera_height:
        notes.append(f"the camera height is uncertain by {100 * height_std / camera_height:.0f} %: "
                     "use a longer video with more people walking over a wider range of distances")
    pitch, roll, _ = params
    K_fit = problem.intrinsics(params)
    relative = problem.track_relative_heights(observations, params)
    result = SelfCalibration(
        width=width, height=height, K=K_fit, focal_source=focal_source,
        focal_std_px=float(K_fit[0, 0] * log_focal_std) if fit_focal else 0.0,
        height_m=camera_height, height_std_m=float(height_std),
        pitch_deg=pitch, pitch_std_deg=float(pitch_std), roll_deg=roll, roll_std_deg=float(roll_std),
        n_observations=len(observations), n_tracks=observations.n_tracks, prior=prior,
        person_height_spread_m=float(np.std(relative * camera_height)),
        lean_residual_px=float(np.median(np.abs(problem.lateral_px(observations, params)))) if use_lean else math.nan,
        notes=notes,
    )
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

    def subset_tracks(self, keep: np.ndarray) -> "_Observations":
        """Only the observations of tracks with ``keep[track]`` (renumbered)."""
        mask = keep[self.track]
        renumber = np.cumsum(keep) - 1
        return _Observations(self.foot[mask], self.top[mask], renumber[self.track[mask]], int(keep.sum()))

    def resample_tracks(self, rng: np.random.Generator) -> "_Observations":
        chosen = rng.integers(0, self.n_tracks, self.n_tracks)
        parts = [np.flatnonzero(self.track == k) for k in chosen]
        index = np.concatenate(parts)
        track = np.concatenate([np.full(len(p), i) for i, p in enumerate(parts)])
        return _Observations(self.foot[index], self.top[index], track, self.n_tracks)


class _Problem:
    """Residuals of candidate parameters (pitch deg, roll deg, log focal scale), unit camera height."""

    def __init__(self, width: int, height: int, K: np.ndarray, prior: HeightPrior, settings: FitSettings,
                 use_lean: bool, fit_focal: bool):
        self.width, self.height, self.K = width, height, K
        self.prior, self.settings = prior, settings
        self.use_lean, self.fit_focal = use_lean, fit_focal

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
        priors = [params[1] / s.roll_prior_deg, params[2] / s.focal_prior_log_std]
        # One person keeps one height wherever they walk.
        within = np.where(valid, (log_h - track_mean[obs.track]) / sigma, 10.0)
        # Between people: track means scatter by the population spread (plus their own noise).
        seen = track_weight > 0
        pop = self.prior.std_m / self.prior.mean_m
        between = np.zeros(obs.n_tracks)
        if seen.sum() > 1:
            centre = np.median(track_mean[seen])     # robust to the odd blob that is not a person
            between[seen] = (track_mean[seen] - centre) / np.sqrt(pop ** 2 + 1.0 / track_weight[seen])
        if not self.use_lean:
            return np.concatenate([within, between, priors])
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
        return np.concatenate([within, between, lean_within, lean_between, priors])

    def coarse_search(self, obs: _Observations) -> tuple[float, float, float]:
        """Best (pitch, roll) on a grid under a redescending loss (the fit is not convex, and
        blobs that are not people must not pull the start)."""
        best, best_cost = (10.0, 0.0, 0.0), math.inf
        pop = math.hypot(self.prior.std_m / self.prior.mean_m, self.settings.posture_fraction)
        for pitch in np.arange(1.0, 86.0, 2.0):
            for roll in np.arange(-15.0, 15.5, 3.0):
                cost = self._robust_cost(obs, (pitch, roll, 0.0), pop)
                if cost < best_cost:
                    best, best_cost = (float(pitch), float(roll), 0.0), cost
        return best

    def _robust_cost(self, obs: _Observations, params, pop: float) -> float:
        relative, _ = heights_from_foot_top(self.camera(params), obs.foot, obs.top)
        valid = np.isfinite(relative) & (relative > 0)
        if valid.sum() < 0.5 * len(obs):
            return math.inf
        log_h = np.log(np.where(valid, relative, 1.0))
        counts = np.bincount(obs.track, valid, obs.n_tracks)
        means = np.bincount(obs.track, valid * log_h, obs.n_tracks) / np.maximum(counts, 1)
        # A point above the horizon costs as much as the worst outlier.
        worst = math.log1p(100.0)
        within = np.where(valid, np.log1p(((log_h - means[obs.track]) / self.settings.posture_fraction) ** 2), worst)
        cost = np.sum(within) / len(obs) * obs.n_tracks
        seen = means[counts > 0]
        between = (seen[:, None] - seen[None, :]) / pop          # every track as the crowd's centre
        cost += np.min(np.sum(np.log1p(between ** 2), axis=0)) + worst * (obs.n_tracks - seen.size)
        return float(cost + (params[1] / self.settings.roll_prior_deg) ** 2)

    def cost(self, params, obs) -> float:
        r = self.residuals(np.asarray(params, float), obs)
        return float(np.sum(2.0 * (np.sqrt(1.0 + r * r) - 1.0)))     # soft-L1, as in the fit

    def fit(self, obs: _Observations, start=None) -> tuple[float, float, float]:
        from scipy.optimize import least_squares

        if start is None:
            start = self.coarse_search(obs)
        if self.fit_focal:
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

    def agreeing_tracks(self, obs: _Observations, params) -> np.ndarray:
        """Tracks whose median relative height is within the crowd's spread of the median,
        and steady along the track (bool per track)."""
        relative, _ = heights_from_foot_top(self.camera(params), obs.foot, obs.top)
        log_h = np.log(np.where(np.isfinite(relative) & (relative > 0), relative, np.nan))
        medians = np.full(obs.n_tracks, np.nan)
        scatter = np.full(obs.n_tracks, np.inf)
        for k in range(obs.n_tracks):
            values = log_h[obs.track == k]
            values = values[np.isfinite(values)]
            if values.size:
                medians[k] = np.median(values)
                scatter[k] = 1.4826 * np.median(np.abs(values - medians[k]))
        tolerance = self.settings.outlier_sigmas * np.hypot(self.prior.std_m / self.prior.mean_m,
                                                             self.settings.posture_fraction)
        steady = np.isfinite(medians) & (scatter < self.settings.max_track_scatter)
        if not steady.any():
            return steady
        # The crowd is the largest group of steady tracks of one height (the mode, not the
        # median: half the blobs may be parts of people).
        candidates = medians[steady]
        support = np.sum(np.abs(candidates[:, None] - candidates[None, :]) < tolerance, axis=0)
        centre = np.median(candidates[np.abs(candidates - candidates[np.argmax(support)]) < tolerance])
        with np.errstate(invalid="ignore"):
            return steady & (np.abs(medians - centre) < tolerance)

    def camera_height(self, obs: _Observations, params) -> float:
        """The camera height that makes the mean person as tall as the prior's mean."""
        return self.prior.mean_m / float(np.mean(self.track_relative_heights(obs, params)))

    def track_relative_heights(self, obs: _Observations, params) -> np.ndarray:
        """Each person's median height over camera height."""
        relative, _ = heights_from_foot_top(self.camera(params), obs.foot, obs.top)
        out = []
        for k in range(obs.n_tracks):
            values = relative[(obs.track == k) & np.isfinite(relative)]
            if values.size:
                out.append(np.median(values))
        return np.array(out)


class HeadFootCollector:
    """Gathers head (top) and foot points of upright tracked objects, frame by frame.

    People are chosen by shape, not by the tracker's class: without a camera height the
    network's metres (and so its person/vehicle classes) are not known yet. An upright blob
    (taller than wide) that a confirmed track follows, clear of the image border, counts.
    """

    def __init__(self, width: int, height: int, border_px: float = 2.0,
                 aspect_range: tuple[float, float] = (0.15, 0.7)):
        self.width, self.height = width, height
        self.border_px = border_px
        self.aspect_range = aspect_range
        self._points: dict[int, list[tuple[float, float, float, float]]] = {}

    def add(self, tracks: list[Track]) -> None:
        for track in tracks:
            if not (track.confirmed and track.updated) or track.cls == "vehicle":
                continue
            x, y, w, h = track.box
            if h <= 0 or not self.aspect_range[0] <= w / h <= self.aspect_range[1]:
                continue
            if (x < self.border_px or y < self.border_px or x + w > self.width - self.border_px
                    or y + h > self.height - self.border_px):
                continue
            centre = x + w / 2.0
            self._points.setdefault(track.track_id, []).append((centre, y + h, centre, y))

    def arrays(self, min_frames: int = 5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(foot N x 2, top N x 2, track ids N) of tracks seen upright in at least ``min_frames`` frames."""
        rows, ids = [], []
        for track_id, points in self._points.items():
            if len(points) >= min_frames:
                rows += points
                ids += [track_id] * len(points)
        data = np.array(rows, dtype=float).reshape(-1, 4)
        return data[:, :2], data[:, 2:], np.array(ids, dtype=int)

    @property
    def n_tracks(self) -> int:
        return len(self._points)
