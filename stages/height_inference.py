"""Height inference: a dense map of metres above the ground for every pixel."""

from __future__ import annotations

import numpy as np

from core.packets import CameraInfo, FramePacket
from stages.contact_heights import ContactHeights, camera_source
from stages.heightnet_model import HeightNetModel


class HeightEstimator:
    """Height map in metres from the network, zero on the ground plane.

    Zeroing the ground keeps the two heads consistent: a pixel the ground stage calls ground
    has no height, so downstream object extraction never sees a raised patch of road.

    A v1 network's heights need only the camera height; a v2 network's ground-contact offsets
    need the whole camera (``stages/contact_heights.py``), and the packet then says which one
    was used (``packet.height_camera``). A network with a detection head also hands on its
    detections (``packet.network_detections``, frame pixels). ``camera`` (the run's) lets a v2
    model without any camera fail when the stage is built, not at the first frame;
    ``assumed_camera_ok`` lets it decode with an assumed camera height (``heightpipe calibrate``);
    ``vertical_edges`` lets the scene's straight lines sharpen the camera heads' estimate.
    """

    def __init__(self, model: HeightNetModel, camera: CameraInfo | None = None,
                 assumed_camera_ok: bool = False, vertical_edges: bool = False):
        self.model = model
        self.contact = (ContactHeights(assumed_camera_ok, model.info.camera_spread_scale,
                                       model.info.camera_error_correlation, vertical_edges)
                        if model.info.contact else None)
        if self.contact is not None and camera is not None:
            camera_source(camera, assumed_camera_ok)

    def process(self, packet: FramePacket) -> FramePacket:
        output = self.model.infer(packet.frame)
        if self.contact is not None:
            h, w = packet.frame.image.shape[:2]
            height, packet.height_camera = self.contact.decode(output, packet.camera, (w, h), packet.frame.image)
        else:
            height = self.model.to_metres(output.height, packet.camera)
        if packet.ground_mask is not None:
            # A new array (``height`` may be the model's cached output), made in one pass.
            height = np.where(packet.ground_mask, np.float32(0.0), height)
        packet.height_map = height
        packet.network_detections = output.detections
        return packet

    def close(self) -> None:
        """Nothing to release (the Stage contract, core/stage.py)."""
