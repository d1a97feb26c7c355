"""Appearance randomisation of training images: the generator's look made unreliable.

The generator renders flat-shaded meshes in bright, uniform colours; real footage has texture,
muted clothes, lens blur and compression. A network trained on the renders alone learns the
renders' look along with the shapes (the detection head scores real walkers lower than rendered
ones, and more training on renders made real clips worse three times). Domain randomisation
(Tobin et al. 2017; style augmentation, Jackson et al. 2019) makes the look a nuisance to be
ignored: every cue that only the renders carry is scrambled, while geometry, the labels' source,
is untouched. Only photometric changes are made here, so every label stays valid as it is.

Both frames of a pair get the same draw (the height-consistency loss matches points between
them); only the sensor noise differs between the two frames, as in video.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class AppearanceDraw:
    """One pair's randomisation: each field off at its neutral value."""

    gamma: float = 1.0
    channel_order: tuple[int, int, int] = (0, 1, 2)
    grey: bool = False
    blur_sigma: float = 0.0
    sharpen: float = 0.0
    texture_sigma: float = 0.0
    """Grey levels of a smooth random texture laid over the whole image (renders are flat)."""
    texture_scale: float = 2.0
    noise_sigma: float = 0.0
    rescale: float = 1.0
    """Down- then up-scaling factor (soft footage from a cheap lens or a low bit rate)."""
    jpeg_quality: int = 0


def draw_appearance(rng: np.random.Generator, probability: float) -> AppearanceDraw:
    """With ``probability`` a random mix of the changes (each on by its own chance), else none."""
    if probability <= 0 or rng.random() >= probability:
        return AppearanceDraw()
    order = tuple(int(i) for i in rng.permutation(3)) if rng.random() < 0.3 else (0, 1, 2)
    texture_sigma, texture_scale = ((float(rng.uniform(3.0, 12.0)), float(rng.uniform(1.0, 4.0)))
                                    if rng.random() < 0.5 else (0.0, 2.0))
    return AppearanceDraw(
        gamma=float(np.exp(rng.uniform(np.log(0.6), np.log(1.6)))) if rng.random() < 0.5 else 1.0,
        channel_order=order,  # type: ignore[arg-type]
        grey=bool(rng.random() < 0.15),
        blur_sigma=float(rng.uniform(0.4, 1.4)) if rng.random() < 0.3 else 0.0,
        sharpen=float(rng.uniform(0.3, 1.0)) if rng.random() < 0.2 else 0.0,
        texture_sigma=texture_sigma,
        texture_scale=texture_scale,
        noise_sigma=float(rng.uniform(1.0, 6.0)) if rng.random() < 0.4 else 0.0,
        rescale=float(rng.uniform(0.45, 0.9)) if rng.random() < 0.3 else 1.0,
        jpeg_quality=int(rng.integers(20, 70)) if rng.random() < 0.3 else 0,
    )


def apply_appearance(rgb: np.ndarray, draw: AppearanceDraw, rng: np.random.Generator,
                     texture: np.ndarray | None = None) -> np.ndarray:
    """``rgb`` (HxWx3 uint8) with ``draw`` applied; ``texture`` (HxW float32, unit std) is the
    pair's shared texture (``pair_texture``), ``rng`` draws this frame's sensor noise."""
    if draw == AppearanceDraw():
        return rgb
    h, w = rgb.shape[:2]
    img = rgb[..., list(draw.channel_order)].astype(np.float32)
    if draw.grey:
        img[...] = img.mean(axis=2, keepdims=True)
    if draw.gamma != 1.0:
        img = 255.0 * (img / 255.0) ** draw.gamma
    if draw.texture_sigma > 0 and texture is not None:
        img += draw.texture_sigma * texture[..., None]
    if draw.rescale < 1.0:
        small = (max(1, round(w * draw.rescale)), max(1, round(h * draw.rescale)))
        img = cv2.resize(cv2.resize(img, small, interpolation=cv2.INTER_AREA), (w, h),
                         interpolation=cv2.INTER_LINEAR)
    if draw.blur_sigma > 0:
        img = cv2.GaussianBlur(img, (0, 0), draw.blur_sigma)
    if draw.sharpen > 0:
        img = img + draw.sharpen * (img - cv2.GaussianBlur(img, (0, 0), 1.0))
    if draw.noise_sigma > 0:
        img += rng.normal(0.0, draw.noise_sigma, img.shape).astype(np.float32)
    out = np.clip(img + 0.5, 0, 255).astype(np.uint8)
    if draw.jpeg_quality:
        ok, buf = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, draw.jpeg_quality])
        if ok:
            out = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    return np.ascontiguousarray(out)


def pair_texture(rng: np.random.Generator, draw: AppearanceDraw, width: int, height: int) -> np.ndarray | None:
    """A smooth random field (unit std) of blobs ``texture_scale`` pixels across, or None when
    the draw lays none. Shared by both frames of a pair: a fixed pattern, like the scene's own."""
    if draw.texture_sigma <= 0:
        return None
    cells = (max(2, round(width / draw.texture_scale)), max(2, round(height / draw.texture_scale)))
    field = cv2.resize(rng.standard_normal((cells[1], cells[0])).astype(np.float32), (width, height),
                       interpolation=cv2.INTER_CUBIC)
    return field / max(float(field.std()), 1e-6)
