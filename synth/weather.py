"""Time of day, weather and the camera's image defects.

Lighting and fog are rendered by MuJoCo; rain streaks, sensor noise, blur and JPEG artefacts
are post effects on the RGB image only (depth, segmentation and heights stay exact).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

TIMES_OF_DAY = ("day", "low_sun", "dusk", "night")
WEATHERS = ("clear", "overcast", "fog", "rain")


@dataclass
class Environment:
    time_of_day: str
    weather: str
    sun_elevation_deg: float
    sun_azimuth_deg: float
    sun_rgb: tuple[float, float, float]
    ambient_rgb: tuple[float, float, float]
    shadows: bool
    sky_top: tuple[float, float, float]
    sky_horizon: tuple[float, float, float]
    fog_start_m: float  # 0 = no fog
    fog_end_m: float
    fog_rgb: tuple[float, float, float]
    lamps_on: bool
    lamp_rgb: tuple[float, float, float]
    # post effects
    rain_streaks: int
    noise_sigma: float  # in 8-bit levels
    blur_sigma: float  # pixels
    jpeg_quality: int  # 0 = no extra JPEG round trip
    exposure: float

    def to_json(self) -> dict:
        return asdict(self)


def sample_environment(rng: np.random.Generator, time_of_day: str | None = None,
                       weather: str | None = None, shadows: bool = True) -> Environment:
    tod = time_of_day or str(rng.choice(TIMES_OF_DAY, p=[0.45, 0.25, 0.15, 0.15]))
    wx = weather or str(rng.choice(WEATHERS, p=[0.5, 0.2, 0.15, 0.15]))
    azimuth = float(rng.uniform(0, 360))
    if tod == "day":
        elevation, sun, amb = rng.uniform(35, 75), np.array([1.0, 0.97, 0.9]) * rng.uniform(0.6, 0.8), 0.35
        sky_top, sky_hor = np.array([0.35, 0.55, 0.85]), np.array([0.75, 0.85, 0.95])
    elif tod == "low_sun":
        elevation, sun, amb = rng.uniform(8, 25), np.array([1.0, 0.8, 0.6]) * rng.uniform(0.6, 0.8), 0.3
        sky_top, sky_hor = np.array([0.3, 0.45, 0.75]), np.array([0.95, 0.75, 0.55])
    elif tod == "dusk":
        elevation, sun, amb = rng.uniform(2, 8), np.array([0.8, 0.5, 0.4]) * rng.uniform(0.2, 0.35), 0.2
        sky_top, sky_hor = np.array([0.12, 0.14, 0.3]), np.array([0.6, 0.4, 0.35])
    else:  # night: a dim moon, lamps do most of the work
        elevation, sun, amb = rng.uniform(20, 60), np.array([0.5, 0.55, 0.7]) * rng.uniform(0.08, 0.15), 0.1
        sky_top, sky_hor = np.array([0.01, 0.01, 0.03]), np.array([0.05, 0.05, 0.08])
    ambient = np.array([1.0, 1.0, 1.0]) * amb * rng.uniform(0.85, 1.15)
    cast = shadows and tod in ("day", "low_sun")
    fog_start = fog_end = 0.0
    fog_rgb = sky_hor
    if wx in ("overcast", "rain"):
        sun = sun * 0.35
        ambient = ambient * (1.6 if tod in ("day", "low_sun") else 1.2)
        grey = float(np.mean(sky_hor)) * (0.8 if wx == "rain" else 0.95)
        sky_top = sky_hor = np.array([grey, grey, grey * 1.03])
        cast = False
    if wx == "fog":
        fog_start = float(rng.uniform(2, 15))
        fog_end = float(rng.uniform(40, 120))
        fog_rgb = np.clip(sky_hor * 0.8 + 0.15, 0, 1) if tod != "night" else np.array([0.08, 0.08, 0.1])
        sky_top = sky_hor = fog_rgb
        sun = sun * 0.6
        cast = cast and rng.random() < 0.3
    elif wx == "rain":
        fog_start, fog_end = float(rng.uniform(20, 40)), float(rng.uniform(150, 300))
        fog_rgb = sky_hor
    night = tod in ("dusk", "night")
    return Environment(
        time_of_day=tod, weather=wx, sun_elevation_deg=float(elevation), sun_azimuth_deg=azimuth,
        sun_rgb=tuple(np.clip(sun, 0, 1).tolist()), ambient_rgb=tuple(np.clip(ambient, 0, 1).tolist()),
        shadows=bool(cast), sky_top=tuple(sky_top.tolist()), sky_horizon=tuple(sky_hor.tolist()),
        fog_start_m=fog_start, fog_end_m=fog_end, fog_rgb=tuple(np.asarray(fog_rgb).tolist()),
        lamps_on=night, lamp_rgb=tuple((np.array([1.0, 0.85, 0.6]) * rng.uniform(0.7, 1.0)).tolist()),
        rain_streaks=int(rng.integers(80, 350)) if wx == "rain" else 0,
        noise_sigma=float(rng.uniform(0.5, 3.0) * (2.5 if night else 1.0)),
        blur_sigma=float(rng.uniform(0.0, 0.9)),
        jpeg_quality=int(rng.integers(35, 85)) if rng.random() < 0.4 else 0,
        exposure=float(rng.uniform(0.9, 1.15)))


def sun_direction(env: Environment) -> np.ndarray:
    """Unit vector the sunlight travels along (pointing down)."""
    el, az = math.radians(env.sun_elevation_deg), math.radians(env.sun_azimuth_deg)
    return -np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])


def apply_post_effects(rgb: np.ndarray, env: Environment, rng: np.random.Generator) -> np.ndarray:
    """Rain streaks, exposure, blur, sensor noise and JPEG artefacts on an RGB uint8 image."""
    import cv2

    img = rgb.astype(np.float32)
    h, w = img.shape[:2]
    if env.rain_streaks:
        layer = np.zeros((h, w), np.float32)
        n = int(env.rain_streaks * w * h / (320 * 240))
        x0 = rng.uniform(0, w, n)
        y0 = rng.uniform(0, h, n)
        length = rng.uniform(0.03, 0.08, n) * h
        slant = rng.normal(0.15, 0.05)
        for x, y, length_px in zip(x0, y0, length):
            cv2.line(layer, (int(x), int(y)), (int(x + slant * length_px), int(y + length_px)), 1.0, 1)
        layer = cv2.GaussianBlur(layer, (3, 3), 0.7)
        img = img * 0.92 + layer[..., None] * 55.0
    # Automatic gain, as CCTV cameras do at dusk and night: dark frames are brightened and
    # their noise amplified with them.
    gain = float(np.clip(75.0 / max(float(img.mean()), 1.0), 1.0, 4.0)) * env.exposure
    img *= gain
    if env.blur_sigma > 0.3:
        img = cv2.GaussianBlur(img, (0, 0), env.blur_sigma)
    if env.noise_sigma > 0:
        img += rng.normal(0.0, env.noise_sigma * max(1.0, gain), img.shape).astype(np.float32)
    out = np.clip(img + 0.5, 0, 255).astype(np.uint8)
    if env.jpeg_quality:
        ok, buf = cv2.imencode(".jpg", out[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, env.jpeg_quality])
        out = cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1].copy()
    return out
