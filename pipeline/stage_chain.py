"""The one place the stages are assembled and the one loop that passes a frame through them.

``heightpipe run``, ``eval-tracks``, ``calibrate`` and the benchmarks all build their stages
with ``build_stage_chain`` and push frames through ``StageChain.process``, so what is measured
in evaluation is what runs in production. The order is the one docs/design.md lists:

(undistortion) → ground segmentation → height inference → keypoints → feature matching →
object extraction → (geometry) → tracking

Undistortion runs when the camera has lens distortion; geometry when the camera is calibrated
(its ground plane is known) and the caller wants it. Evaluation on generator data may replace
ground segmentation and height inference with the true maps (``heights=``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Iterable, Iterator

import numpy as np

from core.config import Config
from core.errors import ConfigError
from core.packets import CameraInfo, Frame, FramePacket
from core.stage import PrimedStage, Stage

if TYPE_CHECKING:
    from stages.heightnet_model import HeightNetModel


@dataclass
class StageChain:
    """Named stages run in order on every frame; each stage's time goes into ``packet.timings_ms``."""

    stages: list[tuple[str, Stage]]

    def prime(self, images: list[np.ndarray]) -> None:
        """Show frames read ahead to the stages that want them (undistortion first, then objects)."""
        for _, stage in self.stages:
            if isinstance(stage, PrimedStage):
                images = stage.prime(images)

    def process(self, packet: FramePacket) -> FramePacket:
        for name, stage in self.stages:
            t0 = time.perf_counter()
            packet = stage.process(packet)
            packet.timings_ms[name] = (time.perf_counter() - t0) * 1000.0
        return packet

    def run(self, frames: Iterable[Frame], camera: CameraInfo) -> Iterator[FramePacket]:
        """Each frame's packet after all stages, one at a time."""
        for frame in frames:
            yield self.process(FramePacket(frame=frame, camera=camera))

    def stage(self, name: str) -> Stage:
        return dict(self.stages)[name]

    def without(self, name: str) -> "StageChain":
        """The same chain less one stage (a benchmark that stops before tracking)."""
        return StageChain([(n, s) for n, s in self.stages if n != name])

    def close(self) -> None:
        close_all([stage for _, stage in self.stages])


def load_height_model(config: Config) -> HeightNetModel:
    """The configured network, checked against ``[objects]``, and run once on a blank image.

    ONNX Runtime plans its memory on the first run: doing it here, before a live stream is
    opened, keeps it out of the time in which the stream's frames pile up unread.
    """
    from stages.box_refinement import refiner_for
    from stages.heightnet_model import HeightNetModel
    from stages.network_objects import check_classes, min_score

    model = HeightNetModel(config.height.model, config.height.threads, min_score(config.objects),
                           config.height.input_width, mirror=config.height.mirror)
    if config.objects.source == "network":
        if not model.info.detection:
            raise ConfigError(f"objects.source = 'network' needs a height model with a detection head "
                              f"(a v2 export trained with detection = true); {model.path} has none")
        check_classes(config.objects, model.info.detection_classes, str(model.path))
        # Only the network's objects read its boxes: in blobs mode refining them is work for nothing.
        model.box_refiner = refiner_for(config.height.box_refiner, model.path)
    model.run(np.zeros((model.info.input_height, model.info.input_width, 3), np.uint8))
    return model


def import_stages() -> None:
    """Import every stage module ``build_stage_chain`` may use (~0.3 s) without building one.

    The runner does this before it opens a live stream, whose frames pile up from then on.
    """
    import stages.calibration  # noqa: F401
    import stages.feature_matching  # noqa: F401
    import stages.geometry  # noqa: F401
    import stages.ground_segmentation  # noqa: F401
    import stages.height_inference  # noqa: F401
    import stages.object_extraction  # noqa: F401
    import stages.tracking  # noqa: F401
    import stages.undistortion  # noqa: F401


def build_stage_chain(config: Config, camera: CameraInfo, heights: Stage | None = None,
                      geometry: bool = True, assumed_camera_ok: bool = False,
                      model: HeightNetModel | None = None) -> StageChain:
    """The stages for this camera and configuration.

    Parameters
    ----------
    config : Config
        Every stage reads its own section.
    camera : CameraInfo
        The run's camera: lens distortion adds undistortion, a known ground plane adds geometry.
    heights : Stage, optional
        Stand-in for ground segmentation and height inference (evaluation with the generator's
        true maps); by default the shipped network fills both.
    geometry : bool
        Fuse the calibrated-camera geometry height where the camera allows it.
    assumed_camera_ok : bool
        A ground-contact (v2) model may decode with the assumed camera height of a camera with
        no height given (``heightpipe calibrate``, which needs only what stands above the
        ground); otherwise such a model without a camera is a ConfigError.

    model : HeightNetModel, optional
        The network from ``load_height_model`` when the caller loaded it already (the runner
        does, before it opens the source); loaded here otherwise.

    ``objects.source = "network"`` needs a model with a detection head (a ConfigError names the
    model otherwise); a ``heights`` stand-in gives the objects only the network detections it
    puts in ``packet.network_detections`` (none for the generator's true maps).
    """
    from stages.calibration import has_distortion, is_calibrated
    from stages.feature_matching import FeatureMatcher, KeypointDetector
    from stages.object_extraction import ObjectExtractor
    from stages.tracking import TrackingStage

    stages: list[tuple[str, Stage]] = []
    if heights is None:
        from stages.ground_segmentation import GroundSegmenter
        from stages.height_inference import HeightEstimator

        model = model or load_height_model(config)
        height_stages = [("ground", GroundSegmenter(config.ground, model)),
                         ("height", HeightEstimator(model, camera, assumed_camera_ok, config.height.vertical_edges))]
    else:
        height_stages = [("heights", heights)]
    if has_distortion(camera):
        from stages.undistortion import Undistorter

        stages.append(("undistortion", Undistorter(camera)))
    stages += height_stages
    stages += [
        ("keypoints", KeypointDetector(config.matching, config.ground)),
        ("matching", FeatureMatcher(config.matching, config.ground)),
        ("objects", ObjectExtractor(config.objects, config.ground)),
    ]
    if geometry and is_calibrated(camera):
        from stages.geometry import GeometryMeasurer

        stages.append(("geometry", GeometryMeasurer(config.camera)))
    stages.append(("tracking", TrackingStage(config.tracking)))
    if config.rules:
        from stages.height_rules import HeightRules

        stages.append(("rules", HeightRules(config.rules, is_calibrated(camera))))
    return StageChain(stages)


def close_all(parts: list[object]) -> None:
    """Close every part even if one fails, so one broken sink cannot cost the others' files."""
    errors = []
    for part in parts:
        close = getattr(part, "close", None)
        if close is None:
            continue
        try:
            close()
        except Exception as exc:  # re-raised below, after the others are closed
            errors.append(exc)
    if errors:
        raise errors[0]
