"""Metres from HeightNet v2's ground-contact offsets: which camera, and the closed form with it.

The offsets are the network's; metres need the camera (``stages/ground_contact.py``). The camera
is the run's one camera (``stages.calibration.camera_for_run``: the same one the geometry channel
measures with), taken in this order:

1. a pose, exact: a calibration file's, or one in ``[camera]`` (height_m and pitch_deg, as
   ``heightpipe calibrate`` prints them), with the lens of the file or of ``camera.fov_deg``;
2. only the mounting height (``--camera-height``): pitch, roll and focal length from the
   network's camera heads, averaged over the frames (``stages/camera_heads.py``), with the
   heads' uncertainty (sharpened by the scene's straight lines when asked:
   ``stages/vertical_edges.py``); the focal length of an intrinsic calibration file when there
   is one.

A given camera comes first because it is exact and the heads are an estimate from pictures; the
heads come last but do not need anything beyond the one number most users know. With none of
these there is no scale at all, and the run stops with one line naming the flags, instead of
decoding with an assumed camera as v1 models do: a v2 network's heights would be wrong in shape
too (a wrong pitch bends them across the image), not just in scale.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from core.errors import ConfigError
from core.packets import CameraInfo, HeightCamera
from stages.calibration import angles_from_rotation, camera_centre, has_distortion
from stages.camera_heads import HeadsAverage, camera_from_heads
from stages.ground_contact import PinholeCamera, heights_from_offsets
from stages.heightnet_model import ModelOutput
from stages.vertical_edges import EdgeFit, FrameSamples, fit_to_edges

MAX_HEIGHT_M = 50.0
"""Decoded heights are clipped to [0, 50] m, as heightnet/contact_eval.py clips them: nothing
stands below the ground, and a contact point predicted near the horizon must not decode to
kilometres."""
NO_CAMERA = ("this height model (HeightNet v2) needs the camera to give metres: give --calibration FILE, "
             "or --camera-height M (camera.height_m; the network then estimates pitch, roll and focal "
             "length), or a pose in [camera] (height_m and pitch_deg)")


def camera_source(camera: CameraInfo, assumed_camera_ok: bool = False) -> str:
    """Where the decoding camera comes from (``HeightCamera.source``); ConfigError without one.

    ``assumed_camera_ok``: the camera height of a camera known to be assumed (source "none") is
    good enough for the heads: ``heightpipe calibrate`` wants only what stands above the ground.
    """
    if camera.R is not None and camera.t is not None and camera.K is not None:
        if camera.pose_from == "config":
            return "self" if camera.source == "self" else "config"
        return "calibration"
    if camera.height_m is not None and camera.height_m > 0:
        if camera.source != "none":
            return "heads"
        if assumed_camera_ok:
            return "assumed"
    raise ConfigError(NO_CAMERA)


def input_camera(camera: CameraInfo, width: int, height: int) -> PinholeCamera:
    """A posed run camera as the network's input sees it: the frame squashed to width x height."""
    pinhole = PinholeCamera(np.asarray(camera.K, np.float64), np.asarray(camera.R, np.float64),
                            camera_centre(camera))
    return pinhole.window(0, 0, camera.width, camera.height, width, height)


def input_intrinsics(camera: CameraInfo, width: int, height: int) -> np.ndarray:
    """The run camera's K for the frame squashed to width x height (the pose is not needed)."""
    lens = PinholeCamera(np.asarray(camera.K, np.float64), np.eye(3), np.zeros(3))
    return lens.window(0, 0, camera.width, camera.height, width, height).K


class ContactHeights:
    """Decodes each frame's offsets with the run's camera; holds the camera heads' running mean.

    One instance per camera and run: the average assumes every frame it sees is from one fixed
    camera. ``spread_scale`` (the model's ``camera_spread_scale``) widens the spread the heads
    report to what their errors are on cameras they never saw: learnt on the training cameras,
    their log-variances said about half of it for pitch and focal length. ``error_correlation``
    (the model's ``camera_error_correlation``) is how their errors go together, which the fit to
    the scene's straight lines needs (``vertical_edges``: True lets them sharpen the heads).
    """

    def __init__(self, assumed_camera_ok: bool = False, spread_scale: tuple[float, float, float] = (1.0, 1.0, 1.0),
                 error_correlation: np.ndarray | None = None, vertical_edges: bool = False):
        self.assumed_camera_ok = assumed_camera_ok
        self.spread_scale = np.asarray(spread_scale, np.float64)
        self.error_correlation = np.eye(3) if error_correlation is None else np.asarray(error_correlation, np.float64)
        self.heads = HeadsAverage()
        self.samples = FrameSamples() if vertical_edges else None
        self.edge_fit: EdgeFit | None = None

    def decode(self, output: ModelOutput, camera: CameraInfo, frame_size: tuple[int, int],
               image: np.ndarray | None = None) -> tuple[np.ndarray, HeightCamera]:
        """Metres (float32, frame_size = (width, height)) and the camera they were decoded with;
        ``image`` (the BGR frame) feeds the fit to the scene's lines when the camera comes from the heads."""
        source = camera_source(camera, self.assumed_camera_ok)
        in_h, in_w = output.offsets.shape[:2]
        if source in ("heads", "assumed"):
            pinhole, used = self._heads_camera(output, camera, in_w, in_h, image)
        else:
            pinhole, used = input_camera(camera, in_w, in_h), _given(camera, source)
        metres = np.clip(heights_from_offsets(pinhole, output.offsets), 0.0, MAX_HEIGHT_M)
        width, height = frame_size
        if (width, height) != (in_w, in_h):
            metres = cv2.resize(metres, (width, height), interpolation=cv2.INTER_LINEAR)
        return metres.astype(np.float32), used

    def heads_camera(self, output: ModelOutput, camera: CameraInfo, image: np.ndarray | None = None) -> HeightCamera:
        """The heads' camera (sharpened by the lines when asked) after this frame, as ``decode``
        would report it, without decoding the frame's heights: for callers after the camera only."""
        in_h, in_w = output.offsets.shape[:2]
        return self._heads_camera(output, camera, in_w, in_h, image)[1]

    def _heads_camera(self, output: ModelOutput, camera: CameraInfo, in_w: int, in_h: int,
                      image: np.ndarray | None) -> tuple[PinholeCamera, HeightCamera]:
        outputs = output.camera
        self.heads.add(outputs)
        mean, std = self.heads.mean, self.heads.std * self.spread_scale
        if self.heads.frames == 0:  # nothing finite from the heads yet: this frame's, whatever it is
            mean, std = np.asarray(outputs[:3], np.float64), np.full(3, np.inf)
        K = input_intrinsics(camera, in_w, in_h) if camera.lens_from_file and camera.K is not None else None
        focal_given = K is not None
        correlation = self.error_correlation
        if focal_given:  # the file's focal length, in image heights, known exactly
            log_focal = math.log(float(camera.K[1, 1]) / camera.height)
            mean, std, correlation = given_focal(mean, std, correlation, log_focal)
        if self.samples is not None and image is not None and self.samples.add(image, output.ground_logit):
            upright, ground, (width, height) = self.samples.segments()
            self.edge_fit = fit_to_edges(mean, std, correlation, upright, width, height, ground)
        edges, square = 0, False
        if self.edge_fit is not None:
            fit = self.edge_fit
            mean, std, edges, square = fit.values, fit.std, fit.edges, fit.square
        pinhole = camera_from_heads(mean, in_w, in_h, (camera.width, camera.height), camera.height_m, K)
        used = HeightCamera(
            source="heads" if camera.source != "none" else "assumed", height_m=float(camera.height_m),
            pitch_deg=math.degrees(mean[0]), roll_deg=math.degrees(mean[1]),
            focal_px=float(camera.K[1, 1]) if focal_given else math.exp(mean[2]) * camera.height,
            pitch_std_deg=math.degrees(std[0]), roll_std_deg=math.degrees(std[1]),
            focal_std_pct=0.0 if focal_given else math.expm1(std[2]) * 100.0,
            frames=self.heads.frames, focal_given=focal_given, edges=edges, square_families=square)
        return pinhole, used


def given_focal(mean: np.ndarray, std: np.ndarray, correlation: np.ndarray,
                log_focal: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The heads' (pitch, roll, log focal) mean, spread and correlation once the focal length is
    known (a calibration file's, in log image heights): Gaussian conditioning.

    Why not just replace the focal length: the heads' pitch error goes with their focal length's
    (correlation -0.81 on fresh cameras: the horizon, f tan pitch, is what they see best), so how
    far their focal length was off says how far their pitch is, and by how much less to doubt it.
    """
    mean, std = np.asarray(mean, np.float64).copy(), np.asarray(std, np.float64).copy()
    if not (np.all(np.isfinite(std)) and std[2] > 0):
        mean[2], std[2] = log_focal, 1e-6
        return mean, std, np.eye(3)
    covariance = np.diag(std) @ np.asarray(correlation, np.float64) @ np.diag(std)
    cross = covariance[:2, 2]
    mean[:2] += cross / covariance[2, 2] * (log_focal - mean[2])
    rest = covariance[:2, :2] - np.outer(cross, cross) / covariance[2, 2]
    std[:2] = np.sqrt(np.maximum(np.diag(rest), 1e-12))
    mean[2], std[2] = log_focal, 1e-6
    conditioned = np.eye(3)
    conditioned[0, 1] = conditioned[1, 0] = rest[0, 1] / (std[0] * std[1])
    return mean, std, conditioned


def read_scene(model, images, camera: CameraInfo) -> tuple[HeightCamera | None, ContactHeights]:
    """The camera a run told only ``camera.height_m`` ends with over ``images`` (BGR frames):
    ``model``'s (a v2 ``HeightNetModel``) camera heads sharpened by the scene's straight lines
    (None without images; what ``heightpipe calibrate --camera-height`` prints as a pose), and
    the reader that read it: its ``samples`` (the scene's median) and ``edge_fit`` (the lines that
    agreed) are what a picture of the reading shows.

    Frames of a lens with distortion (a calibration file's) are undistorted first: straight lines
    are straight only there, and a run with the camera read measures on undistorted frames.
    """
    from stages.undistortion import Undistorter

    if has_distortion(camera):
        undistorter = Undistorter(camera)
        images, camera = (undistorter.undistort(image) for image in images), undistorter.camera
    contact = ContactHeights(spread_scale=model.info.camera_spread_scale,
                             error_correlation=model.info.camera_error_correlation, vertical_edges=True)
    used = None
    for image in images:
        used = contact.heads_camera(model.run(image), camera, image)
    return used, contact


def _given(camera: CameraInfo, source: str) -> HeightCamera:
    pitch, roll, _ = angles_from_rotation(camera.R)
    return HeightCamera(source=source, height_m=float(camera_centre(camera)[2]), pitch_deg=pitch,
                        roll_deg=roll, focal_px=float(camera.K[1, 1]))
