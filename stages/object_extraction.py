"""Object extraction on a fixed camera: moving, above-ground blobs become ``Detection`` s.

Two cues, each covering the other's failure:

* background subtraction finds what moves, but also moving shadows, lighting changes and the
  "ghost" a parked object leaves when it drives off;
* the height map finds what stands above the ground, but also buildings, poles and trees.

A pixel belongs to an object candidate when it is foreground *and* above the ground (and not
on the ground mask). Without a height map the foreground alone is used; with ``background =
"none"`` the height map alone. The background model is seeded with the median of frames read
ahead (``prime_background``), and a global brightness change (auto exposure) is divided out
before background subtraction. The work is done on a downscaled frame (``work_width``) so the
stage costs a few milliseconds; boxes and heights are measured back in the frame's pixels.

Specks of sensor noise are dropped from the foreground first (at dusk they joined every walker
into one sparse blob). Then: blobs that are mostly not foreground (rain over a facade) or taller
than any mover (scenery) are dropped; merged blobs are split where their own foreground shows
people side by side (Oxford Town Centre: a pair walking together was one 2.21 m "person"),
where the height map shows separate peaks and where the foreground's outline shows a row of
heads (a group walking shoulder to shoulder); each detection's height noise gets the
height-consistency residual of the points matched onto it from the previous frame (a rigid
object's points keep their height). The geometry's foot and top points are the object's own
crown and soles on the background model's mask (``foreground_ends``), not its grown box.

Background method, measured on 10 generator sequences (oracle heights, 320x240, rain and fog
included): KNN found 856 of 4020 boxes with 59 clutter detections at ~4 ms/frame; CNT 850 with
169 clutter (its first ~15 frames are all foreground); MOG2 603 with 6 (its sparse masks fail
the foreground-share test). KNN is the default.

With ``objects.source = "network"`` the height network's detection head finds the objects instead
(``network_objects``): the background model still runs, as a cue that confirms weak boxes, and
everything above that exists to make blobs into objects (the foreground-share test, the splits,
crown and soles, classes from shape, denoising) is not run (docs/design.md, "retired in network
mode") but for the blobs no box covers that are big (the head misses most of those) or, with
``keep_motion_blobs``, all of them.

The stage is this module (the per-frame flow and its state); the background model's pieces are in
``background_model``, the blob splitters in ``blob_splitting``, the per-object measurements
(class, crown and soles, robust top) in ``object_measurements`` and the network's boxes in
``network_objects``.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, replace

import cv2
import numpy as np

from core.config import GroundConfig, ObjectsConfig
from core.packets import NETWORK, Detection, FramePacket, Measurement
from stages.association import Region, points_in_regions
from stages.background_model import FOREGROUND_VALUE, drop_small_pieces, make_background_subtractor
from stages.blob_splitting import split_by_foreground, split_by_heads, split_by_height_peaks
from stages.network_objects import check_config, motion_blob_floor, network_objects, still_candidates, uncovered_blobs
from stages.object_measurements import (coarse_class, fit_box_to_ends, foot_above_ground, foreground_ends,
                                        height_noise, moving_beyond_ends, robust_top, seen_outline)


@dataclass(frozen=True)
class ObjectExtractionConstants:
    """Object extraction's fixed numbers: properties of the method, not of a camera or a
    scene (those are in ``[objects]``; the rule is in docs/design.md, Configuration)."""

    # A part split off by height peaks needs this share of the blob's foreground test: half, as a
    # walker's plain coat is half missed by the background model (Oxford: 0.34-0.38 foreground).
    part_foreground_factor: float = 0.5
    # Exposure compensation: log-ratio histogram (bins of 0.02 over a factor of e each way) and the
    # gain change below which a frame is left alone (10 %: smaller steps are left to the model).
    exposure_bins: int = 100
    exposure_range: tuple[float, float] = (-1.0, 1.0)
    exposure_tolerance: float = 0.1
    # Rate of the running mean of the scene that the gain is measured against: about 20 frames, so
    # an object passing through does not become the reference while the light drifts in.
    reference_rate: float = 0.05
    # The foreground is grown by this many work pixels before it is cut to the height map: flat-
    # coloured parts of an object (a car roof, a plain coat) drop out of the background model and
    # the height map fills them back in; the crown and soles come from the ungrown masks.
    grow_radius: int = 3
    # Frames this noisy (grey levels, see ``ObjectExtractor._noisy``) are median-filtered before
    # background subtraction. trk_val20 (cached model heights): 4 of 20 sequences (night and dusk;
    # trk_test40: 4 of 40), HOTA 0.368 -> 0.370, at night 0.164 -> 0.180 (true height maps: 0.475 ->
    # 0.488, false positives 1253 -> 888); trk_dev20 1 of 20, 0.356 -> 0.357; heights unchanged. At
    # 2.5 people's heights got worse on trk_dev20 (10 of 55 objects). Oxford, traffic_bridge and the
    # sample: 0-1.5.
    denoise_min_sigma: float = 4.5
    # Times the median background is fed to a fresh subtractor: enough to fill KNN's sample sets.
    prime_repeats: int = 50
    # Matched points an object needs for a height-consistency residual: a median of fewer is one
    # point's word.
    min_consistency_points: int = 3
    # Frame times within this many seconds are the same instant (``still_s``'s window ends).
    time_epsilon_s: float = 1e-3


CONSTANTS = ObjectExtractionConstants()


@dataclass
class ForegroundMasks:
    """One frame's background-model masks at work size."""

    moving: np.ndarray
    """Foreground, specks dropped."""
    changed: np.ndarray
    """Moving, or darker like a shadow (dark hair, shoes)."""
    grown: np.ndarray
    """``moving`` dilated by ``CONSTANTS.grow_radius``: what the height map may fill in."""
    ends_changed: np.ndarray
    ends_moving: np.ndarray
    """The masks the crown and soles are read from: ``changed`` and ``moving``, or those of the
    unfiltered frame where the frames are denoised."""


class ObjectExtractor:
    """Fills ``packet.foreground`` and ``packet.detections``: from blobs, or with ``source =
    "network"`` from ``packet.network_detections`` (``stages.network_objects``), the background
    model then only a cue.

    Parameters
    ----------
    config : ObjectsConfig
        The ``[objects]`` section (all of it but ``background_prime_*``, which say which frames
        ``prime`` is given).
    ground : GroundConfig
        ``height_threshold_m``: pixels lower than this are ground, not object.
    """

    def __init__(self, config: ObjectsConfig, ground: GroundConfig):
        check_config(config)
        self.config = config
        self.network = config.source == "network"
        # Blobs are found in blobs mode, and in network mode only to keep those no box covers.
        self._blobs = not self.network or config.keep_motion_blobs
        # Without _blobs (network mode, no keep_motion_blobs) the only blobs measured are the big ones
        # the head misses, near vehicles: they read at the vehicles' percentile, as the head's vehicle
        # boxes do (held out, tracked vehicles over the same objects: trk_val20 14.1 -> 10.4 cm,
        # trk_test40 15.9 -> 14.4; docs/results.md, 2026-12-05 twenty-second session).
        self.blob_percentile = config.height_percentile if self._blobs else config.vehicle_height_percentile
        self._reference: np.ndarray | None = None
        self.height_threshold_m = ground.height_threshold_m
        self.subtractor = make_background_subtractor(config.background)
        # Closing joins a person's legs and arms (3x3 at work size). No opening: it erased a small
        # walker's legs (1-2 work pixels wide); speckle is left to min_area_px. Generator dev set,
        # oracle heights: HOTA 0.525 -> 0.569, false positives 172 -> 115 without it.
        self.kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3))
        self.grow_kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * CONSTANTS.grow_radius + 1,) * 2)
        self._prev_height_map: np.ndarray | None = None
        # (time, network boxes) of the last frames, that a weak box standing still is compared with.
        self._earlier_boxes: deque[tuple[float, list]] = deque()
        # Denoising exists to keep specks from joining blobs: without blobs it stays off.
        self._denoise: bool | None = None if self._blobs else False
        self._ends_subtractor = None
        self._edge: tuple[object, tuple[int, int], tuple[np.ndarray, np.ndarray]] | None = None
        """(the image_valid it was made from, frame size, edge masks): see ``_image_edge``."""

    def process(self, packet: FramePacket) -> FramePacket:
        image = packet.frame.image
        src_h, src_w = image.shape[:2]
        scale = self._work_scale(src_w)
        work_size = (max(1, round(src_w * scale)), max(1, round(src_h * scale)))
        small = image if scale == 1.0 else cv2.resize(image, work_size, interpolation=cv2.INTER_AREA)
        masks = self._foreground(packet, small, scale)
        if self.network:
            detections = self._network_detections(packet, masks, scale, work_size)
        else:
            detections = self._blob_detections(packet, masks, scale, work_size)
            if detections is None:
                packet.detections = []
                return packet
        if packet.height_map is not None:
            self._add_consistency_noise(detections, packet)
        packet.detections = detections
        self._prev_height_map = packet.height_map
        return packet

    def _foreground(self, packet: FramePacket, small: np.ndarray, scale: float) -> ForegroundMasks | None:
        """The background model's masks at work size (None without one); fills ``packet.foreground``."""
        if self.subtractor is None:
            return None
        src_h, src_w = packet.frame.image.shape[:2]
        small = self._compensate_exposure(small)
        if self._denoise is None:
            self._set_denoise(self._noisy([small]))
        raw = self.subtractor.apply(cv2.medianBlur(small, 3) if self._denoise else small)
        # Sensor noise is per source pixel: downscaling averages it away, at source size it specks.
        moving = drop_small_pieces(raw == FOREGROUND_VALUE, self.config.min_foreground_piece_px * scale * scale)
        changed = raw > 0
        packet.foreground = _resize_mask(moving, (src_w, src_h))
        ends_changed, ends_moving = changed, moving
        if self._ends_subtractor is not None:
            unfiltered = self._ends_subtractor.apply(small)
            ends_changed, ends_moving = unfiltered > 0, unfiltered == FOREGROUND_VALUE
        grown = cv2.dilate(moving.astype(np.uint8), self.grow_kernel).astype(bool)
        return ForegroundMasks(moving, changed, grown, ends_changed, ends_moving)

    def _network_detections(self, packet: FramePacket, masks: ForegroundMasks | None, scale: float,
                            work_size: tuple[int, int]) -> list[Detection]:
        """``objects.source = "network"``: the network's boxes (``stages.network_objects``), and the
        blobs that no kept box covers: big ones, or all with ``keep_motion_blobs``."""
        src_h, src_w = packet.frame.image.shape[:2]
        edge, _ = self._image_edge(packet.image_valid, (src_w, src_h), scale, work_size)
        detections = network_objects(packet.network_detections, self.config, self.height_threshold_m,
                                     packet.height_map, packet.ground_mask, packet.foreground, edge,
                                     self._still_window(packet.frame.time_s))
        if self.config.still_s > 0:
            self._earlier_boxes.append((packet.frame.time_s,
                                        still_candidates(packet.network_detections, self.config, (src_w, src_h))))
        floor = motion_blob_floor(self.config, src_h, packet.network_detections)
        # With a big-object head no blob can be an object: none is cut out (its cost is saved).
        blobs = (self._blob_detections(packet, masks, scale, work_size, floor) or []) if floor < np.inf else []
        # A weak box (continues_only) may find no track to carry on: it hides no blob.
        detections += uncovered_blobs(blobs, [d for d in detections if not d.continues_only], floor)
        return detections

    def _still_window(self, now_s: float) -> list[list]:
        """The network boxes of every frame of the last ``still_s`` seconds (``network_objects``'s
        ``earlier``), or none while the run has not seen that long; older frames are forgotten."""
        window = self.config.still_s
        if window <= 0:
            return []
        while self._earlier_boxes and self._earlier_boxes[0][0] < now_s - window - CONSTANTS.time_epsilon_s:
            self._earlier_boxes.popleft()
        if not self._earlier_boxes or self._earlier_boxes[0][0] > now_s - window + CONSTANTS.time_epsilon_s:
            return []
        return [boxes for _, boxes in self._earlier_boxes]

    def _blob_detections(self, packet: FramePacket, masks: ForegroundMasks | None, scale: float,
                         work_size: tuple[int, int], min_height_px: float = 0.0) -> list[Detection] | None:
        """``objects.source = "blobs"``: moving, above-ground blobs, split and measured (None when
        there is neither a background model nor a height map). Blobs that cannot make a box
        ``min_height_px`` tall (frame pixels) are left unmeasured."""
        src_h, src_w = packet.frame.image.shape[:2]
        above, work_heights = self._above_ground(packet, work_size)
        if masks is None and above is None:
            return None
        if masks is None:
            candidate = above
        elif above is None:
            # No height map to fill holes: close them with the same growth, then shrink back
            # (eroding the grown foreground is that closing).
            candidate = cv2.erode(masks.grown.astype(np.uint8), self.grow_kernel)
        else:
            # Foreground grown by a few pixels: flat-coloured parts of an object (a car roof, a
            # plain coat) drop out of the background model; the height map fills them back in.
            candidate = masks.grown & above

        candidate = candidate.astype(np.uint8)
        candidate = cv2.morphologyEx(candidate, cv2.MORPH_CLOSE, self.kernel)
        edge, work_edge = self._image_edge(packet.image_valid, (src_w, src_h), scale, work_size)
        return self._blobs_to_detections(candidate, masks, work_heights, packet.height_map, scale, edge, work_edge,
                                         min_height_px)

    def prime(self, images: list[np.ndarray]) -> list[np.ndarray]:
        """Seed the background model from look-ahead frames (``prime_background``); pass them on."""
        self.prime_background(images)
        return images

    def close(self) -> None:
        """Nothing to release (the Stage contract, core/stage.py)."""

    def prime_background(self, images: list[np.ndarray]) -> None:
        """Seed the background model with the per-pixel median of frames spread over the clip's start.

        A background model learnt from the first frame holds everyone standing in it: when they
        walk off, the spot they leave is "foreground" (a ghost) for hundreds of frames, and a
        ghost over a bench or a bin is above ground, so it becomes an object with a height.
        The median of frames seconds apart shows the empty scene instead. Images are in the
        run's frame geometry (undistorted where the run undistorts).
        """
        if self.subtractor is None or not images:
            return
        src_w = images[0].shape[1]
        scale = self._work_scale(src_w)
        size = (max(1, round(src_w * scale)), max(1, round(images[0].shape[0] * scale)))
        small = [cv2.resize(image, size, interpolation=cv2.INTER_AREA) if scale != 1.0 else image
                 for image in images if image.shape[:2] == images[0].shape[:2]]
        background = np.median(np.stack(small), axis=0).astype(np.uint8)
        if self._blobs:
            self._set_denoise(self._noisy(small))
        if self._ends_subtractor is not None:
            for _ in range(CONSTANTS.prime_repeats):
                self._ends_subtractor.apply(background)
        if self._denoise:
            background = cv2.medianBlur(background, 3)
        for _ in range(CONSTANTS.prime_repeats):
            self.subtractor.apply(background)
        self._reference = _grey(background) + 4.0

    def _set_denoise(self, denoise: bool) -> None:
        """Denoise (or not) for the rest of the run. A denoising run keeps a second background model
        of the unfiltered frames: the median filter shaves a walker's crown and soles, so the geometry's
        ends come from that model (trk_test40, a noisy dusk camera at 3.5 m: four people 10-20 cm low
        from the filtered masks, as before from the unfiltered ones)."""
        self._denoise = denoise
        self._ends_subtractor = make_background_subtractor(self.config.background) if denoise else None

    @staticmethod
    def _noisy(images: list[np.ndarray]) -> bool:
        """Whether the camera's sensor noise is high enough to denoise before background subtraction.

        A night camera's noise (generator: sigma 5-7 grey levels at 320 px) speckles the whole
        foreground; grown, the specks join every walker to its neighbours and to the scenery.
        A 3x3 median filter removes them but also thins a small walker's legs, so it is used only
        on noisy cameras: the robust std of a frame minus its median-filtered self (the median
        over the frames given) at least ``CONSTANTS.denoise_min_sigma``. Decided once per run.
        """
        sigmas = [1.4826 * np.median(np.abs(image.astype(np.int16) - cv2.medianBlur(image, 3).astype(np.int16)))
                  for image in images]
        return float(np.median(sigmas)) >= CONSTANTS.denoise_min_sigma

    def _compensate_exposure(self, small: np.ndarray) -> np.ndarray:
        """Undo a global brightness change (auto exposure, a cloud) before background subtraction.

        When a bus fills half the view, the camera's exposure brightens the whole scene and a
        background model flags every pixel. Unchanged pixels all differ from the background by
        one gain, so the gain is the peak of the log-ratio histogram against a slow running mean
        of the (compensated) frames; the moving object's pixels spread over many bins. The frame
        is divided by the gain when it is more than ``CONSTANTS.exposure_tolerance`` off. (OpenCV's own
        background image is not used: reading it from the KNN model changes its later output.)
        """
        grey = _grey(small) + 4.0
        if self._reference is None:
            self._reference = grey
            return small
        # OpenCV's histogram: a third of NumPy's time on a 480x270 frame (the top edge is open).
        low, high = CONSTANTS.exposure_range
        counts = cv2.calcHist([np.log(grey / self._reference).astype(np.float32)], [0], None,
                              [CONSTANTS.exposure_bins], [low, high])
        peak = int(np.argmax(counts))
        gain = float(np.exp(low + (peak + 0.5) * (high - low) / CONSTANTS.exposure_bins))
        if abs(gain - 1.0) > CONSTANTS.exposure_tolerance:
            small = np.clip(small.astype(np.float32) / gain, 0, 255).astype(np.uint8)
            grey = (grey - 4.0) / gain + 4.0
        self._reference += CONSTANTS.reference_rate * (grey - self._reference)
        return small

    def _image_edge(self, image_valid: np.ndarray | None, size: tuple[int, int], scale: float,
                    work_size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        """Pixels within one work pixel of where the image ends (frame border or undistortion's black).

        An object reaching them may go on outside: its foot or top there is not a measurement.
        At source size, and at work size (a work pixel holding any edge pixel is edge). Made once
        per run (the valid region does not change).
        """
        if self._edge is not None and self._edge[0] is image_valid and self._edge[1] == size:
            return self._edge[2]
        margin = int(np.ceil(1.0 / scale)) + 2
        valid = np.ones((size[1], size[0]), np.uint8) if image_valid is None else image_valid.astype(np.uint8)
        valid = np.pad(valid, 1)  # outside the frame is not image either
        inner = cv2.erode(valid, cv2.getStructuringElement(cv2.MORPH_RECT, (2 * margin + 1, 2 * margin + 1)))
        edge = ~inner[1:-1, 1:-1].astype(bool)
        work_edge = cv2.resize(edge.astype(np.uint8), work_size, interpolation=cv2.INTER_AREA) > 0
        self._edge = (image_valid, size, (edge, work_edge))
        return edge, work_edge

    def _work_scale(self, src_w: int) -> float:
        if self.config.work_width <= 0 or self.config.work_width >= src_w:
            return 1.0
        return self.config.work_width / src_w

    def _above_ground(self, packet: FramePacket,
                      work_size: tuple[int, int]) -> tuple[np.ndarray | None, np.ndarray | None]:
        """Above-ground mask and the height map, both at work size (None without a height map)."""
        if packet.height_map is None:
            return None, None
        # INTER_NEAREST keeps object edges crisp; averaging would smear heights onto the ground.
        heights = cv2.resize(packet.height_map, work_size, interpolation=cv2.INTER_NEAREST)
        heights = np.nan_to_num(heights, nan=0.0)
        above = heights > self.height_threshold_m
        if packet.ground_mask is not None:
            above &= ~_resize_mask(packet.ground_mask, work_size)
        return above, heights

    def _blobs_to_detections(self, candidate: np.ndarray, masks: ForegroundMasks | None,
                             work_heights: np.ndarray | None, height_map: np.ndarray | None, scale: float,
                             edge: np.ndarray, work_edge: np.ndarray, min_height_px: float = 0.0) -> list[Detection]:
        """``masks``: None without a background model. A blob whose box in frame pixels (at most
        two more than its work-size rows, scaled) stays under ``min_height_px`` is skipped before
        it is split and measured: network mode asks only for big blobs, and splitting and
        measuring every walker's blob cost it 1.9 ms of CPU a frame at 640x360 (docs/results.md,
        2026-12-04, fifth session)."""
        count, labels, stats, _ = cv2.connectedComponentsWithStats(candidate, connectivity=8)
        min_area_work = self.config.min_area_px * scale * scale
        detections = []
        for label in range(1, count):
            x, y, w, h, area = stats[label]
            if area < min_area_work or h / scale + 2 < min_height_px:
                continue
            blob = labels[y:y + h, x:x + w] == label
            fg = None if masks is None else masks.moving[y:y + h, x:x + w]
            heights = None if work_heights is None else work_heights[y:y + h, x:x + w]
            # Rain streaks and swaying leaves over a building or a tree are foreground too,
            # but sparse: a moving object is mostly foreground itself.
            if fg is not None and fg[blob].mean() < self.config.min_foreground_share:
                continue
            # People side by side part on the foreground (each keeps the blob's share test: a
            # person whose coat the background model half missed is still a person).
            pieces = [blob] if fg is None else split_by_foreground(blob, fg, min_area_work)
            # A crowd's outline shows its heads, unless the frame's edge may cut it (a truck's roof
            # under rain streaks reads as a row of heads there).
            by_heads = fg is not None and not work_edge[y:y + h, x:x + w][blob].any()
            for piece in pieces:
                parts = [piece] if heights is None else split_by_height_peaks(piece, heights, min_area_work)
                if by_heads:
                    parts = [head for part in parts for head in split_by_heads(part, fg, min_area_work, heights)]
                for part in parts:
                    # A part cut off by height (a facade beside a walker) must be moving itself.
                    if (fg is not None and len(parts) > 1
                            and fg[part].mean() < CONSTANTS.part_foreground_factor * self.config.min_foreground_share):
                        continue
                    if masks is None:
                        beyond, ends, outline = (False, False), None, None
                    else:
                        beyond = moving_beyond_ends(part, (x, y), masks.grown, work_edge)
                        ends = foreground_ends(part, (x, y), masks.ends_changed, masks.ends_moving,
                                               CONSTANTS.grow_radius)
                        outline = seen_outline(part, (x, y), masks.changed)
                    detection = self._piece_to_detection(part, (x, y), height_map, scale, edge, beyond, ends,
                                                         outline)
                    if detection is not None:
                        detection.blob = label
                        detections.append(detection)
        return detections

    def _piece_to_detection(self, piece: np.ndarray, offset: tuple[int, int], height_map: np.ndarray | None,
                            scale: float, edge: np.ndarray, beyond: tuple[bool, bool],
                            ends: tuple[int, int] | None, outline: np.ndarray | None) -> Detection | None:
        rows, cols = np.nonzero(piece)
        if rows.size == 0:
            return None
        x, y = offset[0] + cols.min(), offset[1] + rows.min()
        w, h = cols.max() - cols.min() + 1, rows.max() - rows.min() + 1
        piece = piece[rows.min():rows.max() + 1, cols.min():cols.max() + 1]
        # Box back in the frame's pixels (pixel edges, not centres).
        src_h, src_w = edge.shape
        x0, y0 = int(np.floor(x / scale)), int(np.floor(y / scale))
        x1 = min(src_w, int(np.ceil((x + w) / scale)))
        y1 = min(src_h, int(np.ceil((y + h) / scale)))
        mask = _resize_mask(piece, (x1 - x0, y1 - y0))
        detection = self._measure(mask, height_map, (x0, y0, x1, y1), edge[y0:y1, x0:x1] & mask, scale, beyond)
        if detection is not None:
            # Without a background model the part itself is the best outline there is.
            detection.outline = mask if outline is None else _resize_mask(
                outline[rows.min():rows.max() + 1, cols.min():cols.max() + 1], (x1 - x0, y1 - y0))
        if detection is not None and ends is not None:
            # Geometry points from the object's own foreground, not from the grown box (whose top
            # overshoots the head by the growth) nor the height map's cut (which ends above the feet).
            detection.top_xy = (detection.top_xy[0], float(np.floor(ends[0] / scale)))
            detection.foot_xy = (detection.foot_xy[0], float(min(src_h, np.ceil((ends[1] + 1) / scale))))
            # Not a vehicle's: fitted too, vehicles' tracked heights on trk_val20 went 25.4 -> 30.0 cm
            # (not understood; their outline top is the roof's far edge, not a crown).
            if detection.cls != "vehicle":
                fit_box_to_ends(detection)
        return detection

    def _add_consistency_noise(self, detections: list[Detection], packet: FramePacket) -> None:
        """Height consistency: points matched from the last frame keep their height on a rigid object.

        The median height change of an object's matched points between the previous and this
        frame's height maps says how much this frame's heights wobble: it is added (in
        quadrature, times ``consistency_gain``) to the detection's height noise.
        """
        matches = packet.matches
        previous = self._prev_height_map
        if (matches is None or previous is None or previous.shape != packet.height_map.shape
                or len(matches.curr_pts) == 0 or self.config.consistency_gain <= 0):
            return
        on_object = np.asarray(matches.on_object, dtype=bool)
        prev_pts, curr_pts = matches.prev_pts[on_object], matches.curr_pts[on_object]
        if len(curr_pts) == 0:
            return
        change = np.abs(_sample(packet.height_map, curr_pts) - _sample(previous, prev_pts))
        regions = [Region(d.box, d.mask) for d in detections]
        inside = points_in_regions(curr_pts, regions)
        for column, detection in enumerate(detections):
            residuals = change[inside[:, column]]
            residuals = residuals[np.isfinite(residuals)]
            network = detection.heights.get(NETWORK)
            if (residuals.size >= CONSTANTS.min_consistency_points and network is not None
                    and np.isfinite(network.noise_m)):
                residual = float(np.median(residuals))
                noise = float(np.hypot(network.noise_m, self.config.consistency_gain * residual))
                detection.add_height(NETWORK, replace(network, noise_m=noise))

    def _measure(self, mask: np.ndarray, height_map: np.ndarray | None, corners: tuple[int, int, int, int],
                 at_edge: np.ndarray, scale: float, beyond: tuple[bool, bool]) -> Detection | None:
        x0, y0, x1, y1 = corners
        box_w, box_h = float(x1 - x0), float(y1 - y0)
        # The object's first and last rows (one work pixel deep) reaching the image edge: top or foot cut.
        band = int(np.ceil(1.0 / scale))
        rows = np.flatnonzero(mask.any(axis=1))
        top_cut = bool(rows.size and at_edge[rows[0]:rows[0] + band].any()) or beyond[0]
        foot_cut = bool(rows.size and at_edge[max(rows[-1] + 1 - band, 0):rows[-1] + 1].any()) or beyond[1]
        touches_border = bool(at_edge.any())
        height_m, measured = float("nan"), {}
        if height_map is not None:
            heights = height_map[y0:y1, x0:x1]
            height_m = robust_top(heights, mask, self.blob_percentile)
            if not (self.config.min_object_height_m <= height_m <= self.config.max_object_height_m):
                return None
            noise_m = self._height_noise(height_m, box_h, touches_border)
            foot_cut = foot_cut or foot_above_ground(heights, mask, rows, height_m)
            if top_cut:
                noise_m = float("inf")    # top cut off by the frame: a lower bound, not a height
            measured[NETWORK] = Measurement(height_m, noise_m, source="objects")
        return Detection(
            box=(float(x0), float(y0), box_w, box_h),
            heights=measured,
            cls=coarse_class(height_m, box_w, box_h),
            cls_source="objects",
            foot_xy=((x0 + x1) / 2.0, float(y1)),
            top_xy=((x0 + x1) / 2.0, float(y0)),
            touches_border=touches_border,
            foot_cut=foot_cut,
            top_cut=top_cut,
            mask=mask,
        )

    def _height_noise(self, height_m: float, box_h_px: float, touches_border: bool) -> float:
        """Base noise, plus the size of one pixel at the object, times 3 when cut by the border."""
        return height_noise(self.config.height_measurement_noise_m, height_m, box_h_px, touches_border)




def _sample(image: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Values at the nearest pixels of N x 2 (x, y) points."""
    h, w = image.shape[:2]
    x = np.clip(np.round(points[:, 0]).astype(int), 0, w - 1)
    y = np.clip(np.round(points[:, 1]).astype(int), 0, h - 1)
    return image[y, x].astype(float)


def _grey(image: np.ndarray) -> np.ndarray:
    """Mean of each pixel's channels, float32: ``image.astype(np.float32).mean(axis=2)``, bit for bit.

    For 8-bit BGR the three values are summed in 16 bits (exact, as in float32) and the sum is
    divided by 3 in float32, as ``mean`` does: 320x180, 0.9 -> 0.13 ms per frame.
    """
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        return image.astype(np.float32).mean(axis=2)
    blue, green, red = cv2.split(image)
    total = cv2.add(cv2.add(blue, green, dtype=cv2.CV_16U), red, dtype=cv2.CV_16U).astype(np.float32)
    return np.divide(total, np.float32(3.0), out=total)


def _resize_mask(mask: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Bool mask to (width, height) with nearest-neighbour sampling."""
    if mask.shape[1] == size[0] and mask.shape[0] == size[1]:
        return mask.astype(bool, copy=False)
    return cv2.resize(mask.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST).astype(bool)
