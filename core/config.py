"""All configuration in one typed place.

Each section of ``config.toml`` is a dataclass below; the dataclass defaults are the
documented defaults (``tests/core/test_config.py`` checks that ``config.toml`` agrees).
Values come from, in increasing priority: these defaults, a TOML file, ``--set
section.key=value`` overrides and the dedicated command-line flags.

TOML has no null, so "not set" is spelled ``0`` or ``""`` where noted.
"""

from __future__ import annotations

import dataclasses
import tomllib
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from core.errors import ConfigError

REPO_ROOT = Path(__file__).resolve().parent.parent
DEFAULT_CONFIG_PATH = REPO_ROOT / "config.toml"


@dataclass
class CaptureConfig:
    stride: int = 1
    """Process every Nth frame; time stamps and frame indices stay those of the source."""
    max_frames: int = 0
    """Stop after this many processed frames (0 = all)."""
    connect_attempts: int = 5
    """Stream (RTSP/HTTP) open attempts before giving up, with exponential back-off."""
    reconnect_attempts: int = 5
    """Reconnects after a live stream drops mid-run before the run ends."""
    backoff_s: float = 0.5
    """First back-off delay; doubles after each failed attempt."""
    read_timeout_s: float = 10.0
    """A stream that delivers no frame for this long counts as dropped."""
    backend: str = "pyav"
    """Video files: 'pyav' (reports each frame decoded with errors) or 'opencv' (does not)."""
    reference: str = ""
    """A complete recording of the same camera: its codec settings salvage an MP4 cut off before
    its index was written ("" = none: such a file is an error that says so)."""
    max_width: int = 1280
    """Frames wider than this are processed scaled down by the smallest whole factor that makes
    them fit (1920x1080 and 2560x1440 -> 960x540 and 1280x720; 0 = full size). Recordings show the
    scaled frames; tracks.csv, events and image zones stay in the source's pixels."""


@dataclass
class GroundConfig:
    method: str = "model"
    """'model': the network's ground output; 'height': pixels under height_threshold_m."""
    height_threshold_m: float = 0.10
    """Pixels lower than this count as ground (also the minimum object height)."""
    probability_threshold: float = 0.5
    """Ground-probability cut for the 'model' method."""


@dataclass
class HeightConfig:
    model: str = ""
    """ONNX model path, or a shipped model by name: "v1" (stages/models/), "int8" (its INT8
    quantisation), "v2" (HeightNet v2); a v1 or a ground-contact (v2) export, told apart by its
    metadata (v2 needs the camera: README). "" = the shipped model for what the run is told of its
    camera (``model_for_camera``): v2 with its detection head when told only the camera height, v1
    otherwise."""
    threads: int = 0
    """ONNX Runtime intra-op threads; 0 = by the model: one for v1, whose second thread took the
    core the other stages run on beside it (the overlapped run was slower with it), two for the
    slower v2 (docs/design.md, Threads and processes)."""
    input_width: int = 0
    """Network input width in pixels (0 = the width the model was trained at, 320); the height
    keeps the trained aspect. Twice as wide finds objects half as tall (a 640x480 camera's far
    walkers) at about three times the network's cost (72 ms against 23 at 640, two threads): for
    archives and big frames, not for real time. Needs a v2 export with a free input size (the
    shipped one has)."""
    mirror: bool = False
    """Also run the network on the mirror image of each frame and average the two reads
    (``stages/mirrored_views.py``): boxes, scores, the height map and the camera heads. A second
    pass of the network a frame, for archives rather than real time; HeightNet v2 only (v1's
    mirrored reads measured real people worse). docs/results.md, 2026-12-07 thirty-ninth session."""
    box_refiner: str = "auto"
    """Network mode (``objects.source = "network"``): sharper edges for the detection head's person
    boxes (``stages/box_refinement.py``): "auto" =
    the shipped refiner, for the shipped v2 model it was trained on (other models' boxes stay as
    drawn), "off" = none, or a refiner's ONNX file (heightnet/box_refiner.py), used on any model."""
    vertical_edges: bool = False
    """v2 told only the camera height: let the scene's straight lines (walls' and poles' vertical
    edges, parallel kerbs and markings) sharpen the camera heads' pitch, roll and focal length
    (``stages/vertical_edges.py``). Off by default: the camera gets much truer (held-out
    generator cameras: pitch 2.4 -> 0.9 degrees off, horizon 4.0 -> 1.5 % of the image; Oxford
    pitch 34 -> 20.5 degrees against 20.0) and held-out people 25 -> 18 cm, but on Oxford
    people read 24 cm off against 11.6 (v2's offsets read real people short with a true camera;
    the heads' wrong one made up for it). A posed run does better on both: ``heightpipe
    calibrate SOURCE --camera-height H`` prints this camera as a ``[camera]`` snippet
    (docs/results.md, 2026-12-04 tenth session)."""


@dataclass
class MatchingConfig:
    orb_features: int = 400
    """ORB keypoints per frame."""
    lk_window: int = 11
    """Pyramidal Lucas-Kanade window in pixels of the (downscaled) matching image: small,
    so a small object's flow is not dragged by the background around it."""
    lk_levels: int = 2
    """Pyramid levels for Lucas-Kanade."""
    ransac_threshold_px: float = 3.0
    """RANSAC reprojection threshold for the global-motion fit."""
    max_hamming: int = 64
    """ORB descriptor distance above which a match is rejected."""
    downscale: int = 2
    """Match on a 1/N image (points are reported in the frame's pixels): 4x cheaper at N=2."""
    max_width: int = 320
    """The matching image is at most this wide: larger frames are downscaled further (0 = no
    limit). 320 is the sample's matching image (640 / 2), which the window and the ORB budget
    suit; a 1920x1080 frame is matched at 1/6, not at 1/2 (CPU 20 -> 7 ms per frame; 3 held-out
    1080p generator sequences: HOTA 0.309 -> 0.311, ID switches 5 -> 3, tracked height error
    13.1 -> 11.7 cm). Frames up to 640 wide are matched as before."""


@dataclass
class ObjectsConfig:
    """Object extraction: each frame's objects become detections, from moving above-ground blobs
    (``source = "blobs"``) or the height network's detection head (``"network"``)."""

    source: str = "blobs"
    """'blobs': moving, above-ground blobs are the objects; 'network': the height network's own
    detections are (a v2 model with a detection head), motion only confirms weak ones."""
    score_person: float = 0.5
    """Network mode: a person box scoring at least this is an object, moving or not."""
    score_cyclist: float = 0.5
    """Network mode: the same for cyclists."""
    score_vehicle: float = 0.5
    """Network mode: the same for vehicles."""
    score_motion: float = 0.35
    """Network mode: a weaker box scoring at least this is an object while it moves (``moving_share``).
    0.5 and 0.35 since the head grew a residual block (690,000 images): its boxes score higher,
    false ones too (docs/results.md, 2026-12-04 fifth session)."""
    moving_share: float = 0.3
    """Network mode: a weak box moves when at least this share of its pixels above the ground is
    foreground (all its pixels without a height map) ..."""
    motion_contrast: float = 0.0
    """Network mode: ... and that share is at least this much above the foreground share of the
    ring around the box: rain, sensor noise at dusk and swaying grass move everywhere, a walker
    moves against a still background."""
    still_s: float = 0.0
    """Network mode: a weak box (at least ``score_motion``) that does not move is an object when a
    box of its class lay where it lies (IoU >= 0.5) in every frame of the last ``still_s`` seconds:
    a person standing still scores as weakly as a walker but never moves (0 = off)."""
    continue_score: float = 0.2
    """Network mode: a box weaker than that, scoring at least this, moving or not, may carry on a
    confirmed track it overlaps (IoU >= 0.5 with its prediction) but never starts one (ByteTrack's
    low-score round): a walker whose score dips for a few frames keeps his track. At or above the
    class thresholds: off."""
    motion_ends: bool = False
    """Network mode: a moving box's geometry points follow its foreground: where the object's
    moving pixels go on past the box's bottom (top) under the box's middle, its foot (crown) is
    where they stop (``stages.network_objects.motion_ends``); the box itself stays the network's."""
    keep_motion_blobs: bool = False
    """Network mode: a moving blob that no network box covers is an object too (its class from its
    shape); without it only blobs a quarter of the frame tall or taller are (the head misses most of those)."""
    vehicle_height_percentile: float = 80.0
    """Network mode: a box the network calls a vehicle reads its height at this percentile of its
    pixels above the ground (+ half a row), not at ``height_percentile``. A vehicle's top is a
    roof of hundreds of pixels at one height; the highest of v2's scattered decoded heights there
    overshoots it: held-out tracked vehicles read 24-31 cm high at 100, 14-16 cm off (median bias
    -2 to -6 cm) at 80 (people's and cyclists' boxes keep ``height_percentile``: their top is a
    head a few pixels wide; below 80 a box's roof is too small a share of it and single frames
    read low: docs/results.md, 2026-12-05 twenty-first session). The big moving blobs kept for the
    vehicles the head misses read at it too (not with ``keep_motion_blobs``, which keeps walkers'
    blobs as well: twenty-second session)."""
    background: str = "knn"
    """Background subtractor: 'mog2', 'cnt', 'knn', 'gsoc' or 'none' (height map only)."""
    work_width: int = 480
    """Background subtraction and blob finding run at this width in pixels (0 = source width).
    480, not 320 (docs/results.md, 2026-12-05 fourteenth session): at 320 a walker of a 640-pixel
    or wider frame is 6-8 work pixels wide, and the 3 pixels the foreground is grown by on each side
    outweigh him, so his blob failed the foreground-share test (Oxford: covered 0.57 -> 0.65;
    640x480 generator sets HOTA up 0.01-0.05); it costs ~4 ms a frame at 640x360."""
    background_prime_frames: int = 30
    """Frames sampled from the start of a file whose median seeds the background model (0 = off)."""
    background_prime_s: float = 30.0
    """The sample is spread over this many seconds from the start (or the whole clip if shorter)."""
    height_percentile: float = 100.0
    """Single-frame height = this percentile of the height map inside the blob (robust top)."""
    min_area_px: int = 40
    """Above-ground blobs smaller than this (in pixels of the processed frame,
    ``capture.max_width``) are ignored."""
    min_object_height_m: float = 0.5
    """Blobs whose top is lower than this are clutter, not objects."""
    max_object_height_m: float = 5.0
    """Blobs whose top is higher than this are scenery (buildings, trees), not movers (a bus is ~3.5 m)."""
    min_foreground_share: float = 0.4
    """Blobs less than this share foreground are clutter (rain or leaves over a static structure)."""
    min_foreground_piece_px: int = 8
    """Foreground pieces smaller than this (processed-frame pixels) are sensor noise, dropped before blobs are grown."""
    height_measurement_noise_m: float = 0.15
    """Base standard deviation of one frame's height measurement."""
    consistency_gain: float = 1.0
    """Matched points' height-change residual, times this, is added to the measurement noise."""


@dataclass
class TrackingConfig:
    min_hits: int = 2
    """Detections in a row before a track is confirmed (reported), at least ..."""
    confirm_s: float = 0.2
    """... and at least this long in source time (10 fps: 2 detections, 25 fps: 5)."""
    backfill: bool = True
    """Once a track is confirmed, its tentative frames are reported too (they held its
    detections; at 25 fps the first 4 frames of every track were missing). Outputs wait for
    the frames whose tentative tracks are not yet settled: a live source's by up to confirm_s."""
    fill_gaps_s: float = 0.6
    """A confirmed track found again at most this long after its last detection: the frames between
    get boxes interpolated between the two detections (not the prediction from the first), and are
    reported as the track's. Outputs wait while such a gap may still close; a live source's do not
    (its alerts stay prompt: its gaps keep their predicted boxes). 0 = off."""
    smooth_s: float = 0.2
    """Files: a track's box in a frame with a detection becomes a straight line's fit to its
    detections' boxes within this long either side (the motion filter has seen only the frames
    before; less jitter). Outputs wait this long; a live source's do not (0 = off)."""
    max_misses: int = 30
    """Frames without a detection before a track is deleted, at least ..."""
    max_miss_s: float = 4.0
    """... and at least this long in source time (10 fps: 40 frames, 25 fps: 100)."""
    iou_gate: float = 0.1
    """Minimum IoU for an association."""
    height_process_noise_m: float = 0.002
    """Per-frame random walk of the height state: near zero, objects do not grow."""
    ignore_channels: list[str] = field(default_factory=list)
    """Height channels the tracker does not fuse (e.g. ["geometry", "box"]: the network's own
    heights, as issue 20 checks them on real footage)."""
    network_bias_share: float = 0.3
    """Std of the network's bias on one object, as a share of its height (constant over frames)."""
    geometry_bias_factor: float = 1.0
    """Std of the geometry's bias on one object, in units of its first measurement's pixel noise
    (trk_dev20 people: per-object mean error rms 16.5 cm against 17.8 cm stated noise)."""
    motion_gate_chi2: float = 13.28
    """Mahalanobis gate of a detection box against a track's prediction (chi-square, 4 dof; 99 %)."""
    vote_weight: float = 0.5
    """Weight of matched-point votes in the association cost (IoU has weight 1)."""
    min_vote_share: float = 0.3
    """A pair below iou_gate is still allowed when this share of the track's points votes for it."""
    colour_gate: float = 0.4
    """A box of the network's head whose colour signature (``stages.colour_signature``: Hellinger
    distance, 0 same colours, 1 none in common) lies further than this from a track's is not that
    track's object, unless it lies on the track's prediction (IoU >= 0.7); 1 = off (blobs carry no
    colours: ``stages.tracking._one_object``). Walkers side by side swapped tracks on box overlap
    and motion alone (Oxford Town Centre)."""
    colour_weight: float = 0.5
    """Weight of that distance in the association cost (IoU has weight 1)."""
    height_gate_sigma: float = 4.0
    """Height measurements further than this many standard deviations from the track are outliers."""
    stature_window: int = 10
    """Frames in a walker's stature window (upper quantile of recent heights; 0 = off)."""
    stature_quantile: float = 0.75
    """Quantile of the stature window fed to the height filter for people."""


@dataclass
class CameraConfig:
    height_m: float = 0.0
    """Camera height above the ground in metres (0 = unknown)."""
    calibration: str = ""
    """OpenCV-convention calibration JSON ("" = none)."""
    fov_deg: float = 60.0
    """Horizontal field of view assumed when no calibration is given."""
    pitch_deg: float = 0.0
    """Depression of the optical axis below the horizon (0 = unknown); with height_m, a full pose."""
    roll_deg: float = 0.0
    """Rotation about the optical axis, positive when the horizon's right end is higher."""
    height_std_m: float = 0.0
    """Uncertainty of height_m (self-calibration prints it; 0 = exact)."""
    pitch_std_deg: float = 0.0
    """Uncertainty of pitch_deg (a self-calibrated pose: ``heightpipe calibrate``, or read from the
    first frames; 0 = exact). With roll_std_deg, focal_std_pct and height_std_m it widens every
    height's reported std by the error the camera makes on it (the same on every frame)."""
    roll_std_deg: float = 0.0
    """Uncertainty of roll_deg (0 = exact)."""
    focal_std_pct: float = 0.0
    """Uncertainty of the focal length (fov_deg), per cent (0 = exact)."""
    self_calibrated: bool = False
    """height_m/pitch_deg/roll_deg came from `heightpipe calibrate`: heights are flagged as such."""
    point_noise_px: float = 2.0
    """Standard deviation of detected foot/top points, for the geometry height's noise."""
    rescale_network: bool = True
    """Calibrated cameras: scale the network's heights by its median ratio to the geometry's on people."""
    read_scene_frames: int = 60
    """Told only height_m, a run over a file first reads pitch, roll and focal length from this
    many frames of its first read_scene_s seconds (v2's camera heads and the scene's straight
    lines, as ``heightpipe calibrate --camera-height`` does) and then runs posed (0 = off: v2's
    heads guess the camera in the run). 60 rather than 30 (2026-12-05): on four of five held-out
    sets and Oxford Town Centre the people came out better (Oxford 12.3 -> 8.6 cm; one set of
    longer clips 12.2 -> 14.5), for ~0.7 s more at the start (docs/results.md)."""
    read_scene_s: float = 30.0
    """The span of the video's start those frames are spread over."""
    read_scene_live_s: float = 5.0
    """A live stream's camera is read over its first this many seconds instead, which are not
    processed (a stream cannot be read twice; 0 = not read: v2's heads guess it in the run)."""
    calibrate_frames: int = 300
    """``heightpipe calibrate --camera-height`` on a file or folder longer than this reads this
    many frames spread over all of it, not every frame (an hour of video is 90,000 network
    passes, ~45 minutes on two cores, for a camera that a few hundred frames read as well); 0 =
    every frame. ``--max-frames`` or ``--stride`` read from the start as asked instead."""


@dataclass
class OutputConfig:
    directory: str = "recordings"
    """Where `heightpipe run` writes when --out is not given."""
    rerun: str = "save"
    """'save' (.rrd file), 'spawn' (viewer + file), 'web' (rerun's web viewer served as set in
    [web], + file), 'serve' (gRPC + web viewer on all interfaces, fixed ports, + file) or 'off'."""
    mcap: bool = True
    """Write PREFIX.mcap."""
    csv: bool = True
    """Write PREFIX.tracks.csv."""
    objects: bool = True
    """Write PREFIX.objects.csv: one row per confirmed track (the table to hand on)."""
    ground_overlay: bool = False
    """Tint the ground plane in the rerun frame view (its layer can be toggled there either way)."""
    rrd_index: str = "auto"
    """Write rerun's index (the .rrd footer: fast seeking in long recordings) "on", "off", or
    "auto": for files, not for live streams. The index is kept in memory until the run ends, ~1.4
    kB per chunk (~2 MB per minute of 640x360 video), so an endless stream's process would grow
    without bound."""
    jpeg_quality: int = 75
    """JPEG quality of the frames stored in the recordings (75: MCAP under 2 GB per hour of the 640x360 sample)."""
    mcap_chunk_size: int = 1048576
    """MCAP chunk size in bytes: smaller chunks lose less on a hard kill."""
    flush_interval_s: float = 1.0
    """Close the open MCAP chunk at least this often (source time), bounding loss on kill -9."""
    height_map_scale: int = 2
    """Store the height map at 1/N resolution in the recordings (1 = full)."""
    height_map_every: int = 5
    """Store the height map (and ground mask) of every Nth processed frame only (1 = every frame)."""
    progress: bool = True
    """Show a progress bar on stderr."""


@dataclass
class WebConfig:
    """Where ``--rerun web`` (and ``replay --web``) serve rerun's web viewer."""

    bind: str = "127.0.0.1"
    """Address to listen on: loopback by default; "0.0.0.0" lets other machines watch."""
    web_port: int = 9090
    """HTTP port of the web viewer page."""
    grpc_port: int = 9876
    """Port the browser streams the recording from (rerun's gRPC proxy)."""
    memory_limit: str = "1GB"
    """The server keeps this much recent data for browsers that connect late (oldest dropped)."""
    keep_serving: bool = True
    """After the run or replay ends, keep serving until Ctrl-C so browsers can still look."""


@dataclass
class EventsConfig:
    """Where height-rule events go besides PREFIX.events.jsonl, MCAP and rerun."""

    webhook_url: str = ""
    """POST each event as JSON to this URL ("" = no webhook)."""
    webhook_timeout_s: float = 2.0
    """One POST attempt gives up after this long."""
    webhook_retries: int = 3
    """Attempts after the first, with back-off, before an event is given up (it stays in the JSONL)."""
    webhook_backoff_s: float = 0.5
    """First back-off delay; doubles after each failed attempt."""
    webhook_queue: int = 1000
    """Events waiting for the webhook at most; beyond that new ones are not posted (still in the JSONL)."""


@dataclass
class RuleConfig:
    """One ``[[rules]]`` entry: when a confirmed track's height is in range (in the zone) long enough."""

    name: str = ""
    cls: str = ""
    """Object class ('person', 'cyclist', 'vehicle', 'other'; "" = any). Spelled ``class`` in TOML."""
    min_height_m: float = 0.0
    """Fires at or above this height (0 = no lower bound)."""
    max_height_m: float = 0.0
    """... and at or below this height (0 = no upper bound)."""
    max_std_m: float = 0.0
    """Only once the height's standard deviation is at most this (0 = any): a settled height."""
    zone: list[list[float]] = field(default_factory=list)
    """Polygon [[x, y], ...] the track's foot point must lie in (empty = anywhere)."""
    zone_frame: str = "image"
    """'image' (pixels of the source frame) or 'ground' (metres on the ground plane; calibrated cameras)."""
    min_duration_s: float = 0.0
    """The condition must hold this long (source time) ..."""
    min_frames: int = 1
    """... and for this many processed frames in a row before the rule fires."""
    cooldown_s: float = 0.0
    """After firing for a track, the rule fires for it again only after the condition broke off and
    this much time passed (0 = once per track)."""


@dataclass
class SynthConfig:
    seed: int = 0
    """Root seed: same seed, same pixels."""
    sequences: int = 20
    frames: int = 60
    width: int = 320
    height: int = 240
    fps: float = 10.0
    workers: int = 2
    preset: str = ""
    """'paper' = the paper's five camera heights; "" = continuous 3.5-9.2 m."""
    test_fraction: float = 0.2
    """Share of layout seeds held out for testing (never trained on)."""
    shadows: bool = True
    """Sun shadows in clear day scenes (a 2048 shadow map; most of the render cost)."""
    msaa: int = 0
    """MSAA samples for the RGB pass (0, 2, 4, 8); labels and depth are never antialiased."""


@dataclass
class TrainConfig:
    formulation: str = "contact"
    """'contact': HeightNet v2, configured by [train_v2]; 'log_height': the v1 network (the shipped
    model's formulation), configured by the keys below."""
    seed: int = 0
    """Seeds weights, data order and augmentation: same seed and data, same model."""
    data: str = "data/synth_train"
    """Synth dataset folder (its 'train' split is used; 'test' is held out for eval)."""
    out: str = "runs/train"
    """Run folder: checkpoint.pt, log.csv, loss.png."""
    architecture: str = "light"
    """'light' (CPU default, MobileNetV2-style) or 'paper' (ResNeXt-101 LapDepth)."""
    backbone: str = ""
    """Encoder override: 'mobilenetv2', 'resnext50_32x4d', 'resnext101_32x8d' ("" = the architecture's)."""
    input_width: int = 320
    input_height: int = 192
    """Network input size (multiples of 16); every frame is resized to it, any aspect."""
    steps: int = 8000
    """Optimiser steps in total (a resumed run continues to this count)."""
    batch_size: int = 4
    """Pairs of consecutive frames per step (2x images)."""
    lr: float = 1e-3
    """Peak AdamW learning rate (linear warm-up, cosine decay to 5%)."""
    weight_decay: float = 1e-4
    si_lambda: float = 0.85
    """Balance of the scale-invariant log loss (0 = plain log MSE, 1 = fully scale-invariant)."""
    above_ground_weight: float = 1.0
    """Weight of the extra log-error term on pixels above 0.1 m (objects)."""
    above_ground_lambda: float = 0.0
    """Lambda of that term: 0 penalises a uniform under- or over-estimate of objects in full."""
    consistency_weight: float = 1.0
    """Weight of the height consistency loss between matched points of frames t-1, t (m^2)."""
    ground_weight: float = 0.2
    """Weight of the ground-plane cross-entropy."""
    target: str = "relative"
    """'relative' (height / camera height, scale-free) or 'metres'."""
    matcher: str = "lk"
    """Feature matches for the consistency loss: 'lk' (Lucas-Kanade tracks) or 'orb'."""
    max_matches: int = 64
    """Matches per frame pair used by the consistency loss."""
    checkpoint_every: int = 200
    """Steps between checkpoints (and log/plot refreshes)."""
    threads: int = 2
    """Torch CPU threads."""
    init_onnx: str = ""
    """Start from this exported model's weights (fine-tuning; BatchNorms stay frozen), "" = from scratch."""


@dataclass
class TrainV2Config:
    """HeightNet v2 (ground-contact offsets + camera heads): ``heightpipe train`` when
    ``train.formulation = "contact"``. The run folder is meant to be committed: training
    accumulates over working days on machines that are not kept."""

    seed: int = 0
    """Seeds weights, data order and augmentation."""
    data: str = "data/v2_train"
    """Synth dataset of training cameras (its 'train' split)."""
    data_command: str = ("heightpipe synth --out data/v2_train --sequences 1200 --frames 2 "
                         "--size 640x480,640x360 --seed 11 --split train --workers 2")
    """How ``data`` is made; run by ``heightpipe train`` when the folder is missing (fresh clone)."""
    sequences: int = 0
    """Train on the first N sequences by name (0 = all)."""
    test_data: str = "data/v2_test"
    """Held-out synth dataset (its 'test' split) for the learning curve; "" = none."""
    test_command: str = ("heightpipe synth --out data/v2_test --preset paper --sequences 100 --frames 2 "
                         "--size 640x480 --seed 12 --split test --workers 2")
    """How ``test_data`` is made when it is missing."""
    test_sequences: int = 50
    """Held-out sequences scored at each evaluation (first N by name, 0 = all)."""
    out: str = "heightnet/state/v2"
    """Run folder: checkpoint.pt (weights + float16 optimiser moments), log.csv, curve.csv."""
    input_width: int = 320
    input_height: int = 240
    """Network input (multiples of 32); whole frames are squashed to it, as at run time."""
    steps: int = 200000
    """Optimiser steps in total (a resumed run continues to this count; open-ended by design)."""
    batch_size: int = 4
    """Pairs of consecutive frames per step (2x images)."""
    lr: float = 1e-3
    """AdamW learning rate after a 200-step warm-up, constant until the first of ``lr_drops``."""
    lr_drops: list[int] = field(default_factory=lambda: [44750, 53000])
    """Steps at which the learning rate is multiplied by ``lr_drop_factor``: an open-ended run has
    no end to decay towards, so it drops where its held-out curve flattened (kept in the config,
    not edited into ``lr``, so the run stays a function of its config and step). The defaults
    are where the committed run's curve went flat."""
    lr_drop_factor: float = 0.3
    detection_lr_factor: float = 10.0
    """The detection head's learning rate is the network's times this from ``detection_lr_from``
    on: after the drops the shared trunk needs a small step, the head (a few convolutions learning
    new targets) a larger one."""
    detection_lr_from: int = 71500
    """The step from which ``detection_lr_factor`` applies (the committed run's head got it at 71,500)."""
    weight_decay: float = 1e-4
    ema_decay: float = 0.999
    """Decay of the weights' moving average, which is evaluated and exported (0 = the last step's)."""
    threads: int = 2
    """Torch CPU threads."""
    device: str = "cpu"
    """Where the network trains: "cpu", or "cuda" on a machine with an NVIDIA GPU (the state it
    writes loads anywhere)."""
    loader_workers: int = 0
    """Processes preparing training pairs beside the training loop (0 = in the loop, as on the
    2-core machine; a GPU is fed only with several). Same pairs, same order either way."""
    trunk: str = "plain"
    """'plain' (3x3 convolutions) or 'depthwise' (MobileNetV2 blocks; ~10x slower to train here)."""
    widths: list[int] = field(default_factory=lambda: [16, 32, 64, 128])
    """Encoder channels at 1/2, 1/4, 1/8, 1/16 of the input."""
    camera_channels: bool = False
    """CAM-Conv input channels from a known camera (the network then needs the camera to run)."""
    context: list[int] = field(default_factory=lambda: [2, 4, 8])
    """Dilations of residual context blocks at 1/16 (the receptive field tall objects need)."""
    detection: bool = True
    """Detection head (centre heatmaps + boxes per class) trained with the offsets."""
    detection_context: bool = True
    """The detection head also reads the 1/16 context features (big objects; grown at 500,000 images)."""
    detection_blocks: int = 1
    """Residual blocks deepening the detection head (heightnet/contact_model.py ``DetectionHead``;
    the committed run grew one at 604,000 images)."""
    detection_motion: bool = True
    """The detection head also reads each cell's change since the last frame (a motion path that
    starts at zero; the ONNX file then takes the previous frame as a second input). Grown at step
    86,250 (690,000 images) of the committed run."""
    detection_fine: bool = True
    """The detection head's centre heatmaps and boxes at 1/2 of the input instead of 1/4: a fine
    path upsamples the head and corrects it from the decoder's 1/2 features (starts as the 1/4
    outputs upsampled; heightnet/contact_model.py ``DetectionHead``). Grown at step 119,752 of the
    committed run."""
    detection_big: bool = False
    """A second detection head of its own for near, big objects (64 input pixels tall and more) on
    the 1/16 context features (heightnet/contact_model.py ``BigObjectHead``): the 1/2 head finds
    almost none of them, and teaching it them cost it small walkers (docs/results.md, 2026-12-07).
    A network grown with it starts with an empty big-object heatmap."""
    big_head_only: bool = False
    """Train the big-object head alone: everything else, the rest of the detection head included,
    keeps its averaged weights, so what the small head finds stays bit for bit."""
    head_only: bool = True
    """Train the detection head alone: the rest of the network keeps its averaged weights,
    BatchNorm included, so heights stay as they are and a step costs about half (no backward pass
    through the trunk). The committed run does so from 604,000 images; a fresh run sets false."""
    refine: int = 8
    """Channels of the full-resolution refinement of offsets and ground (0 = none): half-resolution
    outputs blur thin objects (people, cyclists) into the ground around them."""
    gate: bool = True
    """Offsets cut by a learnt gate on the full-resolution ground logit, so that the half-resolution
    offset head can predict a smooth field instead of thin outlines (heightnet/contact_model.py)."""
    position: bool = True
    """Input channels saying where each pixel lies in its source frame (crops included), so that
    offsets can lean towards the vertical vanishing point (heightnet/contact_model.py)."""
    crop_probability: float = 0.5
    """Share of samples that are native-resolution windows around a mover (else whole frames)."""
    appearance: float = 0.6
    """Share of pairs whose look is randomised (gamma, channels, grey, blur, texture, noise, JPEG;
    heightnet/appearance.py) so that the network cannot lean on the generator's flat renders
    (the committed run's head from step 86,250; 0 = the look as rendered)."""
    still_pairs: float = 0.0
    """Share of pairs shown as one frame twice, so that a head reading motion (detection_motion)
    sees objects with no motion at all: trained on walking pairs alone, it found fewer people
    standing still than the head without motion did (dev set: 42 % against 52 % of their boxes)."""
    zoom_crops: float = 0.0
    """Share of samples that are windows smaller than the input around a mover, enlarged to it
    (1.5-3x): near objects, 80 px tall and more at 320x240, are rare in whole frames and native
    crops, and the head found almost none of them (0 = none: samples drawn as before). Tried 0.3
    for the head alone, 40 minutes: it still found none (docs/results.md)."""
    centre_core: float = 0.0
    """Objects at least 64 input pixels tall are centres wherever their heatmap Gaussian reaches
    this (0 = at their centre cell alone, CenterNet's target; ``heightnet.detection_targets``).
    Tried 0.9 for the head alone with ``zoom_crops`` 0.3, 40 + 30 minutes: without the big-blob
    rule the head found twice the near, big objects, but the dev set lost HOTA (0.473 -> 0.465) and
    vehicle heights (docs/results.md, 2026-12-07)."""
    whole_boxes: bool = False
    """Detection boxes span the whole object, hidden parts included (the generator's boxes, as
    evaluation scores them), for objects at least 30 % in view; False: the pixels in view. Taught
    the parts in view, the head boxed a half-hidden walker (dev set: 21 % of required boxes are
    less than 90 % in view) short of the box evaluation and his feet ask for. 75 minutes of
    head-only training with it gained on the validation set, lost on the held-out test set: off
    (docs/results.md, 2026-12-06 thirtieth session)."""
    max_matches: int = 64
    """Matched points per frame pair for the height-consistency loss."""
    checkpoint_every: int = 250
    log_every: int = 20
    eval_every: int = 500
    """Steps between held-out evaluations (rows of curve.csv)."""
    offset_all_weight: float = 0.3
    """Offset loss on every labelled pixel (the object-weighted mover term has weight 1)."""
    height_weight: float = 10.0
    """Metric height (m, Huber) on mover pixels decoded with the true camera."""
    si_weight: float = 1.0
    """The paper's scale-invariant log loss on decoded mover heights."""
    consistency_weight: float = 1.0
    """The paper's height consistency (Eq. 2, m^2) at matched points of frames t-1, t."""
    ground_weight: float = 1.0
    """Ground-plane cross-entropy (the offset gate cuts the offsets along this logit)."""
    camera_weight: float = 1.0
    """Camera heads' Huber fit + variance NLL (pitch, roll, focal length; whole frames only)."""
    detection_weight: float = 3.0
    """Centre focal loss + box L1 (+ GIoU, ``box_giou_weight``) of the detection head."""
    box_giou_weight: float = 1.0
    """Generalised-IoU loss on the head's boxes beside the L1 (inside ``detection_weight``); 0 = off."""


@dataclass
class RunConfig:
    overlapped: bool = True
    """Run capture, the network, the other stages and the sinks on their own threads (same output)."""
    queue_frames: int = 4
    """Frames waiting between two threads at most: back-pressure for files, drops for live sources."""
    reuse_backlog: int = 1
    """Live sources: with this many frames waiting for the network, the next one reuses the last
    network outputs instead (no height measured on it); 0 = never (frames are only dropped)."""


@dataclass
class BatchConfig:
    workers: int = 0
    """Parallel videos (0 = one per core)."""
    engine: str = "local"
    """'local' process pool or 'ray'."""


@dataclass
class Config:
    capture: CaptureConfig = field(default_factory=CaptureConfig)
    ground: GroundConfig = field(default_factory=GroundConfig)
    height: HeightConfig = field(default_factory=HeightConfig)
    matching: MatchingConfig = field(default_factory=MatchingConfig)
    objects: ObjectsConfig = field(default_factory=ObjectsConfig)
    tracking: TrackingConfig = field(default_factory=TrackingConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    output: OutputConfig = field(default_factory=OutputConfig)
    web: WebConfig = field(default_factory=WebConfig)
    events: EventsConfig = field(default_factory=EventsConfig)
    rules: list[RuleConfig] = field(default_factory=list)
    """``[[rules]]``: height rules; each firing becomes an event (stages/height_rules.py)."""
    run: RunConfig = field(default_factory=RunConfig)
    synth: SynthConfig = field(default_factory=SynthConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    train_v2: TrainV2Config = field(default_factory=TrainV2Config)
    batch: BatchConfig = field(default_factory=BatchConfig)


def _coerce(where: str, value: Any, annotation: Any) -> Any:
    """Check one TOML value against its dataclass annotation (ints widen to floats)."""
    if annotation is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    origin = typing.get_origin(annotation)
    if origin is list:
        (item_type,) = typing.get_args(annotation)
        if not isinstance(value, list):
            raise ConfigError(f"{where} must be a list, got {value!r}")
        return [_coerce(f"{where}[{i}]", v, item_type) for i, v in enumerate(value)]
    if annotation is int and isinstance(value, bool):
        raise ConfigError(f"{where} must be an integer, got {value!r}")
    if not isinstance(value, annotation):
        raise ConfigError(f"{where} must be {annotation.__name__}, got {type(value).__name__} {value!r}")
    return value


MOVED_KEYS = {("tracking", name): "objects" for name in (
    "background", "work_width", "background_prime_frames", "background_prime_s", "height_percentile",
    "min_area_px", "min_object_height_m", "max_object_height_m", "min_foreground_share",
    "min_foreground_piece_px", "height_measurement_noise_m", "consistency_gain")}
"""(old section, key) -> the section that holds the key now (object extraction left [tracking];
keys added to [objects] since were never in [tracking])."""
NETWORK_OBJECTS_KEYS = ("score_person", "score_cyclist", "score_vehicle", "score_motion", "moving_share",
                        "motion_contrast", "still_s", "continue_score", "motion_ends",
                        "keep_motion_blobs", "vehicle_height_percentile")
"""[objects] keys that only ``source = "network"`` reads."""


def _rule(values: Any, where: str) -> RuleConfig:
    """One [[rules]] table; its ``class`` key is the dataclass's ``cls``."""
    if not isinstance(values, dict):
        raise ConfigError(f"{where} must be a table")
    rule = RuleConfig()
    hints = typing.get_type_hints(RuleConfig)
    for key, value in values.items():
        name = "cls" if key == "class" else key
        if name not in hints or key == "cls":
            raise ConfigError(f"unknown key '{key}' in {where} (known: "
                              f"{', '.join('class' if k == 'cls' else k for k in hints)})")
        setattr(rule, name, _coerce(f"{where}.{key}", value, hints[name]))
    return rule


def _apply(config: Config, table: dict[str, Any], source: str) -> None:
    sections = {f.name: f for f in dataclasses.fields(Config)}
    for section_name, values in table.items():
        if section_name not in sections:
            raise ConfigError(f"unknown config section [{section_name}] in {source} "
                              f"(known: {', '.join(sections)})")
        if section_name == "rules":
            if not isinstance(values, list):
                raise ConfigError(f"rules in {source} must be an array of tables: [[rules]]")
            config.rules = [_rule(v, f"[[rules]] #{i + 1} in {source}") for i, v in enumerate(values)]
            continue
        if not isinstance(values, dict):
            raise ConfigError(f"[{section_name}] in {source} must be a table")
        section = getattr(config, section_name)
        hints = typing.get_type_hints(type(section))
        for key, value in values.items():
            moved_to = MOVED_KEYS.get((section_name, key))
            if moved_to is not None:
                raise ConfigError(f"config key '{section_name}.{key}' in {source} has moved: "
                                  f"it is '{moved_to}.{key}' now (section [{moved_to}])")
            if key not in hints:
                raise ConfigError(f"unknown config key '{section_name}.{key}' in {source} "
                                  f"(known: {', '.join(hints)})")
            setattr(section, key, _coerce(f"{section_name}.{key} in {source}", value, hints[key]))


def parse_override(text: str) -> dict[str, Any]:
    """Turn ``section.key=value`` (value in TOML syntax, bare words as strings) into a table."""
    if "=" not in text or "." not in text.split("=", 1)[0]:
        raise ConfigError(f"override {text!r} must look like section.key=value")
    dotted, raw = text.split("=", 1)
    section, key = dotted.strip().split(".", 1)
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw
    return {section: {key: value}}


HEIGHT_ONLY_MODEL = "v2"
"""The shipped model a run told only its camera's height uses (``model_for_camera``)."""


def told_height_only(camera: CameraConfig, file_has_pose: bool = True) -> bool:
    """Whether ``[camera]`` gives the camera's height and nothing else of its pose: no pitch, and
    no calibration file, or (``file_has_pose`` False) one with the lens alone."""
    return camera.height_m > 0 and camera.pitch_deg == 0.0 and not (camera.calibration and file_has_pose)


def model_for_camera(config: Config, file_has_pose: bool = True) -> Config:
    """The config a run uses: with ``height.model = ""`` and only the camera's height given (no
    calibration file, no pitch), HeightNet v2 with its detection head finding the objects
    (``objects.source = "network"``); otherwise ``config`` as it is.

    Why: v2's camera heads learnt the pitch and focal length that case lacks. Told only the camera
    height, tracked people were 25 cm off with v2 against 61 with v1 on 40 held-out generator
    sequences, 11.6 against 37.5 cm on Oxford Town Centre (docs/results.md, 2026-12-04 eighth
    session); with a full pose v1 and its blobs stay (Oxford: 10.5 cm against v2's 27.6). A model
    named in the config (``v1``, ``v2``, a path) is used as named, with ``[objects]`` as given.
    A run told only the height is posed first (``pipeline/scene_camera.py``), so this case is
    left to ``[camera] read_scene_frames = 0`` and to scenes that could not pose the run.
    ``file_has_pose``: whether ``[camera] calibration`` names a file with a pose (the caller
    reads it: ``pipeline.scene_camera.knows_height_only``); one with the lens alone leaves the
    height the only part of the pose known, v2's case.
    """
    if config.height.model or not told_height_only(config.camera, file_has_pose):
        return config
    return dataclasses.replace(config, height=dataclasses.replace(config.height, model=HEIGHT_ONLY_MODEL),
                               objects=dataclasses.replace(config.objects, source="network"))


def load_config(path: str | Path | None = None, overrides: list[str] | None = None) -> Config:
    """Defaults, then ``path`` (or ./config.toml, or the repository's), then overrides."""
    config = Config()
    if path is None:
        for candidate in (Path.cwd() / "config.toml", DEFAULT_CONFIG_PATH):
            if candidate.is_file():
                path = candidate
                break
    elif not Path(path).is_file():
        raise ConfigError(f"config file not found: {path}")
    if path is not None:
        try:
            table = tomllib.loads(Path(path).read_text())
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"{path} is not valid TOML: {exc}") from None
        _apply(config, table, str(path))
    for text in overrides or []:
        _apply(config, parse_override(text), f"--set {text}")
    return config
