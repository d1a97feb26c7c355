"""Procedural textures for the synthetic scenes, made with NumPy from a seed.

MuJoCo reads textures as PNG bytes handed in as assets, so nothing is downloaded and the
same seed gives the same bytes. Textures are small (64-256 px) and repeat across the
surface (``texuniform``), which keeps upload and memory cheap; realism comes from varying
colours, noise and patterns widely between scenes rather than from detail.
"""

from __future__ import annotations

import numpy as np

TEXTURE_KINDS = ("asphalt", "paving", "slabs", "grass", "concrete", "facade", "brick", "gravel")


def _smooth_noise(rng: np.random.Generator, size: int, cells: int) -> np.ndarray:
    """Tileable value noise in [0, 1]: a random grid upsampled with wrap-around."""
    import cv2

    grid = rng.random((cells, cells)).astype(np.float32)
    tiled = np.tile(grid, (3, 3))
    big = cv2.resize(tiled, (3 * size, 3 * size), interpolation=cv2.INTER_CUBIC)
    return np.clip(big[size:2 * size, size:2 * size], 0.0, 1.0)


def _fractal(rng: np.random.Generator, size: int) -> np.ndarray:
    total = np.zeros((size, size), np.float32)
    weight = 0.0
    for octave, cells in enumerate((4, 8, 16, 32)):
        w = 0.55 ** octave
        total += w * _smooth_noise(rng, size, cells)
        weight += w
    fine = rng.random((size, size)).astype(np.float32)
    return 0.85 * total / weight + 0.15 * fine


def _colour(base: np.ndarray, shade: np.ndarray) -> np.ndarray:
    """base (3,) in [0,1] modulated by shade (H,W) around 1 -> uint8 image."""
    img = base[None, None, :] * shade[..., None]
    return np.clip(img * 255.0, 0, 255).astype(np.uint8)


def make_texture(kind: str, rng: np.random.Generator, size: int = 128) -> np.ndarray:
    """An RGB uint8 image of one texture kind with randomised colour and pattern."""
    noise = _fractal(rng, size)
    if kind == "asphalt":
        grey = rng.uniform(0.22, 0.42)
        base = np.array([grey, grey, grey * rng.uniform(0.97, 1.06)])
        shade = 0.8 + 0.4 * noise
        speckle = rng.random((size, size)) < 0.03
        shade = np.where(speckle, shade * rng.uniform(1.2, 1.5), shade)
        return _colour(base, shade)
    if kind in ("paving", "slabs", "brick"):
        if kind == "paving":
            tiles, mortar = int(rng.integers(4, 9)), 0.06
        elif kind == "slabs":
            tiles, mortar = int(rng.integers(2, 4)), 0.03
        else:
            tiles, mortar = int(rng.integers(6, 10)), 0.08
        hue = rng.uniform(0.35, 0.75)
        base = np.array([hue * rng.uniform(0.95, 1.25), hue, hue * rng.uniform(0.8, 1.05)])
        if kind == "brick":
            base = np.array([rng.uniform(0.45, 0.65), rng.uniform(0.22, 0.35), rng.uniform(0.15, 0.25)])
        y, x = np.mgrid[0:size, 0:size] / size * tiles
        rows = np.floor(y).astype(int)
        x = x + 0.5 * (rows % 2) * (kind != "slabs")
        fx, fy = x % 1.0, y % 1.0
        joint = (fx < mortar) | (fy < mortar * (1.6 if kind == "brick" else 1.0))
        tile_id = (rows * 31 + np.floor(x).astype(int) * 17) % 97
        tile_shade = 0.85 + 0.3 * ((tile_id * 0.6180339) % 1.0)
        shade = tile_shade * (0.85 + 0.3 * noise)
        shade = np.where(joint, 0.55 + 0.1 * noise, shade)
        return _colour(base, shade)
    if kind == "grass":
        base = np.array([rng.uniform(0.18, 0.35), rng.uniform(0.35, 0.55), rng.uniform(0.10, 0.22)])
        blades = rng.random((size, size)).astype(np.float32)
        shade = 0.7 + 0.35 * noise + 0.25 * blades
        return _colour(base, shade)
    if kind == "gravel":
        grey = rng.uniform(0.45, 0.65)
        base = np.array([grey, grey * 0.95, grey * 0.85])
        stones = rng.random((size, size)).astype(np.float32)
        return _colour(base, 0.7 + 0.25 * noise + 0.3 * stones)
    if kind == "concrete":
        grey = rng.uniform(0.5, 0.78)
        base = np.array([grey, grey * rng.uniform(0.96, 1.0), grey * rng.uniform(0.9, 1.0)])
        return _colour(base, 0.88 + 0.22 * noise)
    if kind == "facade":
        wall = np.array([rng.uniform(0.45, 0.9), rng.uniform(0.4, 0.85), rng.uniform(0.35, 0.8)])
        glass = np.array([rng.uniform(0.1, 0.3), rng.uniform(0.15, 0.35), rng.uniform(0.2, 0.45)])
        y, x = np.mgrid[0:size, 0:size] / size
        win_w, win_h = rng.uniform(0.45, 0.75), rng.uniform(0.45, 0.7)
        window = (np.abs(x - 0.5) < win_w / 2) & (np.abs(y - 0.55) < win_h / 2)
        img = np.where(window[..., None], glass[None, None, :] * (0.8 + 0.5 * noise[..., None]),
                       wall[None, None, :] * (0.85 + 0.25 * noise[..., None]))
        return np.clip(img * 255, 0, 255).astype(np.uint8)
    raise ValueError(f"unknown texture kind {kind!r}")


def png_bytes(image: np.ndarray) -> bytes:
    import cv2

    ok, buffer = cv2.imencode(".png", image[..., ::-1])
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return buffer.tobytes()
