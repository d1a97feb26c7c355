"""Ways footage gets damaged, as byte operations on a video file, and the clean decode to judge by.

Used by the capture tests and by ``tests/damage_corpus.py`` (the corpus and its table).
Each operation takes the file's bytes and returns the damaged bytes; all are deterministic.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


def truncate(data: bytes, keep: float) -> bytes:
    """A recording cut off (power loss, full disk): the first ``keep`` share of the bytes."""
    return data[:int(len(data) * keep)]


def delete_bytes(data: bytes, count: int, seed: int) -> bytes:
    """``count`` single bytes deleted at random places in the middle 80 % (a bad sector read)."""
    rng = np.random.default_rng(seed)
    drop = sorted(set(rng.integers(len(data) // 10, len(data) * 9 // 10, count).tolist()))
    return b"".join(data[start:end] for start, end in _keep_ranges(len(data), drop))


def _keep_ranges(size: int, drop: list[int]):
    start = 0
    for position in drop:
        yield start, position
        start = position + 1
    yield start, size


def zero_header(data: bytes, count: int = 4) -> bytes:
    """The first ``count`` bytes zeroed (a header overwritten)."""
    return bytes(count) + data[count:]


def flip_bits(data: bytes, count: int, seed: int, low: float = 0.1, high: float = 0.9) -> bytes:
    """``count`` random single-bit flips between ``low`` and ``high`` of the file (bit rot)."""
    rng = np.random.default_rng(seed)
    damaged = bytearray(data)
    for position in rng.integers(int(len(data) * low), int(len(data) * high), count):
        damaged[position] ^= 1 << int(rng.integers(8))
    return bytes(damaged)


def decode_all(path: Path) -> dict[int, np.ndarray]:
    """Frame index -> image as heightpipe's capture reads it (damage ignored)."""
    from core.config import CaptureConfig
    from stages.capture import open_source

    source = open_source(str(path), CaptureConfig())
    try:
        return {frame.index: frame.image for frame in source.frames()}
    finally:
        source.close()


def damaged_against(clean: dict[int, np.ndarray], frames: dict[int, np.ndarray]) -> set[int]:
    """Indices whose picture differs from the clean decode, or that the clean decode lacks."""
    return {index for index, image in frames.items()
            if index not in clean or clean[index].shape != image.shape
            or not np.array_equal(clean[index], image)}
