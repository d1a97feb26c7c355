"""Lens undistortion of whole frames, before the network sees them.

The network was trained on pinhole renders, and the ground is only a plane in a pinhole
image: with strong distortion (Oxford Town Centre: k1 = -0.60, k2 = 4.70) heights bend
towards the image edges. The undistorted frame keeps the calibrated K and size, so pixels of
the undistorted frame and ``packet.camera`` (now without ``dist``) agree everywhere after this
stage; the geometry stage only undistorts points itself when this stage did not run.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from core.errors import SourceError
from core.packets import CameraInfo, FramePacket


class Undistorter:
    """Remaps every frame through maps computed once; sets ``packet.camera`` to the undistorted camera.

    Parameters
    ----------
    camera : CameraInfo
        The run's camera with ``K`` and ``dist`` of the raw frames.
    """

    def __init__(self, camera: CameraInfo):
        if camera.K is None or camera.dist is None:
            raise ValueError("Undistorter needs a camera with K and distortion coefficients")
        self.size = (camera.width, camera.height)
        # Same K for the undistorted image: points keep their scale, and the few pixels of the
        # border the remap cannot fill stay black rather than cropping or shrinking the view.
        self.map_x, self.map_y = cv2.initUndistortRectifyMap(
            camera.K, np.asarray(camera.dist, float), None, camera.K, self.size, cv2.CV_16SC2)
        self.camera = dataclasses.replace(camera, dist=None)
        """The camera of the undistorted frames."""
        self.image_valid = self.undistort(np.full((self.size[1], self.size[0]), 255, np.uint8)) == 255
        """Pixels of the undistorted frame that come from the raw frame (not the black border)."""

    def undistort(self, image: np.ndarray) -> np.ndarray:
        return cv2.remap(image, self.map_x, self.map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)

    def process(self, packet: FramePacket) -> FramePacket:
        image = packet.frame.image
        if (image.shape[1], image.shape[0]) != self.size:
            raise SourceError(f"frame {packet.frame.index} is {image.shape[1]}x{image.shape[0]}, "
                              f"the calibration is for {self.size[0]}x{self.size[1]}")
        packet.frame.image = self.undistort(image)
        packet.camera = self.camera
        packet.image_valid = self.image_valid
        return packet

    def prime(self, images: list[np.ndarray]) -> list[np.ndarray]:
        """Look-ahead frames undistorted, so later stages are primed in the run's geometry."""
        return [self.undistort(image) for image in images]

    def close(self) -> None:
        """Nothing to release (the Stage contract, core/stage.py)."""
