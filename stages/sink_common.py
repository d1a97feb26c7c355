"""What the output sinks share: per-frame encodings done once, labels and class ids.

The runner can pass one ``FrameEncoder`` to both the rerun and the MCAP sink so each frame
is JPEG-encoded (and its height map downscaled) once, not once per sink.
"""

from __future__ import annotations

import cv2
import numpy as np

from core.config import OutputConfig
from core.errors import ConfigError
from core.packets import OBJECT_CLASSES, FramePacket, Track

CLASS_COLORS_RGB = {"other": (200, 200, 200), "person": (255, 80, 80),
                    "cyclist": (255, 200, 0), "vehicle": (80, 160, 255)}
"""Box colour per object class, the same in rerun and Foxglove."""
OBJECT_MATCH_RGB = (255, 60, 60)
BACKGROUND_MATCH_RGB = (60, 220, 255)
"""Feature-match colours: on a moving object / on the static background."""
MATCH_KIND_KEY = "kind"
"""Metadata key of each /camera/matches PointsAnnotation in MCAP: 'object' or 'background'."""


def check_output_config(config: OutputConfig) -> None:
    if not 1 <= config.jpeg_quality <= 100:
        raise ConfigError(f"output.jpeg_quality must be 1..100, got {config.jpeg_quality}")
    if config.height_map_scale < 1:
        raise ConfigError(f"output.height_map_scale must be >= 1, got {config.height_map_scale}")
    if config.height_map_every < 1:
        raise ConfigError(f"output.height_map_every must be >= 1, got {config.height_map_every}")
    if config.mcap_chunk_size < 1024:
        raise ConfigError(f"output.mcap_chunk_size must be >= 1024 bytes, got {config.mcap_chunk_size}")
    if config.flush_interval_s < 0:
        raise ConfigError(f"output.flush_interval_s must be >= 0, got {config.flush_interval_s}")


class FrameEncoder:
    """Encodes a packet's frame (JPEG) and height map (uint16 mm, downscaled) once per packet.

    Caches the last result keyed on the identity of the source array, so sinks sharing one
    encoder pay once per frame.
    """

    def __init__(self, jpeg_quality: int, height_map_scale: int, height_map_every: int = 1):
        self.jpeg_params = [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)]
        self.height_map_scale = int(height_map_scale)
        self.height_map_every = max(1, int(height_map_every))
        self._jpeg_source: np.ndarray | None = None
        self._jpeg: bytes = b""
        self._height_source: np.ndarray | None = None
        self._height_mm: np.ndarray | None = None

    @classmethod
    def from_config(cls, config: OutputConfig) -> FrameEncoder:
        return cls(config.jpeg_quality, config.height_map_scale, config.height_map_every)

    def maps_due(self, packet: FramePacket) -> bool:
        """Whether this frame's height map and ground mask are stored (``output.height_map_every``).

        By source index, so a recording's maps fall on the same frames whatever the stride or
        the sink; between them, viewers keep showing the last map stored.
        """
        return packet.frame.index % self.height_map_every == 0

    def jpeg(self, packet: FramePacket) -> bytes:
        image = packet.frame.image
        if image is not self._jpeg_source:
            ok, encoded = cv2.imencode(".jpg", image, self.jpeg_params)
            if not ok:
                raise ValueError(f"JPEG encoding failed for frame {packet.frame.index}")
            self._jpeg, self._jpeg_source = encoded.tobytes(), image
        return self._jpeg

    def height_mm(self, packet: FramePacket) -> np.ndarray | None:
        """Height map in whole millimetres (uint16, NaN and below-ground as 0) at 1/scale size."""
        height_map = packet.height_map
        if height_map is None:
            return None
        if height_map is not self._height_source:
            self._height_mm = height_to_mm(height_map, self.height_map_scale)
            self._height_source = height_map
        return self._height_mm


def height_to_mm(height_m: np.ndarray, scale: int) -> np.ndarray:
    height = np.asarray(height_m, dtype=np.float32)
    if scale > 1:  # before the NaN fix-up: 1/scale^2 of the pixels to touch
        rows, cols = height.shape[:2]
        height = cv2.resize(height, (max(1, cols // scale), max(1, rows // scale)),
                            interpolation=cv2.INTER_AREA)
    millimetres = height * np.float32(1000.0) + np.float32(0.5)
    millimetres[~np.isfinite(millimetres)] = 0.0
    return np.clip(millimetres, 0.0, 65535.0, out=millimetres).astype(np.uint16)


def confirmed(tracks: list[Track]) -> list[Track]:
    return [track for track in tracks if track.confirmed]


def track_label(track: Track) -> str:
    return f"#{track.track_id} {track.height_m:.2f}\u00b1{track.height_std_m:.2f} m"


def class_id(cls: str) -> int:
    return OBJECT_CLASSES.index(cls) if cls in OBJECT_CLASSES else 0
