"""The ONNX HeightNet model as the run-time stages see it.

One network has two heads (height and ground), and two stages read them, so both hold the
same ``HeightNetModel`` and it caches its result for the frame being processed: the
network runs once per frame. Everything about the model's input and output (size,
normalisation, units) is read from metadata stored in the ONNX file, never hard-coded.

Two generations of network: v1 (``heightpipe.output_units`` "metres" or
"camera_height_fraction") outputs ``height``; v2 ("ground_contact_offsets",
heightnet/contact_export.py) outputs ``offsets`` and ``camera`` instead, which become metres only
with a camera (``stages/contact_heights.py``). Outputs are read by name and any other output is
left alone, so a network that gains heads still loads. A v2 network whose metadata
(``heightpipe.outputs``) lists a detection head (``centre_logit`` with its classes and stride, and
``box``) also gives its detections, decoded here (``stages/centre_detections.py``) in frame pixels;
with a big-object head (``big_centre_logit``, ``big_box``) its peaks join them, strongest first.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import cv2
import numpy as np

from core.errors import ConfigError, ModelError
from core.packets import CameraInfo, Frame, NetworkDetections
from stages.box_refinement import BoxRefiner
from stages.centre_detections import CentreDetections, centre_detections, in_frame, with_big_objects
from stages.mirrored_views import averaged_with_mirror, mirror_input, mirror_problem, unmirrored_outputs
from stages.onnx_session import cpu_session

SHIPPED_MODEL = Path(__file__).resolve().parent / "models" / "heightnet.onnx"
SHIPPED_INT8_MODEL = SHIPPED_MODEL.with_name("heightnet_int8.onnx")
"""The shipped model quantised to INT8 (heightnet/quantize.py): ``height.model = "int8"``."""
SHIPPED_V2_MODEL = SHIPPED_MODEL.with_name("heightnet_v2.onnx")
"""HeightNet v2 (ground-contact offsets, camera heads, detection head) as exported from the
committed training state (690,000 images): ``height.model = "v2"``, and the model of a run told
only its camera's height (``core.config.model_for_camera``)."""
NAMED_MODELS = {"v1": SHIPPED_MODEL, "int8": SHIPPED_INT8_MODEL, "v2": SHIPPED_V2_MODEL}
CONTACT_UNITS = "ground_contact_offsets"
"""HeightNet v2's units (heightnet/contact_export.py writes them)."""
PREVIOUS_INPUT = "previous_image"
"""The second input of a v2 network whose detection head reads motion: the frame before, prepared
as the image is (``heightnet/contact_model.py``, ``motion_channels``)."""
OUTPUT_UNITS = ("metres", "camera_height_fraction", CONTACT_UNITS)
CAMERA_HEAD_SIZE = 6
"""v2's ``camera`` output: pitch, roll, log focal length in image heights, their log-variances."""
BOX_SIZE = 4
"""The detection head's ``box`` output: centre dx, dy from the cell centre, width, height."""


def model_file(name: str | Path) -> Path:
    """The file ``height.model`` names: "" = the shipped v1 model (``core.config.model_for_camera``
    chose before: v2 for a run told only its camera's height), a name of ``NAMED_MODELS``, else a path."""
    return NAMED_MODELS.get(str(name)) or (Path(name) if name else SHIPPED_MODEL)


@dataclass(frozen=True)
class HeightNetModelConstants:
    """Fixed numbers of reading the network (the rule is in docs/design.md, Configuration)."""

    # Peaks decoded from the detection head per frame at most, the strongest first: CenterNet's
    # 100 (Zhou et al. 2019), more than a street camera's view holds.
    max_detections: int = 100
    # Weakest peak decoded where the caller names no floor (``objects`` passes its lowest
    # threshold): weaker peaks of a trained head are background.
    detection_min_score: float = 0.1
    # The big-object head's boxes shorter than this (input pixels) are dropped: it was taught
    # objects this tall and more (``heightnet.detection_targets.BIG_MIN_PX`` is this number), and
    # below that its coarse boxes only compete with the small head's finer ones.
    big_min_height_px: float = 64.0
    # ``ModelOutput.ground_at_least`` compares logits, not probabilities, except within this
    # margin of the threshold's logit, where it evaluates the sigmoid itself: float32 rounding
    # moves a probability by a few 1e-8, the margin by at least 1e-4 (thresholds 0.01-0.99).
    logit_margin: float = 0.01
    threshold_range: tuple[float, float] = (0.01, 0.99)
    # An input size other than the trained one is rounded to a multiple of this: the v2 trunk
    # halves the image four times (its deepest features are 1/16 of the input).
    size_multiple: int = 16
    # ONNX Runtime threads where none are asked for (``threads = 0``), at most the cores there are.
    # The overlapped run's other stages keep a core busy beside the network (~21 ms a frame at
    # 640x360 on two cores): v1 (~22 ms) ran faster on one thread, which leaves them that core;
    # v2 (~30 ms on one thread) is the slower of the two and ran faster on two (docs/results.md,
    # 2026-12-05, sixteenth session).
    auto_threads_v1: int = 1
    auto_threads_v2: int = 2


CONSTANTS = HeightNetModelConstants()


@dataclass
class ModelInfo:
    """What the ONNX metadata says about the model (see heightnet/export.py)."""

    input_width: int
    input_height: int
    mean: tuple[float, float, float]
    std: tuple[float, float, float]
    output_units: str
    architecture: str
    color_order: str = "RGB"
    detection_classes: tuple[str, ...] = ()
    """The detection head's classes, in the order of ``centre_logit``'s channels (() = no head)."""
    detection_stride: int = 0
    """Input pixels per cell of the detection head's outputs."""
    big_detection_stride: int = 0
    """Input pixels per cell of the big-object head's outputs (0 = the network has none)."""
    camera_spread_scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """v2: how much wider the camera heads' errors on cameras they never saw are than the spread
    they report (pitch, roll, log focal length; ``python -m heightnet.camera_fresh``); 1 where
    not measured."""
    camera_error_correlation: tuple[tuple[float, ...], ...] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    """v2: the correlation of the camera heads' errors (pitch, roll, log focal length) on cameras
    they never saw (the same tool); independent where not measured."""

    @property
    def contact(self) -> bool:
        """A HeightNet v2 network: ground-contact offsets and camera heads, no height output."""
        return self.output_units == CONTACT_UNITS

    @property
    def detection(self) -> bool:
        """The network has a detection head (v2 metadata lists ``centre_logit``)."""
        return bool(self.detection_classes)


@dataclass
class ModelOutput:
    """Network outputs. The ground logit is resized to the frame, and so is v1's height
    (model units); v2's offsets stay at the input size, in input pixels, because the closed form
    that makes them metres works on the camera of the image they were predicted on."""

    height: np.ndarray | None
    ground_logit: np.ndarray
    """Frame size; ``ground_probability`` is its sigmoid, made only when asked for."""
    offsets: np.ndarray | None = None
    """v2: input H x W x 2 (du, dv) to each pixel's ground-contact point, input pixels."""
    camera: np.ndarray | None = None
    """v2: the camera heads' 6 numbers (``CAMERA_HEAD_SIZE``)."""
    detections: NetworkDetections | None = None
    """v2 with a detection head: its peaks at or above the model's ``detection_min_score``, in
    frame pixels (None without a head)."""

    @cached_property
    def ground_probability(self) -> np.ndarray:
        """P(ground) per frame pixel (float32)."""
        return _sigmoid(self.ground_logit)

    def ground_at_least(self, threshold: float) -> np.ndarray:
        """``ground_probability >= threshold``, bit for bit, without a sigmoid over every pixel.

        The sigmoid is monotonic: a pixel whose logit is clearly above the threshold's logit is
        ground, one clearly below is not; only those within ``CONSTANTS.logit_margin`` of it get
        the float32 sigmoid that ``ground_probability`` computes. The ground stage runs this on
        every frame (1920x1080: 7 ms of sigmoid per frame, 2 ms of comparisons).
        """
        low, high = CONSTANTS.threshold_range
        if not low <= threshold <= high or "ground_probability" in self.__dict__:
            return self.ground_probability >= threshold
        edge = math.log(threshold / (1.0 - threshold))
        logit = self.ground_logit
        mask = logit > edge
        near = (logit >= edge - CONSTANTS.logit_margin) & (logit <= edge + CONSTANTS.logit_margin)
        near = np.flatnonzero(near.ravel())
        mask.ravel()[near] = _sigmoid(logit.ravel()[near]) >= threshold
        return mask


def _read_info(path: Path, meta: dict[str, str]) -> ModelInfo:
    try:
        info = ModelInfo(
            input_width=int(meta["heightpipe.input_width"]),
            input_height=int(meta["heightpipe.input_height"]),
            mean=tuple(json.loads(meta["heightpipe.mean"])),
            std=tuple(json.loads(meta["heightpipe.std"])),
            output_units=meta["heightpipe.output_units"],
            architecture=meta.get("heightpipe.architecture", "unknown"),
            color_order=meta.get("heightpipe.color_order", "RGB"),
        )
    except KeyError as exc:
        raise ModelError(f"{path} lacks heightpipe metadata {exc.args[0]!r}: "
                         "export it with `heightpipe export`") from None
    except (ValueError, TypeError) as exc:
        raise ModelError(f"{path} has malformed heightpipe metadata: {exc}") from None
    if info.output_units not in OUTPUT_UNITS:
        raise ModelError(f"{path}: unknown output units {info.output_units!r}")
    if info.contact:
        info.detection_classes, info.detection_stride = _read_detection_head(path, meta)
        big_classes, info.big_detection_stride = _read_detection_head(path, meta, "big_centre_logit")
        if big_classes and big_classes != info.detection_classes:
            raise ModelError(f"{path}: the big-object head's classes {list(big_classes)} differ from the "
                             f"detection head's {list(info.detection_classes)}")
        info.camera_spread_scale = _read_spread_scale(path, meta)
        info.camera_error_correlation = _read_error_correlation(path, meta)
    return info


def _read_spread_scale(path: Path, meta: dict[str, str]) -> tuple[float, float, float]:
    """``heightpipe.camera_spread_scale``: three positive numbers, (1, 1, 1) when absent."""
    text = meta.get("heightpipe.camera_spread_scale")
    if text is None:
        return (1.0, 1.0, 1.0)
    try:
        scale = tuple(float(v) for v in json.loads(text))
    except (ValueError, TypeError) as exc:
        raise ModelError(f"{path} has malformed heightpipe.camera_spread_scale metadata: {exc}") from None
    if len(scale) != 3 or not all(math.isfinite(v) and v > 0 for v in scale):
        raise ModelError(f"{path}: heightpipe.camera_spread_scale needs three positive numbers, got {text}")
    return scale


def _read_error_correlation(path: Path, meta: dict[str, str]) -> tuple[tuple[float, ...], ...]:
    """``heightpipe.camera_error_correlation``: a 3 x 3 correlation matrix (symmetric, ones on the
    diagonal, positive definite), the identity when absent."""
    text = meta.get("heightpipe.camera_error_correlation")
    if text is None:
        return ModelInfo.camera_error_correlation
    try:
        matrix = np.array(json.loads(text), np.float64)
    except (ValueError, TypeError) as exc:
        raise ModelError(f"{path} has malformed heightpipe.camera_error_correlation metadata: {exc}") from None
    if (matrix.shape != (3, 3) or not np.all(np.isfinite(matrix)) or not np.allclose(matrix, matrix.T)
            or not np.allclose(np.diag(matrix), 1.0) or np.linalg.eigvalsh(matrix).min() <= 0):
        raise ModelError(f"{path}: heightpipe.camera_error_correlation needs a 3 x 3 correlation matrix, got {text}")
    return tuple(tuple(float(v) for v in row) for row in matrix)


def _read_detection_head(path: Path, meta: dict[str, str], name: str = "centre_logit") -> tuple[tuple[str, ...], int]:
    """Classes and stride of a v2 model's detection head (``name``: its centre output; the
    big-object head's is ``big_centre_logit``) from ``heightpipe.outputs`` ((), 0: none)."""
    try:
        outputs = json.loads(meta.get("heightpipe.outputs", "{}"))
        centre = outputs.get(name)
        if centre is None:
            return (), 0
        classes, stride = tuple(str(c) for c in centre["classes"]), int(centre["stride"])
    except (ValueError, TypeError, KeyError, AttributeError) as exc:
        raise ModelError(f"{path} has malformed heightpipe.outputs metadata: {exc!r}") from None
    if not classes or stride <= 0:
        raise ModelError(f"{path}: heightpipe.outputs {name} needs classes and a positive stride")
    return classes, stride


class HeightNetModel:
    """One ONNX HeightNet (v1 or v2) in an ONNX Runtime session.

    Parameters
    ----------
    model_path : str or Path
        "" = the shipped model, "int8" = its INT8 version, "v2" = HeightNet v2, else an exported file.
    threads : int
        ONNX Runtime intra-op threads; 0 = by the model (``CONSTANTS.auto_threads_v1`` / ``_v2``).
    detection_min_score : float
        A detection head's peaks weaker than this are not decoded (object extraction passes its
        lowest threshold, ``stages.network_objects.min_score``).
    input_width : int
        Run the network at this input width (0 = the size it was trained at); the height keeps
        the trained aspect, both rounded to ``CONSTANTS.size_multiple``. Needs an export with a
        free input size (``heightpipe export`` writes one); ONNX Runtime then fixes the size when
        the session is built, so it runs as fast as a fixed-size export.
    mirror : bool
        Read every image twice, as it is and mirrored, and average the two reads (a second pass
        of the network; ``stages/mirrored_views.py`` says why). v2 models only.

    A run whose objects come from the detection head sets ``box_refiner`` (pipeline/stage_chain.py,
    ``objects.source = "network"``): it moves the edges of the head's boxes of its classes, read
    from the image the network read (``stages/box_refinement.py``); None: the boxes as drawn.
    """

    def __init__(self, model_path: str | Path = "", threads: int = 0,
                 detection_min_score: float = CONSTANTS.detection_min_score, input_width: int = 0,
                 mirror: bool = False):
        path = model_file(model_path)
        if not path.is_file():
            raise ModelError(f"model file not found: {path}")
        if input_width < 0:
            raise ConfigError(f"height.input_width must be 0 (the trained size) or a width in pixels, "
                              f"got {input_width}")
        if threads < 0:
            raise ConfigError(f"height.threads must be 0 (by the model) or more, got {threads}")
        self.path = path
        self.detection_min_score = detection_min_score
        first_threads = threads or CONSTANTS.auto_threads_v1
        self.session = cpu_session(path, first_threads)
        self.info = _read_info(path, self.session.get_modelmeta().custom_metadata_map)
        self.threads = threads or _auto_threads(self.info)
        free = [dim for dim in self.session.get_inputs()[0].shape[2:] if not isinstance(dim, int)]
        if len(free) == 2:
            # A free input size: fixed here, at the trained size or the one asked for.
            width, height = input_size(self.info, input_width)
            self.info = dataclasses.replace(self.info, input_width=width, input_height=height)
            self.session = cpu_session(path, self.threads, dict(zip(free, (height, width))))
        elif input_width and input_size(self.info, input_width) != (self.info.input_width, self.info.input_height):
            raise ModelError(f"{path} takes only its fixed {self.info.input_width}x{self.info.input_height} "
                             f"input, not {input_width} wide (a v2 export by heightpipe export takes any width)")
        elif self.threads != first_threads:
            self.session = cpu_session(path, self.threads)
        self._check_signature()
        if mirror:
            if not self.info.contact:
                raise ConfigError(f"height.mirror needs a HeightNet v2 model (height.model = \"v2\"); {path} is a "
                                  "v1 model, whose mirrored reads measured real people worse (docs/results.md)")
            strides = (self.info.detection_stride, self.info.big_detection_stride)
            problem = mirror_problem(self.info.input_width, strides)
            if problem:
                raise ConfigError(problem)
        self.mirror = mirror
        self.box_refiner: BoxRefiner | None = None
        self._mean = np.array(self.info.mean, np.float32) * 255.0
        self._inv_std = 1.0 / (np.array(self.info.std, np.float32) * 255.0)
        self._cached_index: int | None = None
        self._cached: ModelOutput | None = None
        self._last_input: np.ndarray | None = None
        """The input of the last frame ``infer`` ran on: a motion-reading head's previous frame."""

    def _check_signature(self) -> None:
        inputs = self.session.get_inputs()
        names = [i.name for i in inputs]
        if len(inputs) not in (1, 2) or (len(inputs) == 2 and names[1] != PREVIOUS_INPUT):
            raise ModelError(f"{self.path}: expected an image input (and optionally {PREVIOUS_INPUT!r}), "
                             f"found {names}")
        expected = [1, 3, self.info.input_height, self.info.input_width]
        for given in inputs:
            if list(given.shape) != expected:
                raise ModelError(f"{self.path}: input shape {given.shape} ({given.name!r}) does not match "
                                 f"the expected {expected} (1 x RGB x height x width from metadata)")
        self.input_name = inputs[0].name
        self.takes_previous = len(inputs) == 2
        """Whether the network reads the frame before (a detection head with a motion path)."""
        outputs = {o.name: o.shape for o in self.session.get_outputs()}
        h, w = self.info.input_height, self.info.input_width
        if self.info.contact:
            expected_outputs = {"offsets": [1, 2, h, w], "ground_logit": [1, 1, h, w],
                                "camera": [1, CAMERA_HEAD_SIZE]}
        else:
            expected_outputs = {"height": [1, 1, h, w], "ground_logit": [1, 1, h, w]}
        if self.info.detection:
            cells = [h // self.info.detection_stride, w // self.info.detection_stride]
            expected_outputs["centre_logit"] = [1, len(self.info.detection_classes), *cells]
            expected_outputs["box"] = [1, BOX_SIZE, *cells]
        if self.info.big_detection_stride:
            cells = [h // self.info.big_detection_stride, w // self.info.big_detection_stride]
            expected_outputs["big_centre_logit"] = [1, len(self.info.detection_classes), *cells]
            expected_outputs["big_box"] = [1, BOX_SIZE, *cells]
        for name, shape in expected_outputs.items():
            if name not in outputs:
                raise ModelError(f"{self.path}: missing output {name!r} (has {sorted(outputs)})")
            if list(outputs[name]) != shape:
                raise ModelError(f"{self.path}: output {name!r} has shape {outputs[name]}, expected {shape}")
        self.output_names = list(expected_outputs)

    def preprocess(self, image_bgr: np.ndarray) -> np.ndarray:
        """The 1 x 3 x H x W input: resized, channels in the model's order, normalised."""
        return self._tensor(self._resized(image_bgr))

    def _resized(self, image_bgr: np.ndarray) -> np.ndarray:
        """The image squashed to the input size: what the network (and the box refiner) read."""
        return cv2.resize(image_bgr, (self.info.input_width, self.info.input_height), interpolation=cv2.INTER_AREA)

    def _tensor(self, small: np.ndarray) -> np.ndarray:
        """The network's input from the resized image, written plane by plane into the tensor,
        so no interleaved float copy is made and transposed (640x360: 1.9 -> 0.9 ms per frame;
        the same float32 arithmetic)."""
        channels = (2, 1, 0) if self.info.color_order == "RGB" else (0, 1, 2)
        tensor = np.empty((1, 3, *small.shape[:2]), np.float32)
        for plane, channel in enumerate(channels):
            np.subtract(small[:, :, channel], self._mean[plane], out=tensor[0, plane], dtype=np.float32)
            tensor[0, plane] *= self._inv_std[plane]
        return tensor

    def infer(self, frame: Frame) -> ModelOutput:
        """Run the network on a frame (once: repeated calls for one frame hit the cache). A network
        that reads motion gets the last frame this ran on as the one before (on the first, itself)."""
        if self._cached_index == frame.index and self._cached is not None:
            return self._cached
        small = self._resized(frame.image)
        tensor = self._tensor(small)
        self._cached = self._outputs(tensor, self._last_input, frame.image.shape[:2], small)
        self._last_input = tensor if self.takes_previous else None
        self._cached_index = frame.index
        return self._cached

    def run(self, image_bgr: np.ndarray) -> ModelOutput:
        """The network on one image alone (no cache, no frame before: a motion-reading head sees
        no change); outputs as ``ModelOutput`` describes."""
        small = self._resized(image_bgr)
        return self._outputs(self._tensor(small), None, image_bgr.shape[:2], small)

    def _outputs(self, tensor: np.ndarray, previous: np.ndarray | None, frame_shape: tuple[int, int],
                 small: np.ndarray) -> ModelOutput:
        """The network on one prepared input (``previous``: the frame before, None = no change;
        ``small``: the image it was prepared from), its outputs at ``frame_shape`` (rows, columns)."""
        named = self._run(tensor, previous)
        if self.mirror:
            mirror_read = self._run(mirror_input(tensor), None if previous is None else mirror_input(previous))
            named = averaged_with_mirror(named, unmirrored_outputs(mirror_read))
        h, w = frame_shape
        logit_full = cv2.resize(named["ground_logit"][0, 0], (w, h), interpolation=cv2.INTER_LINEAR)
        if self.info.contact:
            return ModelOutput(None, logit_full, offsets=named["offsets"][0].transpose(1, 2, 0),
                               camera=named["camera"][0], detections=self._detections(named, (w, h), small))
        height_full = cv2.resize(named["height"][0, 0], (w, h), interpolation=cv2.INTER_LINEAR)
        return ModelOutput(np.maximum(height_full, 0.0, out=height_full), logit_full)

    def _run(self, tensor: np.ndarray, previous: np.ndarray | None) -> dict[str, np.ndarray]:
        """The session's outputs by name for one prepared input (and the frame before)."""
        feed = {self.input_name: tensor}
        if self.takes_previous:
            feed[PREVIOUS_INPUT] = tensor if previous is None else previous
        return dict(zip(self.output_names, self.session.run(self.output_names, feed)))

    def _detections(self, named: dict[str, np.ndarray], frame_size: tuple[int, int],
                    small: np.ndarray) -> NetworkDetections | None:
        """The detection head's peaks in frame pixels, their boxes refined where a refiner is
        given (None without a head)."""
        if not self.info.detection:
            return None
        found = centre_detections(named["centre_logit"][0], named["box"][0], self.info.detection_stride,
                                  self.detection_min_score, CONSTANTS.max_detections)
        if self.info.big_detection_stride:
            found = with_big_objects(found, named["big_centre_logit"][0], named["big_box"][0],
                                     self.info.big_detection_stride, self.detection_min_score,
                                     CONSTANTS.big_min_height_px, CONSTANTS.max_detections)
        if self.box_refiner is not None and len(found):
            names = [self.info.detection_classes[int(c)] for c in found.classes]
            found = CentreDetections(self.box_refiner.refine(small, found.boxes, names), found.classes, found.scores)
        return in_frame(found, self.info.detection_classes,
                        (self.info.input_width, self.info.input_height), frame_size,
                        big_objects=bool(self.info.big_detection_stride))

    def to_metres(self, height: np.ndarray, camera: CameraInfo) -> np.ndarray:
        """v1 model units to metres: scale-free outputs are multiplied by the camera height
        (v2 offsets need the whole camera: ``stages.contact_heights``)."""
        if self.info.contact:
            raise ModelError(f"{self.path}: a ground-contact-offset model has no height output to scale")
        if self.info.output_units == "metres":
            return height
        return height * np.float32(camera.height_m)


def input_size(info: ModelInfo, input_width: int) -> tuple[int, int]:
    """(width, height) the network runs at: ``input_width`` (0 = the trained width) with the
    trained aspect, each rounded to a multiple of ``CONSTANTS.size_multiple`` (at least one)."""
    step = CONSTANTS.size_multiple
    width = input_width or info.input_width
    height = width * info.input_height / info.input_width
    return max(step, round(width / step) * step), max(step, round(height / step) * step)


def most_threads(threads: int) -> int:
    """The most ONNX Runtime threads a ``height.threads`` setting gives a model: itself, or for 0 (by
    the model) the larger of the two the models get, at most the cores there are. Callers that
    share the cores out between videos or cameras divide this."""
    return threads or min(max(CONSTANTS.auto_threads_v1, CONSTANTS.auto_threads_v2), cores())


def _auto_threads(info: ModelInfo) -> int:
    """``threads = 0``: the model's share of the cores (``CONSTANTS.auto_threads_v1`` / ``_v2``)."""
    wanted = CONSTANTS.auto_threads_v2 if info.contact else CONSTANTS.auto_threads_v1
    return max(1, min(wanted, cores()))


def cores() -> int:
    """The cores this process may run on (its affinity, where the system tells it)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def _sigmoid(logit: np.ndarray) -> np.ndarray:
    """float32 sigmoid, the logit clipped to +-30 (in place on one new array: at 1920x1080 each
    temporary costs about a millisecond)."""
    x = np.clip(logit, -30, 30)
    np.negative(x, out=x)
    np.exp(x, out=x)
    np.add(x, 1.0, out=x)
    return np.divide(1.0, x, out=x)
