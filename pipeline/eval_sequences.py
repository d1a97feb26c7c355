"""Running ``heightpipe run``'s stages over one generator sequence, keeping what evaluation needs.

A sequence of a synthetic dataset (``synth.dataset``) goes through the same stage chain as a
video (``pipeline.stage_chain``), with the dataset's exact camera or, as most users have it, its
mounting height alone (``known = "height"``), or that height and the pose read from the scene
(``"scene"``); each frame leaves a ``FrameRecord``: the
ground-truth boxes, the confirmed tracks and the detections.
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from core.config import Config, model_for_camera
from core.packets import NETWORK
from pipeline.track_backfill import backfilled
from synth.dataset import COARSE_CLASS, PARKED_VEHICLE_ID

# The classes evaluation scores: the generator's (pedestrian, car, ...) and the pipeline's
# (object extraction's ``coarse_class``) both come down to these; anything else is "other".
EVAL_CLASSES = ("person", "cyclist", "vehicle")


def eval_class(name: str) -> str:
    """person / cyclist / vehicle / other, from a generator class or a pipeline detection's class."""
    name = COARSE_CLASS.get(name, name)
    return name if name in EVAL_CLASSES else "other"


@dataclass
class TruthBox:
    object_id: int
    cls: str
    """Coarse class: person, cyclist, vehicle."""
    box: tuple[float, float, float, float]
    visibility: float
    height_m: float
    speed_mps: float = float("nan")
    """Ground speed around this frame (``ground_speeds``): tells a standing person from a walker;
    NaN where the generator wrote no ground position."""


@dataclass
class OutputBox:
    track_id: int
    box: tuple[float, float, float, float]
    height_m: float
    height_std_m: float
    cls: str
    height_source: str
    updated: bool
    filled: bool = False
    """Its box interpolated between the track's detections around this frame (``Track.filled``)."""


@dataclass
class DetectionBox:
    box: tuple[float, float, float, float]
    height_m: float
    cls: str = "other"
    """Evaluation class (``eval_class``) that object extraction gave it."""


def detection_record(detection) -> DetectionBox:
    """What evaluation keeps of one pipeline detection (``core.packets.Detection``): box, height,
    class. The one place that reads a detection, so a change to its fields is one edit here."""
    return DetectionBox(tuple(map(float, detection.box)), detection.height(NETWORK), eval_class(detection.cls))


@dataclass
class FrameRecord:
    truth: list[TruthBox]
    tracks: list[OutputBox]
    """Confirmed tracks, updated or predicted."""
    detections: list[DetectionBox]
    region: np.ndarray | None = None
    """Don't-care pixels (the parked vehicles the generator gives no box), ``np.packbits`` along
    rows; None where there are none (``dont_care_region``)."""

    @property
    def seen_tracks(self) -> list[OutputBox]:
        """The tracks updated with a detection this frame, or with boxes interpolated between the
        detections around it: the boxes the MOT metrics score (a box predicted from one side only
        is the tracker's guess, not a report)."""
        return [o for o in self.tracks if o.updated or o.filled]


@dataclass
class SequenceRun:
    name: str
    camera_height_m: float
    weather: str
    time_of_day: str
    fps: float = 0.0
    frames: list[FrameRecord] = field(default_factory=list)


class OracleHeights:
    """Stand-in for ground segmentation + height inference: the generator's true maps."""

    def __init__(self, sequence):
        self.sequence = sequence

    def process(self, packet):
        truth = self.sequence.frame(packet.frame.index)
        packet.height_map = np.nan_to_num(truth.height_m, nan=0.0).astype(np.float32)
        packet.ground_mask = truth.ground.astype(bool)
        return packet

    def close(self) -> None:
        """Nothing to release (the Stage contract, core/stage.py)."""


def ground_speeds(sequence, index: int) -> dict[int, float]:
    """Each object's ground speed (m/s) at frame ``index``: its ground position's change from the
    frame before to the frame after (one side at a sequence's ends); objects without a ground
    position on either side are left out."""
    def positions(i: int) -> dict[int, np.ndarray]:
        if not 0 <= i < len(sequence):
            return {}
        return {o.id: np.asarray(o.ground_xy_m, dtype=float) for o in sequence.objects(i)
                if np.all(np.isfinite(o.ground_xy_m))}

    before, now, after = positions(index - 1), positions(index), positions(index + 1)
    speeds = {}
    for object_id in now:
        first = before.get(object_id, now[object_id])
        last = after.get(object_id, now[object_id])
        frames = (object_id in before) + (object_id in after)
        if frames:
            speeds[object_id] = float(np.hypot(*(last - first)) / frames * sequence.meta.fps)
    return speeds


def dont_care_region(semantic: np.ndarray) -> np.ndarray | None:
    """A frame's parked-vehicle pixels, packed (``FrameRecord.region``), or None."""
    parked = semantic == PARKED_VEHICLE_ID
    return np.packbits(parked, axis=1) if parked.any() else None


CAMERA_KNOWN = ("true", "height", "scene")
"""What a run is told of a sequence's camera: its exact pose and lens, its height only (the run
then reads the rest from its first frames, as ``heightpipe run --camera-height H`` does), or its
height and the pose ``heightpipe calibrate --camera-height`` reads from all of its frames."""


def camera_info(sequence, config: Config | None = None, known: str = "true"):
    """The sequence's camera as the run is told it: exact (``"true"``), or, as ``heightpipe run
    --camera-height H`` is told it, the height alone with ``[camera]``'s default lens
    (``"height"``: no pose), or that height with the pose ``heightpipe calibrate --camera-height``
    prints (``"scene"``). What the run makes of it: ``run_setup``."""
    from core.packets import CameraInfo
    from stages.calibration import camera_for_run

    camera = sequence.meta.camera
    if known == "height":
        return camera_for_run(told_height_only(sequence, config), camera.width, camera.height)
    if known == "scene":
        return run_setup(sequence, config or Config(), "scene")[1]
    if known != "true":
        raise ValueError(f"camera known as {known!r}, not one of {CAMERA_KNOWN}")
    return CameraInfo(width=camera.width, height=camera.height, K=np.asarray(camera.K, float),
                      R=np.asarray(camera.R, float), t=np.asarray(camera.t, float).reshape(3),
                      height_m=float(camera.height_m), source="calibration")


def run_setup(sequence, config: Config, known: str = "true"):
    """The config and camera ``heightpipe run`` works with, told ``known`` of the sequence's camera.

    Told only the height, the run reads pitch, roll and focal length from frames spread over its
    start (``pipeline/scene_camera.py``; ``[camera] read_scene_frames``) and runs posed, or keeps
    v2's camera heads where that is off; ``"scene"`` reads them from every frame. The model is
    the one such a run picks (``core.config.model_for_camera``).
    """
    import cv2

    from pipeline.scene_camera import pose_from_scene, reads_scene
    from stages.calibration import camera_for_run
    from stages.capture import background_indices

    if known == "true":
        return config, camera_info(sequence)
    if known not in CAMERA_KNOWN:
        raise ValueError(f"camera known as {known!r}, not one of {CAMERA_KNOWN}")
    told = replace(config, camera=told_height_only(sequence, config))
    indices: list[int] = []
    if known == "scene":
        indices = list(range(len(sequence)))
    elif reads_scene(told):
        indices = background_indices(len(sequence), sequence.meta.fps, told.camera.read_scene_frames,
                                     told.camera.read_scene_s)
    images = [cv2.cvtColor(sequence.frame(i).rgb, cv2.COLOR_RGB2BGR) for i in indices]
    # calibrate's snippet poses a run even without lines (it says they were missing).
    config = model_for_camera(pose_from_scene(told, images, needs_lines=known == "height")[0])
    camera = sequence.meta.camera
    return config, camera_for_run(config.camera, camera.width, camera.height)


def told_height_only(sequence, config: Config | None = None):
    """``[camera]`` as ``heightpipe run --camera-height H`` leaves it: the sequence's true height,
    no pitch, no calibration file (the default lens)."""
    return replace((config or Config()).camera, height_m=float(sequence.meta.camera.height_m), pitch_deg=0.0,
                   roll_deg=0.0, calibration="")


def build_eval_chain(sequence, config: Config, heights: str, geometry: bool, known: str = "true", camera=None):
    """``heightpipe run``'s stages for a generator sequence (``pipeline.stage_chain``): with
    ``camera`` None, for the config and camera ``run_setup`` gives a run told ``known``; else
    for ``config`` and ``camera`` as given (``run_setup``'s).

    With ``heights="oracle"`` the true height and ground maps stand in for the network, and the
    stages that correct the network's scale and bias are told there is none to correct.
    """
    from pipeline.stage_chain import build_stage_chain

    if camera is None:
        config, camera = run_setup(sequence, config, known)
    if heights == "oracle":
        # True heights are metric: there is no network scale to learn (nor to doubt), nor a
        # per-object bias for the height filter to learn.
        config = replace(config, camera=replace(config.camera, rescale_network=False),
                         tracking=replace(config.tracking, network_bias_share=0.0))
    return build_stage_chain(config, camera, heights=OracleHeights(sequence) if heights == "oracle" else None,
                             geometry=geometry)


def prime_sequence_background(sequence, chain, config: Config) -> None:
    """Seeds the object extractor's background model as ``heightpipe run`` does for files."""
    import cv2

    from stages.capture import background_indices

    chain.prime([cv2.cvtColor(sequence.frame(i).rgb, cv2.COLOR_RGB2BGR)
                 for i in background_indices(len(sequence), sequence.meta.fps,
                                             config.objects.background_prime_frames,
                                             config.objects.background_prime_s)])


def sequence_packets(sequence, chain, max_frames: int = 0, camera=None):
    """Each frame of a generator sequence through the stage chain: yields (truth frame, packet).

    ``camera`` is the run's (``camera_info``; the exact one when None). The stages are closed
    when the frames run out or the caller closes the generator.
    """
    import cv2

    from core.packets import Frame, FramePacket

    camera = camera_info(sequence) if camera is None else camera
    count = len(sequence) if max_frames <= 0 else min(max_frames, len(sequence))
    try:
        for index in range(count):
            truth_frame = sequence.frame(index)
            image = cv2.cvtColor(truth_frame.rgb, cv2.COLOR_RGB2BGR)
            yield truth_frame, chain.process(FramePacket(frame=Frame(index, truth_frame.time_s, image), camera=camera))
    finally:
        chain.close()


def run_sequence(sequence, config: Config, heights: str = "model", geometry: bool = True,
                 max_frames: int = 0, record: Path | None = None, known: str = "true") -> SequenceRun:
    """Runs the tracking pipeline over one generator sequence and keeps what evaluation needs
    (``known``: what the run is told of the camera, ``CAMERA_KNOWN``)."""
    meta = sequence.meta
    run = SequenceRun(sequence.name, float(meta.camera.height_m), meta.weather, meta.time_of_day)
    config, camera = run_setup(sequence, config, known)
    chain = build_eval_chain(sequence, config, heights, geometry, camera=camera)
    prime_sequence_background(sequence, chain, config)
    sink = _open_recording(record, config, sequence.name) if record else None
    start = time.perf_counter()
    try:
        with contextlib.closing(sequence_packets(sequence, chain, max_frames, camera)) as packets:
            for truth_frame, packet in backfilled(packets, lambda pair: pair[1], config.tracking.backfill,
                                                  config.tracking.fill_gaps_s, config.tracking.smooth_s):
                if sink is not None:
                    sink.write(packet)
                speeds = ground_speeds(sequence, packet.frame.index)
                run.frames.append(FrameRecord(
                    truth=[TruthBox(o.id, eval_class(o.cls), tuple(map(float, o.box)),
                                    float(o.visible_fraction), float(o.height_m),
                                    speeds.get(o.id, float("nan")))
                           for o in sequence.objects(packet.frame.index)],
                    tracks=[OutputBox(t.track_id, tuple(map(float, t.box)), t.height_m, t.height_std_m,
                                      t.cls, t.height_source, t.updated, t.filled)
                            for t in packet.tracks if t.confirmed],
                    detections=[detection_record(d) for d in packet.detections],
                    region=dont_care_region(truth_frame.semantic),
                ))
    finally:
        if sink is not None:
            sink.close()
    run.fps = len(run.frames) / max(time.perf_counter() - start, 1e-9)
    return run


def _open_recording(path: Path, config: Config, name: str):
    from stages.rerun_sink import RerunSink

    path.parent.mkdir(parents=True, exist_ok=True)
    return RerunSink(path, "save", config.output, name)
