"""Geometry measurement: each detection's height and ground position through the calibrated camera.

A second height measurement, independent of the network: the foot point's ray meets the ground
plane, and the top point's ray passes the vertical through that ground point at the object's
height (:func:`stages.calibration.heights_from_foot_top`). The tracker fuses it with the
network's height, so its noise must be honest: pixel noise of the two points propagated through
the geometry, the camera-height uncertainty of a self-calibrated camera, and for long objects
the error of assuming the top is above the foot.

Objects as wide as a vehicle also get a third reading, the height of a box on the ground fitted
to their outline (:mod:`stages.vehicle_geometry`): a vehicle's outline top is its roof's far
edge, metres behind its foot, where foot and top read it ~1 m high. The tracker takes it for
vehicle tracks instead of foot and top.

An object whose foot is cut off (by the frame's edge, or hidden) still gets a lower bound: its
true foot lies lower in the image, nearer the camera, where the top's ray stands higher. The
tracker raises a network height below it (Oxford: a walker leaving at the bottom corner read
1.47 m by the network alone, against a bound of up to 1.70 m).

It also checks the network's scale: on whole people, the median ratio of geometry to network
height over the run so far says how far the network reads off in this scene (the shipped model
reads about 0.7x on real footage), and every network height is multiplied by it, so objects
that only the network can measure (cut by the frame's edge) get the corrected scale too. The
scale's uncertainty (a wide prior until there are enough ratios) is added to every network
height's noise: a filter that took an unscaled network's 1.0 m for a 1.8 m walker as sure would
reject the geometry against it.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

from core.config import CameraConfig
from core.packets import BOX, GEOMETRY, NETWORK, CameraInfo, Detection, FramePacket, Measurement
from stages.calibration import (angles_from_rotation, camera_from_pose, has_distortion, heights_from_foot_top,
                                is_calibrated, undistort_pixels)
from stages.vehicle_geometry import vehicle_box


@dataclass(frozen=True)
class GeometryConstants:
    """The geometry's fixed numbers: properties of the method, not of a camera or a scene
    (those are in ``[camera]``; the rule is in docs/design.md, Configuration)."""

    # Horizontal distance between an object's ground contact (the bottom of its blob) and the part
    # that is its top in the image. The geometry assumes the top is vertically above the foot: for a
    # person that holds to a few centimetres, for a car seen from above the top of the blob is the far
    # edge of the roof, metres behind the front bumper, and the height comes out too large.
    horizontal_extent_m: dict[str, float] = field(
        default_factory=lambda: {"person": 0.3, "cyclist": 1.2, "vehicle": 4.5, "other": 1.0})
    # Network scale: ratios from this many whole-person detections at least (a median of 30 is sure
    # to a few per cent), the last this many kept (a scene's lighting changes over hours).
    scale_min_samples: int = 30
    scale_window: int = 1000
    # The network's relative height error before its scale is known in this scene: on the generator's
    # dev tracking set (data/trk_dev) the shipped model reads people at 0.48x their height (log-ratio
    # rms 0.77); on Oxford at ~0.8x. Half the height is an honest std there, not the 0.15 m base noise.
    network_prior_scale_noise: float = 0.5
    # Geometry heights outside this range are failures (foot near the horizon, top ray grazing):
    # nothing on a street is under 5 cm or over 30 m tall.
    plausible_height_m: tuple[float, float] = (0.05, 30.0)
    # Classes in metres (see ``metric_class``): wider than a bicycle is long, or taller than anyone
    # and wider than a person, is a vehicle; a person is at most this wide (a stride, arms swinging);
    # upright objects between these heights are people or cyclists.
    vehicle_min_width_m: float = 1.8
    person_max_width_m: float = 1.3
    upright_height_m: tuple[float, float] = (0.8, 2.3)
    # Objects at least this wide at their foot get the vehicle geometry too (the tracker picks the
    # reading that fits the track's class, which may differ from this frame's).
    vehicle_outline_min_width_m: float = 1.4
    # The vehicle geometry's error beyond its pixels: a footprint width from a prior, the clearance
    # under the body, a car's cabin taken as a share of its body. Measured with the shipped model's
    # masks on held-out generator sequences (data/trk_val20; the train-split data/trk_dev20 alike):
    # per detection a robust std of 0.20 m (trk_dev20: 0.43), per object (repeating frame after
    # frame) 0.22 m (0.27); 91 % (88 %) of readings within 2 stated std.
    vehicle_shape_noise_m: float = 0.3
    vehicle_shape_bias_m: float = 0.2
    # Added (in quadrature) where only the vehicle's end was seen and its length is assumed: a van's
    # roof runs 1-1.5 m further back than a car's cabin.
    vehicle_end_on_noise_m: float = 0.3


CONSTANTS = GeometryConstants()


class GeometryMeasurer:
    """Adds each whole detection's ``GEOMETRY`` height (and a vehicle's ``BOX`` height), its class
    in metres (unless the network's detection head gave it one), its ground point, and a lower
    bound on its height where its foot is cut.

    Does nothing unless ``packet.camera`` has a pose (source "calibration" or "self").
    Points are undistorted here when the camera still has distortion (no Undistorter ran).

    Parameters
    ----------
    config : CameraConfig
        ``point_noise_px`` (std of foot and top points) sets the noise; ``height_std_m``,
        ``pitch_std_deg``, ``roll_std_deg`` and ``focal_std_pct`` (a self-calibrated pose's
        uncertainty) each detection's ``camera_share``.
    """

    def __init__(self, config: CameraConfig):
        self.point_noise_px = config.point_noise_px
        self.camera_height_std_m = config.height_std_m
        self.pose_std = (config.pitch_std_deg, config.roll_std_deg, config.focal_std_pct)
        self._shifted: tuple[CameraInfo, list[CameraInfo]] | None = None
        self.network_scale = NetworkScale() if config.rescale_network else None

    def process(self, packet: FramePacket) -> FramePacket:
        camera = packet.camera
        usable = [d for d in packet.detections if d.foot_xy is not None]
        if is_calibrated(camera) and usable:
            self.measure(camera, usable)
            if self.network_scale is not None:
                self.network_scale.rescale(packet.detections)
        return packet

    def close(self) -> None:
        """Nothing to release (the Stage contract, core/stage.py)."""

    def measure(self, camera: CameraInfo, detections: list[Detection]) -> None:
        foot = np.array([d.foot_xy for d in detections], dtype=float)
        top = np.array([d.top_xy if d.top_xy is not None else (np.nan, np.nan) for d in detections])
        # A foot at the image's edge is not the object's ground contact; and of an object that the
        # edge cuts anywhere, the lowest and highest visible points are not its foot and top.
        foot_ok = np.array([not d.foot_cut for d in detections])
        whole = np.array([not (d.foot_cut or d.top_cut or d.touches_border) for d in detections])
        foot = undistort_pixels(camera, foot)
        top = undistort_pixels(camera, top)

        heights, ground = heights_from_foot_top(camera, foot, top)
        noise = self._pixel_noise(camera, foot, top)
        camera_share = self._camera_share(camera, foot, top, heights)
        distance = np.hypot(*(ground - (-camera.R.T @ camera.t)[:2]).T)
        widths = _widths_at_ground(camera, ground, np.array([d.box[2] for d in detections], dtype=float))
        for i, detection in enumerate(detections):
            if foot_ok[i] and np.all(np.isfinite(ground[i])):
                detection.ground_xy_m = (float(ground[i, 0]), float(ground[i, 1]))
            if (whole[i] and np.isfinite(heights[i]) and np.isfinite(widths[i]) and heights[i] > 0
                    and detection.cls_source != NETWORK):
                # The network's height classed people it reads at half their height as "other";
                # the calibrated camera measures both height and width in metres. A class from the
                # network's detection head is the network's to decide: it saw the object.
                detection.classify(metric_class(float(heights[i]), float(widths[i])), GEOMETRY)
            height = heights[i]
            if (not foot_ok[i] and np.isfinite(height) and 0.0 < height < camera.height_m
                    and not widths[i] >= CONSTANTS.vehicle_min_width_m):
                # The top's ray descends (it is below the horizon): a nearer foot means a taller object.
                # Not for a vehicle-wide one: its top is the roof's far edge, metres behind the foot
                # (generator, a car coming into view at the bottom: bounds of 3.2-4.4 m for 1.5 m).
                detection.min_height_m = float(height)
            if not (whole[i] and np.isfinite(height) and np.isfinite(noise[i])
                    and CONSTANTS.plausible_height_m[0] <= height <= CONSTANTS.plausible_height_m[1]):
                continue
            extent = CONSTANTS.horizontal_extent_m.get(detection.cls, CONSTANTS.horizontal_extent_m["other"])
            shape_error = self._top_offset_error(camera.height_m, height, distance[i], extent)
            # The camera height's std also stays in the noise, where it weighs the geometry against
            # the network (Oxford, self-calibrated: 8.7 cm with it there, 11.9 with it only in the share).
            scale_error = height * self.camera_height_std_m / camera.height_m
            if np.isfinite(camera_share[i]):
                detection.camera_share = float(camera_share[i])
            detection.add_height(GEOMETRY, Measurement(
                float(height), float(np.sqrt(noise[i] ** 2 + shape_error ** 2 + scale_error ** 2)),
                source=GEOMETRY, bias_m=float(noise[i])))
        if has_distortion(camera):
            return   # outlines are in raw pixels; the vehicle geometry needs undistorted ones
        for i, detection in enumerate(detections):
            if whole[i] and detection.outline is not None and widths[i] >= CONSTANTS.vehicle_outline_min_width_m:
                self._measure_vehicle(camera, detection)

    def _measure_vehicle(self, camera: CameraInfo, detection: Detection) -> None:
        """Height of the box on the ground under the outline, noise from its top rows' pixel noise."""
        fitted = vehicle_box(camera, detection.outline, (detection.box[0], detection.box[1]), self.point_noise_px)
        if fitted is None or not CONSTANTS.plausible_height_m[0] <= fitted.height_m <= camera.height_m:
            return
        pixel = fitted.pixel_noise_m
        scale_error = fitted.height_m * self.camera_height_std_m / camera.height_m
        end_on = CONSTANTS.vehicle_end_on_noise_m if fitted.length_assumed else 0.0
        shape = np.hypot(CONSTANTS.vehicle_shape_noise_m, end_on)
        shape_bias = np.hypot(CONSTANTS.vehicle_shape_bias_m, end_on)
        noise = float(np.sqrt(pixel ** 2 + shape ** 2 + scale_error ** 2))
        detection.add_height(BOX, Measurement(fitted.height_m, noise, source="vehicle geometry",
                                              bias_m=float(np.hypot(pixel, shape_bias))))
        detection.vehicle_axis_xy = fitted.axis_xy
        detection.vehicle_length_assumed = fitted.length_assumed

    def _camera_share(self, camera: CameraInfo, foot: np.ndarray, top: np.ndarray,
                      heights: np.ndarray) -> np.ndarray:
        """Relative std of each height from the pose's stated uncertainty: the camera height's
        (heights scale with it) and, one at a time, pitch's, roll's and the focal length's (each
        moved by its std; their errors taken as independent). Zero for an exact pose.

        Why not in the measurement's noise: the error is the same on every frame (frames would
        average it away) and on every channel measured with this camera (the network is rescaled
        to the geometry), so fusing it would change nothing but the std; the tracker adds it there.
        (The camera height's part is in the noise too, as it was before the share: see ``measure``.)
        """
        with np.errstate(divide="ignore", invalid="ignore"):
            share2 = np.full(len(heights), (self.camera_height_std_m / camera.height_m) ** 2)
            for shifted in self._shifted_cameras(camera):
                moved, _ = heights_from_foot_top(shifted, foot, top)
                share2 = share2 + ((moved - heights) / heights) ** 2
        return np.sqrt(share2)

    def _shifted_cameras(self, camera: CameraInfo) -> list[CameraInfo]:
        """``camera`` with pitch, roll and focal length each moved by its std (those not zero);
        only for a pose given in ``[camera]`` (a calibration file's is exact). Made once a camera."""
        if self._shifted is not None and self._shifted[0] is camera:
            return self._shifted[1]
        pitch_std, roll_std, focal_std = self.pose_std
        shifted = []
        if camera.pose_from == "config" and (pitch_std or roll_std or focal_std):
            pitch, roll, yaw = angles_from_rotation(camera.R)
            for d_pitch, d_roll, d_focal in ((pitch_std, 0.0, 0.0), (0.0, roll_std, 0.0), (0.0, 0.0, focal_std)):
                if d_pitch or d_roll or d_focal:
                    K = np.array(camera.K, float)
                    K[0, 0] *= 1.0 + d_focal / 100.0
                    K[1, 1] *= 1.0 + d_focal / 100.0
                    shifted.append(camera_from_pose(camera.width, camera.height, K, camera.height_m,
                                                    pitch + d_pitch, roll + d_roll, yaw, dist=camera.dist))
        self._shifted = (camera, shifted)
        return shifted

    def _pixel_noise(self, camera: CameraInfo, foot: np.ndarray, top: np.ndarray) -> np.ndarray:
        """Std of the height from independent noise on the four point coordinates (central differences)."""
        step = self.point_noise_px
        variance = np.zeros(len(foot))
        for points_index in (0, 1):
            for axis in (0, 1):
                shifted = [foot.copy(), top.copy()]
                shifted[points_index][:, axis] += step
                plus, _ = heights_from_foot_top(camera, *shifted)
                shifted[points_index][:, axis] -= 2 * step
                minus, _ = heights_from_foot_top(camera, *shifted)
                variance += ((plus - minus) / 2.0) ** 2
        return np.sqrt(variance)

    @staticmethod
    def _top_offset_error(camera_height_m: float, height_m: float, distance_m: float,
                          extent_m: float) -> float:
        """Half the height error made when the top lies ``extent_m`` behind the foot (taken as 1 std).

        The top ray crosses the foot's vertical at h_c - (h_c - H) d / (d + L) instead of H.
        """
        if not np.isfinite(distance_m):
            return float("inf")
        drop = max(camera_height_m - height_m, 0.0)
        return 0.5 * drop * extent_m / (distance_m + extent_m)


def metric_class(height_m: float, width_m: float) -> str:
    """Person / cyclist / vehicle / other from the geometry's height and the width at the foot.

    The width is the box's at the foot's distance: a person's stride, a bicycle's length seen
    from the side, a car's front or flank. A vehicle's geometry height reads high (its blob's top
    is the far roof edge), which only pushes it further from the upright classes.
    """
    if width_m >= CONSTANTS.vehicle_min_width_m or height_m > CONSTANTS.upright_height_m[1]:
        return "vehicle"
    if height_m < CONSTANTS.upright_height_m[0]:
        return "other"
    return "person" if width_m < CONSTANTS.person_max_width_m else "cyclist"


def _widths_at_ground(camera: CameraInfo, ground_xy: np.ndarray, widths_px: np.ndarray) -> np.ndarray:
    """Metres spanned by ``widths_px`` image pixels at each ground point's depth (NaN without one)."""
    points = np.column_stack([ground_xy, np.zeros(len(ground_xy))])
    depth = (points @ np.asarray(camera.R, float).T + np.asarray(camera.t, float).reshape(3))[:, 2]
    focal = float(np.asarray(camera.K, float)[0, 0])
    with np.errstate(invalid="ignore"):
        return np.where(depth > 0, widths_px * depth / focal, np.nan)


class NetworkScale:
    """Running median of geometry / network height on whole people; rescales network heights.

    Only people: their top is above their foot, so their geometry height is sound; a vehicle's
    is not (see ``horizontal_extent_m``). Nothing changes until ``scale_min_samples`` ratios
    are in. Vehicles keep their network height: the shipped model reads thin people far lower than big
    objects (trk_test40: rescaled like people, vehicles' single-frame median error went
    44 -> 62 cm; left alone, 49 cm).
    """

    def __init__(self):
        self.log_ratios: deque[float] = deque(maxlen=CONSTANTS.scale_window)

    @property
    def scale(self) -> float:
        if len(self.log_ratios) < CONSTANTS.scale_min_samples:
            return 1.0
        return float(np.exp(np.median(self.log_ratios)))

    @property
    def scale_noise(self) -> float:
        """Relative std of the network's scale: a prior until it is measured, then the median's
        standard error (1.2533 x 1.4826 MAD / sqrt(n))."""
        n = len(self.log_ratios)
        if n < CONSTANTS.scale_min_samples:
            return CONSTANTS.network_prior_scale_noise
        ratios = np.asarray(self.log_ratios)
        return float(1.2533 * 1.4826 * np.median(np.abs(ratios - np.median(ratios))) / np.sqrt(n))

    def rescale(self, detections: list[Detection]) -> None:
        """Learn from this frame's whole people (not from weak boxes that may lie on nothing), then
        replace each network height (vehicles' aside) by the rescaled one, its noise grown by the
        scale's uncertainty (source "geometry scale")."""
        for d in detections:
            network, geometry = d.heights.get(NETWORK), d.heights.get(GEOMETRY)
            if (d.cls == "person" and not d.continues_only and geometry is not None and network is not None
                    and np.isfinite(network.value_m) and network.value_m > 0):
                self.log_ratios.append(float(np.log(geometry.value_m / network.value_m)))
        scale, relative = self.scale, self.scale_noise
        for d in detections:
            network = d.heights.get(NETWORK)
            if d.cls == "vehicle" or network is None:
                continue      # learnt on thin people; the network reads big objects far less low
            height = network.value_m * scale
            noise = float(np.hypot(network.noise_m * scale, relative * height))
            d.add_height(NETWORK, Measurement(height, noise, source="geometry scale", bias_m=network.bias_m))
