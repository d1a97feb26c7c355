"""Height inference: a dense map of metres above the ground for every pixel."""

from __future__ import annotations

from core.packets import FramePacket
from stages.heightnet_model import HeightNetModel


class HeightEstimator:
    """Height map in metres from the network, zero on the ground plane.

    Zeroing the ground keeps the two heads consistent: a pixel the ground stage calls ground
    has no height, so downstream object extraction never sees a raised patch of road.
    """

    def __init__(self, model: HeightNetModel):
        self.model = model

    def process(self, packet: FramePacket) -> FramePacket:
        output = self.model.infer(packet.frame)
        height = self.model.to_metres(output.height, packet.camera)
        if packet.ground_mask is not None:
            height = height.copy()
            height[packet.ground_mask] = 0.0
        packet.height_map = height
        return packet

    def close(self) -> None:
        """Nothing to release (the Stage contract, core/stage.py)."""
