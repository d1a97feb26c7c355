"""What the output sinks share: per-frame encodings done once, labels and class ids.

The runner can pass one ``FrameEncoder`` to both the rerun and the MCAP sink so each frame
is JPEG-encoded (and its height map downscaled) once, not once per sink.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from core.config import OutputConfig
from core.errors import ConfigError
from core.packets import OBJECT_CLASSES, Frame, FramePacket, HeightCamera, Track

CLASS_COLORS_RGB = {"other": (200, 200, 200), "person": (255, 80, 80),
                    "cyclist": (255, 200, 0), "vehicle": (80, 160, 255)}
"""Box colour per object class, the same in rerun and Foxglove."""
OBJECT_MATCH_RGB = (255, 60, 60)
BACKGROUND_MATCH_RGB = (60, 220, 255)
"""Feature-match colours: on a moving object / on the static background."""
DAMAGE_TOPIC = "/capture/damage"
"""MCAP topic and rerun entity of the damaged-frame log entries."""
NETWORK_SKIPPED_TOPIC = "/capture/network_skipped"
"""MCAP topic and rerun entity of the notes on live frames that reused the last frame's network
outputs (``FramePacket.network_reused``); under /capture so one rerun log view shows both kinds."""
MATCH_KIND_KEY = "kind"
"""Metadata key of each /camera/matches PointsAnnotation in MCAP: 'object' or 'background'."""


RRD_INDEX_CHOICES = ("auto", "on", "off")


def check_output_config(config: OutputConfig) -> None:
    if not 1 <= config.jpeg_quality <= 100:
        raise ConfigError(f"output.jpeg_quality must be 1..100, got {config.jpeg_quality}")
    if config.height_map_scale < 1:
        raise ConfigError(f"output.height_map_scale must be >= 1, got {config.height_map_scale}")
    if config.height_map_every < 1:
        raise ConfigError(f"output.height_map_every must be >= 1, got {config.height_map_every}")
    if config.mcap_chunk_size < 1024:
        raise ConfigError(f"output.mcap_chunk_size must be >= 1024 bytes, got {config.mcap_chunk_size}")
    if config.rrd_index not in RRD_INDEX_CHOICES:
        raise ConfigError(f"output.rrd_index must be one of {', '.join(RRD_INDEX_CHOICES)}, "
                          f"got {config.rrd_index!r}")
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
        the sink; between them, viewers keep showing the last map stored. Never on a frame that
        reused the last frame's network outputs (a live run keeping up): its maps are the last
        frame's.
        """
        return packet.frame.index % self.height_map_every == 0 and not packet.network_reused

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


def damage_text(frame: Frame) -> str:
    return f"frame {frame.index} damaged, heights not measured: {frame.damage}"


def network_skipped_text(frame: Frame) -> str:
    return (f"frame {frame.index}: height network skipped to keep up with the live source, "
            "the last frame's height map and ground mask used, heights not measured")


def confirmed(tracks: list[Track]) -> list[Track]:
    return [track for track in tracks if track.confirmed]


@dataclass(frozen=True)
class SinkConstants:
    """The views' fixed numbers (the rule is in docs/design.md, Configuration)."""

    settled_std_m: float = 0.10
    """A track whose height std is at most this is 'settled' (drawn green); above it 'settling':
    a decimetre is what a calibrated camera reaches on people."""
    label_room_px: tuple[int, int] = (40, 48)
    """A box at least this wide and tall (pixels) has room for the label's second line (id,
    class, source) without hiding the object."""


CONSTANTS = SinkConstants()

QUALITY_RGB = {"settled": (60, 220, 90), "settling": (255, 190, 40), "no height": (170, 170, 170)}
"""Box colour by measurement quality, the same in rerun and Foxglove."""
CAMERA_STATES = {
    "calibration": "calibrated (full pose: a calibration file, or camera height and pitch)",
    "camera-height": "camera height given, no full calibration",
    "self": "self-calibrated (heightpipe calibrate, or read from the first frames told only the camera height): "
            "heights carry its uncertainty",
    "none": "UNCALIBRATED: no camera height or calibration given, an assumed height is used, "
            "heights are indicative only",
}
"""What each ``CameraInfo.source`` means for the heights, in the summary and the view."""
HEIGHT_CAMERA_SOURCES = {
    "calibration": "the calibration file's camera",
    "config": "the [camera] pose",
    "self": "the self-calibrated [camera] pose",
    "heads": "the camera height given",
    "assumed": "an assumed camera height",
}
"""Where a v2 network's decoding camera came from (``HeightCamera.source``)."""


def height_camera_text(camera: HeightCamera, frames: bool = True) -> str:
    """How a v2 network's heights were made metric, for the summary and the view: the camera
    given, or the heads' estimate with their spread (``frames``: say how many frames it averages;
    the view leaves it out so its text changes only when the estimate does)."""
    where = HEIGHT_CAMERA_SOURCES.get(camera.source, camera.source)
    if camera.source not in ("heads", "assumed"):
        pitch, roll = (_degrees(angle) for angle in (camera.pitch_deg, camera.roll_deg))
        return (f"HeightNet v2 metres with {where} (height {camera.height_m:.2f} m, pitch "
                f"{pitch}, roll {roll}, focal {camera.focal_px:.0f} px)")
    text = f"HeightNet v2 metres with {where} ({camera.height_m:.2f} m) and {estimate_text(camera)}"
    return text + (f", mean of {camera.frames} frames" if frames else "")


def estimate_text(camera: HeightCamera) -> str:
    """'pitch, roll, focal length from the network's camera heads and 55 straight lines of the
    scene: pitch 20.5° ±1.3°, ...': a camera the heads estimated, with their spread."""
    focal = (f"focal {camera.focal_px:.0f} px (calibration file)" if camera.focal_given
             else f"focal {camera.focal_px:.0f} px ±{camera.focal_std_pct:.0f}%")
    estimated = "pitch, roll" if camera.focal_given else "pitch, roll, focal length"
    heads = "network's camera heads" + (f" and {lines_text(camera)}" if camera.edges else "")
    return (f"{estimated} from the {heads}: pitch {_degrees(camera.pitch_deg)} ±{camera.pitch_std_deg:.1f}°, "
            f"roll {_degrees(camera.roll_deg)} ±{camera.roll_std_deg:.1f}°, {focal}")


def lines_text(camera: HeightCamera) -> str:
    """'55 straight lines of the scene', saying so when two ground families were taken as square."""
    square = " (two families of ground lines taken to cross at right angles)" if camera.square_families else ""
    return f"{camera.edges} straight lines of the scene{square}"


def _degrees(angle: float) -> str:
    return f"{round(angle, 1) + 0.0:.1f}°"  # + 0.0: no "-0.0"


def camera_state_text(source: str, height_camera: HeightCamera | None = None, frames: bool = True) -> str:
    """The camera line of the summary and the view: the run camera's state, and for a v2 network
    the camera its heights were decoded with."""
    state = CAMERA_STATES.get(source, source)
    return state if height_camera is None else f"{state}; {height_camera_text(height_camera, frames)}"


def height_quality(track: Track) -> str:
    """'settled', 'settling' or 'no height' (its top never inside the frame)."""
    if not np.isfinite(track.height_m):
        return "no height"
    return "settled" if track.height_std_m <= CONSTANTS.settled_std_m else "settling"


def height_text(height_m: float, std_m: float) -> str:
    """'1.72 m ±4 cm'; 'no height' for NaN; the ± part left out when the std is unknown."""
    if not np.isfinite(height_m):
        return "no height"
    if not np.isfinite(std_m):
        return f"{height_m:.2f} m"
    spread = f"{std_m * 100:.0f} cm" if std_m < 0.995 else f"{std_m:.1f} m"
    return f"{height_m:.2f} m \u00b1{spread}"


def track_label(track: Track) -> str:
    """'1.72 m ±4 cm', with '#12 person, geometry' on a second line when the box has room (and
    ', box predicted' or ', box interpolated' where no detection placed it this frame)."""
    text = height_text(track.height_m, track.height_std_m)
    _x, _y, width, height = track.box
    if width >= CONSTANTS.label_room_px[0] and height >= CONSTANTS.label_room_px[1]:
        text += f"\n#{track.track_id} {track.cls}, {track.height_source}"
        if not track.updated:
            text += f", box {track.box_source}"
    return text


def quality_rgb(track: Track) -> tuple[int, int, int]:
    return QUALITY_RGB[height_quality(track)]


def class_id(cls: str) -> int:
    return OBJECT_CLASSES.index(cls) if cls in OBJECT_CLASSES else 0
