"""What flows between stages: one ``FramePacket`` per processed frame.

Each stage fills in its own fields and leaves the rest alone, so a sink can log whatever
the stages before it produced. Images are NumPy arrays in source resolution.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# Coarse object classes reported by the tracker (and used in CSV/MCAP records).
OBJECT_CLASSES = ("other", "person", "cyclist", "vehicle")


@dataclass
class Frame:
    index: int
    """0-based index of the frame in the source (counts frames skipped by --stride)."""
    time_s: float
    """Capture time in seconds from the container/stream time stamps, from the source start."""
    image: np.ndarray
    """BGR uint8, H x W x 3."""
    damage: str = ""
    """Why this frame cannot be trusted ("" = it decoded clean): a decoder error, a corrupt flag,
    frames missing before it, or a damaged frame it is predicted from (``stages.pyav_capture``)."""
    source_scale: tuple[float, float] = (1.0, 1.0)
    """Source pixels per pixel of ``image`` along x and y: capture scales frames wider than
    ``capture.max_width`` down, and the pixels users read or write (tracks.csv boxes, events,
    image zones) stay the source's."""

    def to_source(self, values: tuple[float, ...]) -> tuple[float, ...]:
        """(x, y) or (x, y, w, h) in pixels of ``image`` as source pixels (pixel edges: pixel i
        covers [i, i + 1), so whole-factor scaling maps a box onto the block it came from)."""
        sx, sy = self.source_scale
        if sx == 1.0 and sy == 1.0:
            return tuple(values)
        return tuple(v * (sx if i % 2 == 0 else sy) for i, v in enumerate(values))


@dataclass
class CameraInfo:
    """What is known of the camera; fields are None where unknown."""

    width: int
    height: int
    K: np.ndarray | None = None
    """3x3 intrinsics of the (undistorted) image."""
    dist: np.ndarray | None = None
    """OpenCV distortion coefficients of the raw image."""
    R: np.ndarray | None = None
    """3x3 world-to-camera rotation (world z up, ground z = 0)."""
    t: np.ndarray | None = None
    """World-to-camera translation in metres: x_cam = R @ x_world + t."""
    height_m: float | None = None
    """Camera height above the ground plane."""
    source: str = "none"
    """Where the calibration came from: 'calibration', 'camera-height', 'self' or 'none'."""
    pose_from: str = ""
    """Where R and t came from: 'file' (a calibration JSON), 'config' (``[camera]`` height_m and
    pitch_deg) or '' (no pose, or made in code). The run has one camera either way; this only
    lets outputs say which of the user's inputs it was."""
    lens_from_file: bool = False
    """K came from a calibration file; False: from ``camera.fov_deg``, an assumption."""


@dataclass
class HeightCamera:
    """The camera the height stage turned a HeightNet v2 network's ground-contact offsets into
    metres with, and where it came from (shown in the run summary and the rerun view).

    ``source``: 'calibration' (a calibration file's pose), 'config' (a pose in ``[camera]``),
    'self' (that pose from ``heightpipe calibrate``), 'heads' (the camera height given, pitch,
    roll and focal length from the network's camera heads) or 'assumed' (the heads with an
    assumed camera height: ``heightpipe calibrate`` only). The standard deviations are the
    heads' own (0 for a given camera).
    """

    source: str
    height_m: float
    pitch_deg: float
    roll_deg: float
    focal_px: float
    """Vertical focal length in source-frame pixels."""
    pitch_std_deg: float = 0.0
    roll_std_deg: float = 0.0
    focal_std_pct: float = 0.0
    frames: int = 0
    """Frames the heads' outputs were averaged over (0 for a given camera)."""
    focal_given: bool = False
    """Heads path only: the focal length is a calibration file's, not the heads'."""
    edges: int = 0
    """Heads path only: straight lines of the scene (vertical edges, parallel ground lines) the
    heads' camera was sharpened with (``stages/vertical_edges.py``; 0 = the heads alone)."""
    square_families: bool = False
    """Heads path only: two families of ground lines were taken to cross at right angles."""


@dataclass
class FeatureMatches:
    """Points matched between the previous and this frame (ORB + pyramidal LK, RANSAC-filtered)."""

    prev_pts: np.ndarray
    """N x 2 float32 pixel positions in the previous frame."""
    curr_pts: np.ndarray
    """N x 2 float32 pixel positions in this frame."""
    on_object: np.ndarray
    """N bool: the point lies on an above-ground (moving) region, not the static background."""
    camera_motion: np.ndarray = field(default_factory=lambda: np.eye(2, 3, dtype=np.float32))
    """2x3 affine of the static background from the previous to this frame (shake)."""


@dataclass
class FrameKeypoints:
    """One frame's ORB keypoints on its matching image (``stages.feature_matching``): matched to
    the next frame's picture there, and what the last frame's keypoints are tracked into."""

    gray: np.ndarray
    """The matching image: the frame in grey, ``scale`` times smaller."""
    scale: int
    """Frame pixels per matching-image pixel."""
    above_ground: np.ndarray | None
    """Matching-image bool mask of the pixels above the ground (None without a height map)."""
    keypoints: list
    """``cv2.KeyPoint``s in matching-image pixels."""
    descriptors: np.ndarray | None
    """Their ORB descriptors (N x 32 uint8; None when there are none)."""


@dataclass(frozen=True)
class NetworkDetections:
    """The height network's own detections in one frame (its detection head: centre-heatmap peaks
    with their boxes), columns of equal length, before object extraction applies its thresholds.

    Boxes are in source-frame pixels (pixel edges: a box over the whole frame is 0, 0, W, H),
    mapped back from the network's input through the squash the frame was resized with.
    """

    boxes: np.ndarray
    """N x 4 float32: x0, y0, x1, y1."""
    classes: tuple[str, ...]
    """The network's class of each box ("person", "cyclist", "vehicle": the model's metadata names them)."""
    scores: np.ndarray
    """N float32: the centre heatmap's probability at the peak."""
    big_objects: bool = False
    """The network has a head of its own for near, big objects (``big_centre_logit``): the objects
    stage then needs no motion blobs standing in for the objects a head without one misses."""

    def __len__(self) -> int:
        return len(self.scores)


# Height channels of the shipped stages: the keys of ``Detection.heights`` and what a track's
# ``height_source`` names. A stage may add a channel of any other name; the tracker fuses it as a
# measurement of its own (its own bias on each object) with no edit anywhere else.
NETWORK = "network"
"""Object extraction's reading of the height map (the network's height); as a ``cls_source``, the
class the network's detection head gave the box."""
GEOMETRY = "geometry"
"""Foot and top points through the calibrated camera (``stages.geometry``); as a ``cls_source``,
the class that stage gave from metric height and width."""
BOX = "box"
"""A vehicle's outline fitted with a box on the ground (``stages.vehicle_geometry``)."""


@dataclass(frozen=True)
class Measurement:
    """One stage's reading of one object's height in one frame."""

    value_m: float
    """Height above the ground in metres."""
    noise_m: float
    """Standard deviation the tracker should assume for ``value_m`` this frame. ``inf`` (or NaN
    ``value_m``) makes it no measurement: e.g. a top cut by the frame gives a lower bound only."""
    source: str
    """The stage that measured it ("objects", "geometry", ...; "geometry scale" where the
    geometry rescaled the network's reading)."""
    bias_m: float | None = None
    """The part of ``noise_m`` that repeats on this object frame after frame (the same hair taken
    for the crown in every frame): the prior std of the channel's bias on the object. None: all of
    ``noise_m`` (the network's bias prior is a share of the height instead, ``[tracking]``)."""

    @property
    def usable(self) -> bool:
        """A finite value with a finite, positive noise: something the tracker can fuse."""
        return bool(np.isfinite(self.value_m) and np.isfinite(self.noise_m) and self.noise_m > 0)


@dataclass
class Detection:
    """One object candidate in one frame, before tracking.

    Object extraction makes it (box, class, ends, masks, the network's height); later stages add
    what they measure: a height is one more entry in ``heights`` under the stage's channel, a
    class decided again names its stage (``classify``).
    """

    box: tuple[float, float, float, float]
    """x, y, w, h in source pixels."""
    heights: dict[str, Measurement] = field(default_factory=dict)
    """This frame's height measurements by channel (``NETWORK``, ``GEOMETRY``, ``BOX``, or any
    channel a stage adds): each written by the stage that measured it (``add_height``), fused by
    the tracker."""
    score: float = 1.0
    """The network's score for a detection of its head (``NetworkDetections``); 1 for a blob's."""
    continues_only: bool = False
    """A weak box of the network's head (below its class's threshold, not confirmed by motion):
    it may carry on a confirmed track it lies on, never start one (ByteTrack's low-score round);
    the tracking stage drops it from the frame's objects when it carries none."""
    cls: str = "other"
    """Coarse class (``OBJECT_CLASSES``); the tracker votes over frames."""
    cls_source: str = ""
    """The stage that decided ``cls``: "objects" (the network's height and the box's shape),
    "network" (the height network's detection head, ``objects.source = "network"``: no later
    stage reclassifies it), "geometry" (metres, calibrated cameras), "tracking" (a merged blob's
    piece takes its track's); "" where the detection was made by hand."""
    foot_xy: tuple[float, float] | None = None
    """Image point where the object touches the ground."""
    top_xy: tuple[float, float] | None = None
    """Image point of the object's top."""
    touches_border: bool = False
    """Some of the object's pixels lie at the edge of the image: it may continue outside."""
    foot_cut: bool = False
    """foot_xy is not the object's ground contact: its bottom lies at the edge of the image, or
    stands above the ground on the height map (legs hidden or missed by the background model)."""
    top_cut: bool = False
    """The object's top lies at the edge of the image: its heights are lower bounds."""
    min_height_m: float | None = None
    """Lower bound on the height when the foot is cut or hidden: the true foot lies lower in the
    image, nearer the camera, where the top's ray stands higher (the geometry; calibrated cameras)."""
    camera_share: float = 0.0
    """Relative std of this object's heights from the camera's stated uncertainty (a self-calibrated
    pose; 0 = exact): the same error on every frame and every channel measured with that camera, so
    the tracker adds it to the std it reports rather than fusing it (``stages/geometry.py``)."""
    ground_xy_m: tuple[float, float] | None = None
    """Foot point on the ground plane in world metres (calibrated cameras only)."""
    mask: np.ndarray | None = None
    """Bool mask of the object's pixels inside its box (box-sized), where the extractor has one."""
    colour: np.ndarray | None = None
    """The object's colour signature (``stages.colour_signature``), set by the tracking stage where
    its colour cue is on, for the detection head's boxes; None where unknown (a blob, a damaged
    frame)."""
    outline: np.ndarray | None = None
    """The mask without what the foreground's growth added above the object (box-sized): the
    outline the vehicle geometry reads."""
    vehicle_axis_xy: tuple[float, float] | None = None
    """Unit vector along the length of the box fitted to a vehicle's outline (channel ``BOX``),
    on the ground: a vehicle drives along it."""
    vehicle_length_assumed: bool = False
    """Only the box's end was seen: its length is a car's by assumption (and a bicycle seen from
    the side looks the same; the tracker tells them apart by the direction they move)."""
    blob: int | None = None
    """Which of this frame's above-ground blobs object extraction cut the detection from (pieces
    of one blob share it; None where no blob made it): the tracker joins a vehicle's pieces only
    within one blob (``stages.vehicle_fragments``)."""

    def add_height(self, channel: str, measurement: Measurement) -> None:
        """Record the channel's measurement (replacing one already there). Copy on write: a
        detection copied with ``dataclasses.replace`` keeps its own measurements."""
        self.heights = {**self.heights, channel: measurement}

    def height(self, channel: str = NETWORK) -> float:
        """The channel's height this frame, NaN where it has none."""
        measurement = self.heights.get(channel)
        return float("nan") if measurement is None else measurement.value_m

    def classify(self, cls: str, source: str) -> None:
        """Set the class, saying which stage decided it (a later stage's decision replaces an
        earlier one's, visibly)."""
        self.cls, self.cls_source = cls, source


@dataclass
class Track:
    """A confirmed or tentative object track after this frame's update."""

    track_id: int
    box: tuple[float, float, float, float]
    cls: str
    height_m: float
    height_std_m: float
    score: float = 1.0
    confirmed: bool = False
    ground_xy_m: tuple[float, float] | None = None
    """Ground position in metres (world x, y) where the camera is calibrated."""
    height_source: str = "network"
    """The one channel the height is made of ('network', 'geometry' (foot and top), 'box' (a
    vehicle's outline), or a channel a stage added), 'fused' where several went in, or 'none'
    while the track has no height measurement (height_m NaN): e.g. its top is cut by the image edge."""
    hits: int = 0
    age: int = 0
    updated: bool = True
    """Whether a detection was associated this frame (else the box is predicted)."""
    filled: bool = False
    """Not updated, but found again soon after: the box is interpolated between the detections
    before and after this frame (``tracking.fill_gaps_s``, pipeline/track_backfill.py)."""
    detected_box: tuple[float, float, float, float] | None = None
    """The box of the detection that updated the track this frame (None where none did): what was
    measured, where ``box`` is the motion filter's estimate from it and the frames before (the
    smoothing fits these: pipeline/track_backfill.py)."""
    foot_in_view: bool = True
    """False where the object reaches past the image's bottom edge: ``box`` is cut there, and its
    bottom is the frame's edge, not where the object stands."""

    @property
    def box_source(self) -> str:
        """Where this frame's box comes from: 'detected', 'interpolated' (``filled``) or 'predicted'
        (coasting), as the outputs say it."""
        if self.updated:
            return "detected"
        return "interpolated" if self.filled else "predicted"


@dataclass
class FramePacket:
    frame: Frame
    camera: CameraInfo
    ground_mask: np.ndarray | None = None
    """H x W bool: ground plane."""
    height_map: np.ndarray | None = None
    """H x W float32 metres above the ground."""
    foreground: np.ndarray | None = None
    """H x W bool: moving pixels from background subtraction."""
    image_valid: np.ndarray | None = None
    """H x W bool: pixels that carry image (undistortion leaves black corners); None = all."""
    keypoints: FrameKeypoints | None = None
    """This frame's ORB keypoints (the keypoints stage; matching finds them itself without it)."""
    matches: FeatureMatches | None = None
    network_detections: NetworkDetections | None = None
    """The height network's detections (a v2 model with a detection head; None without one)."""
    detections: list[Detection] = field(default_factory=list)
    tracks: list[Track] = field(default_factory=list)
    events: list = field(default_factory=list)
    """Height-rule firings this frame (``stages.height_rules.RuleEvent``)."""
    height_camera: HeightCamera | None = None
    """The camera the height map was decoded with (HeightNet v2 models; None for v1 models,
    whose heights need only ``camera.height_m``)."""
    timings_ms: dict[str, float] = field(default_factory=dict)
    """Per-stage wall time for this frame (for the summary and the benchmark)."""
    network_reused: bool = False
    """The network outputs are the previous frame's: a live run behind (``pipeline/overlapped.py``).
    The boxes still carry tracks; no height is measured on this frame."""
