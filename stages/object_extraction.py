"""Object extraction on a fixed camera: moving, above-ground blobs become ``Detection`` s.

Two cues, each covering the other's failure:

* background subtraction finds what moves, but also moving shadows, lighting changes and the
  "ghost" a parked object leaves when it drives off;
* the height map finds what stands above the ground, but also buildings, poles and trees.

A pixel belongs to an object candidate when it is foreground *and* above the ground (and not
on the ground mask). Without a height map the foreground alone is used; with ``background =
"none"`` the height map alone. The work is done on a downscaled frame (``work_width``) so the
stage costs a few milliseconds; boxes and heights are measured back in source pixels.
"""

from __future__ import annotations

import time

import cv2
import numpy as np

from pipeline.config import GroundConfig, TrackingConfig
from pipeline.errors import ConfigError
from pipeline.packets import Detection, FramePacket

BACKGROUND_METHODS = ("mog2", "cnt", "knn", "gsoc", "none")

# MOG2/KNN mark shadows as 127 in the foreground mask; only 255 is a moving object.
_FOREGROUND_VALUE = 255


def make_background_subtractor(method: str):
    """OpenCV background subtractor by name (None for 'none')."""
    if method == "mog2":
        return cv2.createBackgroundSubtractorMOG2(history=500, varThreshold=16, detectShadows=True)
    if method == "knn":
        return cv2.createBackgroundSubtractorKNN(history=500, dist2Threshold=400.0, detectShadows=True)
    if method == "cnt":
        # CNT absorbs stopped objects quickly; a longer max stability keeps slow walkers.
        return cv2.bgsegm.createBackgroundSubtractorCNT(minPixelStability=15, useHistory=True,
                                                        maxPixelStability=15 * 60, isParallel=False)
    if method == "gsoc":
        return cv2.bgsegm.createBackgroundSubtractorGSOC()
    if method == "none":
        return None
    raise ConfigError(f"tracking.background must be one of {', '.join(BACKGROUND_METHODS)}, "
                      f"got {method!r}")


def coarse_class(height_m: float, box_w_px: float, box_h_px: float) -> str:
    """Person / cyclist / vehicle / other from the object's height and its image shape.

    The metric width is estimated as box width times the metres per pixel implied by the
    height (exact for a side view, an underestimate when the camera looks down on a long
    footprint). Crude on purpose: the tracker votes over many frames.
    """
    if not np.isfinite(height_m) or box_h_px <= 0:
        return "other"
    width_m = box_w_px * height_m / box_h_px
    aspect = box_w_px / box_h_px
    if height_m > 2.4:
        return "vehicle"              # buses, trucks, vans
    if width_m > 2.6:
        return "vehicle"              # cars seen from the side
    if 1.0 <= height_m <= 2.2 and aspect < 0.75:
        return "person"
    if 1.3 <= height_m <= 2.2 and width_m <= 2.6:
        return "cyclist" if width_m >= 1.0 and aspect < 1.6 else "vehicle"
    if height_m >= 1.0:
        return "vehicle"
    return "other"


class ObjectExtractor:
    """Fills ``packet.foreground`` and ``packet.detections``.

    Parameters
    ----------
    config : TrackingConfig
        ``background``, ``work_width``, ``min_area_px``, ``min_object_height_m``,
        ``height_percentile`` and ``height_measurement_noise_m`` are used.
    ground : GroundConfig
        ``height_threshold_m``: pixels lower than this are ground, not object.
    """

    def __init__(self, config: TrackingConfig, ground: GroundConfig):
        self.config = config
        self.height_threshold_m = ground.height_threshold_m
        self.subtractor = make_background_subtractor(config.background)
        # Closing joins a person's legs and arms; opening removes speckle. 3x3 at work size.
        self.kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3))
        self.grow_kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (7, 7))

    def process(self, packet: FramePacket) -> FramePacket:
        start = time.perf_counter()
        image = packet.frame.image
        src_h, src_w = image.shape[:2]
        scale = self._work_scale(src_w)
        work_size = (max(1, round(src_w * scale)), max(1, round(src_h * scale)))
        small = image if scale == 1.0 else cv2.resize(image, work_size, interpolation=cv2.INTER_AREA)

        moving = None
        if self.subtractor is not None:
            moving = self.subtractor.apply(small) == _FOREGROUND_VALUE
            packet.foreground = _resize_mask(moving, (src_w, src_h))

        above = self._above_ground(packet, work_size)
        if moving is None and above is None:
            packet.detections = []
            packet.timings_ms["object_extraction"] = (time.perf_counter() - start) * 1000
            return packet
        if moving is None:
            candidate = above
        elif above is None:
            # No height map to fill holes: close them with the same growth, then shrink back.
            candidate = cv2.morphologyEx(moving.astype(np.uint8), cv2.MORPH_CLOSE, self.grow_kernel)
        else:
            # Foreground grown by a few pixels: flat-coloured parts of an object (a car roof, a
            # plain coat) drop out of the background model; the height map fills them back in.
            candidate = cv2.dilate(moving.astype(np.uint8), self.grow_kernel).astype(bool) & above

        candidate = candidate.astype(np.uint8)
        candidate = cv2.morphologyEx(candidate, cv2.MORPH_CLOSE, self.kernel)
        candidate = cv2.morphologyEx(candidate, cv2.MORPH_OPEN, self.kernel)
        packet.detections = self._blobs_to_detections(candidate, packet.height_map, scale, (src_w, src_h))
        packet.timings_ms["object_extraction"] = (time.perf_counter() - start) * 1000
        return packet

    def _work_scale(self, src_w: int) -> float:
        if self.config.work_width <= 0 or self.config.work_width >= src_w:
            return 1.0
        return self.config.work_width / src_w

    def _above_ground(self, packet: FramePacket, work_size: tuple[int, int]) -> np.ndarray | None:
        if packet.height_map is None:
            return None
        # INTER_NEAREST keeps object edges crisp; averaging would smear heights onto the ground.
        heights = cv2.resize(packet.height_map, work_size, interpolation=cv2.INTER_NEAREST)
        above = np.nan_to_num(heights, nan=0.0) > self.height_threshold_m
        if packet.ground_mask is not None:
            above &= ~_resize_mask(packet.ground_mask, work_size)
        return above

    def _blobs_to_detections(self, candidate: np.ndarray, height_map: np.ndarray | None,
                             scale: float, src_size: tuple[int, int]) -> list[Detection]:
        src_w, src_h = src_size
        count, labels, stats, _ = cv2.connectedComponentsWithStats(candidate, connectivity=8)
        min_area_work = self.config.min_area_px * scale * scale
        detections = []
        for label in range(1, count):
            x, y, w, h, area = stats[label]
            if area < min_area_work:
                continue
            # Box back in source pixels (pixel edges, not centres).
            x0, y0 = int(np.floor(x / scale)), int(np.floor(y / scale))
            x1 = min(src_w, int(np.ceil((x + w) / scale)))
            y1 = min(src_h, int(np.ceil((y + h) / scale)))
            blob = labels[y:y + h, x:x + w] == label
            mask = _resize_mask(blob, (x1 - x0, y1 - y0))
            detection = self._measure(mask, height_map, (x0, y0, x1, y1), src_size)
            if detection is not None:
                detections.append(detection)
        return detections

    def _measure(self, mask: np.ndarray, height_map: np.ndarray | None,
                 corners: tuple[int, int, int, int], src_size: tuple[int, int]) -> Detection | None:
        x0, y0, x1, y1 = corners
        box_w, box_h = float(x1 - x0), float(y1 - y0)
        src_w, src_h = src_size
        touches_border = x0 <= 1 or y0 <= 1 or x1 >= src_w - 1 or y1 >= src_h - 1
        height_m, noise_m = float("nan"), float("inf")
        if height_map is not None:
            values = height_map[y0:y1, x0:x1][mask]
            values = values[np.isfinite(values)]
            if values.size == 0:
                return None
            # A high percentile, not the maximum: the top of the object without single-pixel spikes.
            height_m = float(np.percentile(values, self.config.height_percentile))
            if height_m < self.config.min_object_height_m:
                return None
            noise_m = self._height_noise(height_m, box_h, touches_border)
        return Detection(
            box=(float(x0), float(y0), box_w, box_h),
            height_m=height_m,
            cls=coarse_class(height_m, box_w, box_h),
            foot_xy=((x0 + x1) / 2.0, float(y1)),
            top_xy=((x0 + x1) / 2.0, float(y0)),
            height_noise_m=noise_m,
            touches_border=touches_border,
            mask=mask,
        )

    def _height_noise(self, height_m: float, box_h_px: float, touches_border: bool) -> float:
        """Base noise, plus the size of one pixel at the object, times 3 when cut by the border."""
        metres_per_px = height_m / max(box_h_px, 1.0)
        noise = float(np.hypot(self.config.height_measurement_noise_m, 2.0 * metres_per_px))
        if touches_border:
            noise *= 3.0              # the top or the foot may be outside the image
        return noise


def _resize_mask(mask: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Bool mask to (width, height) with nearest-neighbour sampling."""
    if mask.shape[1] == size[0] and mask.shape[0] == size[1]:
        return mask.astype(bool, copy=False)
    return cv2.resize(mask.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST).astype(bool)
