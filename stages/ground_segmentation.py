"""Ground-plane segmentation: which pixels belong to the plane heights are measured from."""

from __future__ import annotations

from core.config import GroundConfig
from core.errors import ConfigError
from core.packets import FramePacket
from stages.heightnet_model import HeightNetModel

METHODS = ("model", "height")


class GroundSegmenter:
    """Ground mask from the network's ground head, or from the height map itself.

    'model' uses the ground head (it sees texture and context, so a low kerb or a bench
    seat is not mistaken for ground); 'height' thresholds the height map and exists for
    models exported without a trustworthy ground head.
    """

    def __init__(self, config: GroundConfig, model: HeightNetModel):
        if config.method not in METHODS:
            raise ConfigError(f"ground.method must be one of {METHODS}, got {config.method!r}")
        if config.method == "height" and model.info.contact:
            # v2 heights exist only after the height stage has chosen the camera, and every v2
            # export trains its ground head (heightnet/contact_losses.py): 'height' has no use.
            raise ConfigError("ground.method = 'height' is for v1 height models; a ground-contact "
                              "(HeightNet v2) model needs ground.method = 'model'")
        self.config = config
        self.model = model

    def process(self, packet: FramePacket) -> FramePacket:
        output = self.model.infer(packet.frame)
        if self.config.method == "model":
            packet.ground_mask = output.ground_at_least(self.config.probability_threshold)
        else:
            metres = self.model.to_metres(output.height, packet.camera)
            packet.ground_mask = metres < self.config.height_threshold_m
        return packet

    def close(self) -> None:
        """Nothing to release (the Stage contract, core/stage.py)."""
