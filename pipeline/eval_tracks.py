"""``heightpipe eval-tracks DATA``: tracking quality and per-object height error on generator data.

For every sequence of a synthetic dataset (``synth.dataset``) the tracking pipeline runs as in
``heightpipe run`` (feature matching, object extraction, geometry, tracking) with heights from
the shipped network or, with ``--heights oracle``, from the ground-truth height map. Reported:

* HOTA, MOTA, IDF1 and ID switches over all sequences (class-agnostic boxes, IoU 0.5 for
  CLEAR / Identity). The metrics are computed by trackeval when the optional ``eval`` extra is
  installed and otherwise by the built-in implementation below, which follows trackeval's code.
* Height error per ground-truth object: the final height of the track that followed it versus
  the truth, next to the single-frame estimates (detections) versus the truth; per class and
  per camera height.
* Occlusions: objects hidden for a while and seen again, whether their track kept its id and
  its height.
* Misses (``--misses``): every required box by what became of it (tracked, detected but not
  tracked, merged with other objects, box off, not detected), per class, size and scene.

Ground-truth boxes that are mostly hidden (``--min-visibility``) are "don't care": they are
neither required nor penalised, and a track box on one is dropped (as MOTChallenge does with
occluded and distractor boxes).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import time
from collections import Counter, defaultdict
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from core.config import Config
from core.errors import HeightpipeError

# Generator classes in the tracker's coarse terms.
COARSE_CLASS = {"pedestrian": "person", "cyclist": "cyclist", "car": "vehicle", "van": "vehicle",
                "truck": "vehicle", "bus": "vehicle"}
MATCH_IOU = 0.5
HOTA_ALPHAS = np.arange(0.05, 0.99, 0.05)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("data", help="synthetic dataset folder (manifest.json), from `heightpipe synth`")
    parser.add_argument("--split", choices=("test", "train", "all"), default="test",
                        help="which sequences (default: the held-out test split)")
    parser.add_argument("--sequences", nargs="+", metavar="NAME", help="only these sequences")
    parser.add_argument("--heights", choices=("model", "oracle"), default="model",
                        help="height maps from the network (default) or the ground truth (oracle)")
    parser.add_argument("--no-geometry", action="store_true",
                        help="do not fuse the calibrated-camera geometry height")
    parser.add_argument("--max-frames", type=int, default=0, help="frames per sequence (0 = all)")
    parser.add_argument("--min-visibility", type=float, default=0.3,
                        help="ground-truth boxes less visible than this are don't-care (default 0.3)")
    parser.add_argument("--min-box-px", type=float, default=20.0,
                        help="ground-truth boxes shorter than this (pixels) are don't-care (default 20)")
    parser.add_argument("--min-frames", type=int, default=10,
                        help="objects matched in fewer frames are left out of the height errors")
    parser.add_argument("--misses", action="store_true",
                        help="also print why required objects were missed (not detected, merged, box off, "
                             "detected but not tracked) per class, size, time of day, weather")
    parser.add_argument("--json", metavar="FILE", help="write the full report as JSON")
    parser.add_argument("--plot", metavar="PNG", help="picture of per-track height series (first sequence)")
    parser.add_argument("--record", metavar="RRD", help="rerun recording of the first sequence")


def main(args: argparse.Namespace, config: Config) -> int:
    from synth.dataset import list_sequences

    root = Path(args.data)
    if not (root / "manifest.json").is_file():
        raise HeightpipeError(f"{root} is not a synthetic dataset (no manifest.json)")
    sequences = list_sequences(root, split=None if args.split == "all" else args.split)
    if args.sequences:
        wanted = set(args.sequences)
        sequences = [s for s in sequences if s.name in wanted]
        missing = wanted - {s.name for s in sequences}
        if missing:
            raise HeightpipeError(f"no such sequence in {root} ({args.split} split): {', '.join(sorted(missing))}")
    if not sequences:
        raise HeightpipeError(f"no {args.split} sequences in {root}")
    if args.plot:
        from core.extras import require

        require("matplotlib", "synth", "eval-tracks --plot")

    runs = []
    start = time.perf_counter()
    for index, sequence in enumerate(sequences):
        record_path = Path(args.record) if (args.record and index == 0) else None
        run = run_sequence(sequence, config, heights=args.heights, geometry=not args.no_geometry,
                           max_frames=args.max_frames, record=record_path)
        runs.append(run)
        print(f"  {sequence.name}: {len(run.frames)} frames, {run.fps:.1f} fps", file=sys.stderr)
        if index == 0 and args.plot:
            plot_height_series(run, Path(args.plot), args.min_visibility)
    report = evaluate(runs, min_visibility=args.min_visibility, min_frames=args.min_frames,
                      min_box_px=args.min_box_px)
    report["heights"] = args.heights
    report["geometry"] = not args.no_geometry
    report["wall_s"] = round(time.perf_counter() - start, 1)
    print(format_report(report))
    if args.misses:
        print(format_misses(report["misses"]))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(report, indent=2, default=_json_default))
    return 0


# --------------------------------------------------------------------------------------------
# Running the pipeline over one sequence
# --------------------------------------------------------------------------------------------

@dataclass
class TruthBox:
    object_id: int
    cls: str
    """Coarse class: person, cyclist, vehicle."""
    box: tuple[float, float, float, float]
    visibility: float
    height_m: float


@dataclass
class OutputBox:
    track_id: int
    box: tuple[float, float, float, float]
    height_m: float
    height_std_m: float
    cls: str
    height_source: str
    updated: bool


@dataclass
class DetectionBox:
    box: tuple[float, float, float, float]
    height_m: float


@dataclass
class FrameRecord:
    truth: list[TruthBox]
    tracks: list[OutputBox]
    """Confirmed tracks, updated or predicted."""
    detections: list[DetectionBox]


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


def camera_info(sequence):
    from core.packets import CameraInfo

    camera = sequence.meta.camera
    return CameraInfo(width=camera.width, height=camera.height, K=np.asarray(camera.K, float),
                      R=np.asarray(camera.R, float), t=np.asarray(camera.t, float).reshape(3),
                      height_m=float(camera.height_m), source="calibration")


def build_eval_chain(sequence, config: Config, heights: str, geometry: bool):
    """``heightpipe run``'s stages for a generator sequence (``pipeline.stage_chain``).

    With ``heights="oracle"`` the true height and ground maps stand in for the network, and the
    stages that correct the network's scale and bias are told there is none to correct.
    """
    from pipeline.stage_chain import build_stage_chain

    if heights == "oracle":
        # True heights are metric: there is no network scale to learn (nor to doubt), nor a
        # per-object bias for the height filter to learn.
        config = replace(config, camera=replace(config.camera, rescale_network=False),
                         tracking=replace(config.tracking, network_bias_share=0.0))
    return build_stage_chain(config, camera_info(sequence),
                             heights=OracleHeights(sequence) if heights == "oracle" else None,
                             geometry=geometry)


def prime_sequence_background(sequence, chain, config: Config) -> None:
    """Seeds the object extractor's background model as ``heightpipe run`` does for files."""
    import cv2

    from stages.capture import background_indices

    chain.prime([cv2.cvtColor(sequence.frame(i).rgb, cv2.COLOR_RGB2BGR)
                 for i in background_indices(len(sequence), sequence.meta.fps,
                                             config.tracking.background_prime_frames,
                                             config.tracking.background_prime_s)])


def sequence_packets(sequence, chain, max_frames: int = 0):
    """Each frame of a generator sequence through the stage chain: yields (truth frame, packet).

    The stages are closed when the frames run out or the caller closes the generator.
    """
    import cv2

    from core.packets import Frame, FramePacket

    camera = camera_info(sequence)
    count = len(sequence) if max_frames <= 0 else min(max_frames, len(sequence))
    try:
        for index in range(count):
            truth_frame = sequence.frame(index)
            image = cv2.cvtColor(truth_frame.rgb, cv2.COLOR_RGB2BGR)
            yield truth_frame, chain.process(FramePacket(frame=Frame(index, truth_frame.time_s, image), camera=camera))
    finally:
        chain.close()


def run_sequence(sequence, config: Config, heights: str = "model", geometry: bool = True,
                 max_frames: int = 0, record: Path | None = None) -> SequenceRun:
    """Runs the tracking pipeline over one generator sequence and keeps what evaluation needs."""
    meta = sequence.meta
    run = SequenceRun(sequence.name, float(meta.camera.height_m), meta.weather, meta.time_of_day)
    chain = build_eval_chain(sequence, config, heights, geometry)
    prime_sequence_background(sequence, chain, config)
    sink = _open_recording(record, config, sequence.name) if record else None
    start = time.perf_counter()
    try:
        with contextlib.closing(sequence_packets(sequence, chain, max_frames)) as packets:
            for _, packet in packets:
                if sink is not None:
                    sink.write(packet)
                run.frames.append(FrameRecord(
                    truth=[TruthBox(o.id, COARSE_CLASS.get(o.cls, "other"), tuple(map(float, o.box)),
                                    float(o.visible_fraction), float(o.height_m))
                           for o in sequence.objects(packet.frame.index)],
                    tracks=[OutputBox(t.track_id, tuple(map(float, t.box)), t.height_m, t.height_std_m,
                                      t.cls, t.height_source, t.updated)
                            for t in packet.tracks if t.confirmed],
                    detections=[DetectionBox(tuple(map(float, d.box)), d.height_m) for d in packet.detections],
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


# --------------------------------------------------------------------------------------------
# MOT metrics: HOTA, CLEAR (MOTA, IDSW), Identity (IDF1)
# --------------------------------------------------------------------------------------------

def iou_matrix(boxes_a, boxes_b) -> np.ndarray:
    from stages.association import iou_matrix as _iou

    return _iou(boxes_a, boxes_b)


def matched_at_iou(boxes_a, boxes_b) -> list[tuple[int, int]]:
    """One-to-one (Hungarian on IoU) pairs of ``a`` and ``b`` indices whose IoU reaches ``MATCH_IOU``:
    the matching of CLEAR and Identity, used for everything here that asks "which track is this"."""
    from scipy.optimize import linear_sum_assignment

    if len(boxes_a) == 0 or len(boxes_b) == 0:
        return []
    iou = iou_matrix(boxes_a, boxes_b)
    return [(int(r), int(c)) for r, c in zip(*linear_sum_assignment(-iou)) if iou[r, c] >= MATCH_IOU]


def cared_for(truth: TruthBox, min_visibility: float, min_box_px: float) -> bool:
    """Whether a ground-truth box is required (else don't-care): visible enough and big enough."""
    return truth.visibility >= min_visibility and truth.box[3] >= min_box_px


def mot_data(run: SequenceRun, min_visibility: float, min_box_px: float = 0.0) -> dict:
    """One sequence in trackeval's per-sequence format, with don't-care boxes removed."""
    from scipy.optimize import linear_sum_assignment

    gt_ids, tracker_ids, similarity = [], [], []
    for frame in run.frames:
        cared = [t for t in frame.truth if cared_for(t, min_visibility, min_box_px)]
        ignored = [t for t in frame.truth if not cared_for(t, min_visibility, min_box_px)]
        outputs = [o for o in frame.tracks if o.updated]
        if ignored and outputs:
            # A track box that best explains a don't-care box is neither TP nor FP.
            everything = cared + ignored
            iou = iou_matrix([t.box for t in everything], [o.box for o in outputs])
            rows, cols = linear_sum_assignment(-iou)
            drop = {c for r, c in zip(rows, cols) if r >= len(cared) and iou[r, c] >= MATCH_IOU}
            outputs = [o for i, o in enumerate(outputs) if i not in drop]
        gt_ids.append([t.object_id for t in cared])
        tracker_ids.append([o.track_id for o in outputs])
        similarity.append(iou_matrix([t.box for t in cared], [o.box for o in outputs]))
    gt_map = {g: i for i, g in enumerate(sorted({g for ids in gt_ids for g in ids}))}
    tr_map = {g: i for i, g in enumerate(sorted({g for ids in tracker_ids for g in ids}))}
    return {
        "num_timesteps": len(run.frames),
        "num_gt_ids": len(gt_map), "num_tracker_ids": len(tr_map),
        "num_gt_dets": sum(len(ids) for ids in gt_ids),
        "num_tracker_dets": sum(len(ids) for ids in tracker_ids),
        "gt_ids": [np.array([gt_map[g] for g in ids], dtype=int) for ids in gt_ids],
        "tracker_ids": [np.array([tr_map[g] for g in ids], dtype=int) for ids in tracker_ids],
        "similarity_scores": similarity,
    }


def _trackeval_metrics():
    """trackeval's metric objects, or None when the optional extra is not installed."""
    try:
        with contextlib.redirect_stdout(io.StringIO()):   # it prints about optional datasets
            from trackeval.metrics import CLEAR, HOTA, Identity
            return {"HOTA": HOTA(), "CLEAR": CLEAR({"THRESHOLD": MATCH_IOU, "PRINT_CONFIG": False}),
                    "Identity": Identity({"THRESHOLD": MATCH_IOU, "PRINT_CONFIG": False})}
    except ImportError:
        return None


def mot_metrics(datas: list[dict], use_trackeval: bool | None = None) -> dict:
    """Combined HOTA / CLEAR / Identity over sequences (trackeval if available and allowed)."""
    return mot_metrics_by_group(datas, {}, use_trackeval)[0]


def mot_metrics_by_group(datas: list[dict], groups: dict[str, list[int]],
                         use_trackeval: bool | None = None) -> tuple[dict, dict[str, dict]]:
    """``mot_metrics`` over all sequences, and over each group of them (indices into ``datas``).

    Each sequence is scored once; the groups only combine its parts.
    """
    metrics = _trackeval_metrics() if use_trackeval in (None, True) else None
    if use_trackeval and metrics is None:
        raise HeightpipeError("trackeval is not installed (pip install --no-deps trackeval==1.3.0)")
    if metrics is not None:
        parts = [{name: metric.eval_sequence(d) for name, metric in metrics.items()} for d in datas]
        combiners = {name: (lambda chosen, metric=metric: metric.combine_sequences(
            {str(i): part for i, part in enumerate(chosen)})) for name, metric in metrics.items()}
        engine = "trackeval"
    else:
        parts = [{"HOTA": _hota(d), "CLEAR": _clear(d), "Identity": _identity(d)} for d in datas]
        combiners = {"HOTA": _combine_hota, "CLEAR": _combine_clear, "Identity": _combine_identity}
        engine = "built-in"

    def combined(indices) -> dict:
        scores = {name: combine([parts[i][name] for i in indices]) for name, combine in combiners.items()}
        hota, clear, identity = scores["HOTA"], scores["CLEAR"], scores["Identity"]
        return {
            "engine": engine,
            "HOTA": float(np.mean(hota["HOTA"])), "DetA": float(np.mean(hota["DetA"])),
            "AssA": float(np.mean(hota["AssA"])),
            "MOTA": float(clear["MOTA"]), "IDSW": int(clear["IDSW"]), "IDF1": float(identity["IDF1"]),
            "gt_dets": int(clear["CLR_TP"] + clear["CLR_FN"]), "false_positives": int(clear["CLR_FP"]),
            "misses": int(clear["CLR_FN"]),
        }

    return combined(range(len(datas))), {group: combined(indices) for group, indices in groups.items()}


def _hota(data: dict) -> dict:
    """HOTA for one sequence, as trackeval.metrics.HOTA computes it (Luiten et al., IJCV 2021)."""
    n_alpha = len(HOTA_ALPHAS)
    res = {k: np.zeros(n_alpha) for k in ("TP", "FN", "FP", "AssA")}
    if data["num_tracker_dets"] == 0 or data["num_gt_dets"] == 0:
        res["FN"][:] = data["num_gt_dets"]
        res["FP"][:] = data["num_tracker_dets"]
        return res
    from scipy.optimize import linear_sum_assignment

    potential = np.zeros((data["num_gt_ids"], data["num_tracker_ids"]))
    gt_count = np.zeros((data["num_gt_ids"], 1))
    tr_count = np.zeros((1, data["num_tracker_ids"]))
    for gt, tr, sim in zip(data["gt_ids"], data["tracker_ids"], data["similarity_scores"]):
        denominator = sim.sum(0)[None, :] + sim.sum(1)[:, None] - sim
        sim_iou = np.where(denominator > np.finfo(float).eps, sim / np.maximum(denominator, 1e-12), 0.0)
        potential[gt[:, None], tr[None, :]] += sim_iou
        gt_count[gt] += 1
        tr_count[0, tr] += 1
    alignment = potential / (gt_count + tr_count - potential)
    matches = [np.zeros_like(potential) for _ in HOTA_ALPHAS]
    for gt, tr, sim in zip(data["gt_ids"], data["tracker_ids"], data["similarity_scores"]):
        if len(gt) == 0 or len(tr) == 0:
            res["FP"] += len(tr)
            res["FN"] += len(gt)
            continue
        rows, cols = linear_sum_assignment(-(alignment[gt[:, None], tr[None, :]] * sim))
        for a, alpha in enumerate(HOTA_ALPHAS):
            ok = sim[rows, cols] >= alpha - np.finfo(float).eps
            res["TP"][a] += ok.sum()
            res["FN"][a] += len(gt) - ok.sum()
            res["FP"][a] += len(tr) - ok.sum()
            matches[a][gt[rows[ok]], tr[cols[ok]]] += 1
    for a in range(n_alpha):
        ass = matches[a] / np.maximum(1, gt_count + tr_count - matches[a])
        res["AssA"][a] = np.sum(matches[a] * ass) / max(1.0, res["TP"][a])
    return res


def _combine_hota(parts: list[dict]) -> dict:
    tp = sum(p["TP"] for p in parts)
    fn = sum(p["FN"] for p in parts)
    fp = sum(p["FP"] for p in parts)
    ass_a = sum(p["AssA"] * p["TP"] for p in parts) / np.maximum(1e-10, tp)
    det_a = tp / np.maximum(1, tp + fn + fp)
    return {"HOTA": np.sqrt(det_a * ass_a), "DetA": det_a, "AssA": ass_a}


def _clear(data: dict) -> dict:
    """CLEAR MOT counts for one sequence, as trackeval.metrics.CLEAR counts them."""
    from scipy.optimize import linear_sum_assignment

    res = {"TP": 0, "FN": 0, "FP": 0, "IDSW": 0}
    last_tracker = np.full(data["num_gt_ids"], np.nan)       # for ID switches (any gap)
    previous_frame = np.full(data["num_gt_ids"], np.nan)     # for continuing matches
    for gt, tr, sim in zip(data["gt_ids"], data["tracker_ids"], data["similarity_scores"]):
        if len(gt) == 0 or len(tr) == 0:
            res["FP"] += len(tr)
            res["FN"] += len(gt)
            if len(gt) and not len(tr):
                previous_frame[:] = np.nan
            continue
        score = 1000.0 * (tr[None, :] == previous_frame[gt[:, None]]) + sim
        score[sim < MATCH_IOU - np.finfo(float).eps] = 0
        rows, cols = linear_sum_assignment(-score)
        ok = score[rows, cols] > np.finfo(float).eps
        matched_gt, matched_tr = gt[rows[ok]], tr[cols[ok]]
        before = last_tracker[matched_gt]
        res["IDSW"] += int(np.sum(~np.isnan(before) & (matched_tr != before)))
        last_tracker[matched_gt] = matched_tr
        previous_frame[:] = np.nan
        previous_frame[matched_gt] = matched_tr
        res["TP"] += len(matched_gt)
        res["FN"] += len(gt) - len(matched_gt)
        res["FP"] += len(tr) - len(matched_gt)
    return res


def _combine_clear(parts: list[dict]) -> dict:
    total = {k: sum(p[k] for p in parts) for k in ("TP", "FN", "FP", "IDSW")}
    mota = (total["TP"] - total["FP"] - total["IDSW"]) / max(1, total["TP"] + total["FN"])
    return {"MOTA": mota, "IDSW": total["IDSW"], "CLR_TP": total["TP"], "CLR_FN": total["FN"],
            "CLR_FP": total["FP"]}


def _identity(data: dict) -> dict:
    """IDTP of the best one-to-one id mapping (maximising IDTP minimises IDFN + IDFP)."""
    from scipy.optimize import linear_sum_assignment

    potential = np.zeros((data["num_gt_ids"], data["num_tracker_ids"]))
    for gt, tr, sim in zip(data["gt_ids"], data["tracker_ids"], data["similarity_scores"]):
        g, t = np.nonzero(sim >= MATCH_IOU)
        potential[gt[g], tr[t]] += 1
    idtp = 0.0
    if potential.size:
        rows, cols = linear_sum_assignment(-potential)
        idtp = float(potential[rows, cols].sum())
    return {"IDTP": idtp, "gt": data["num_gt_dets"], "tr": data["num_tracker_dets"]}


def _combine_identity(parts: list[dict]) -> dict:
    idtp = sum(p["IDTP"] for p in parts)
    total = sum(p["gt"] + p["tr"] for p in parts)
    return {"IDF1": 2 * idtp / max(1, total)}


# --------------------------------------------------------------------------------------------
# Height errors per ground-truth object
# --------------------------------------------------------------------------------------------

@dataclass
class ObjectHeight:
    sequence: str
    object_id: int
    cls: str
    camera_height_m: float
    weather: str
    true_height_m: float
    matched_frames: int
    tracked_height_m: float | None
    """Final height of the track that followed the object (None: never tracked)."""
    tracked_std_m: float | None
    track_ids: list[int]
    single_frame_errors_m: list[float]


def object_heights(run: SequenceRun, min_visibility: float, min_box_px: float = 0.0) -> list[ObjectHeight]:
    """Per ground-truth object: its track's final height, and every single-frame estimate."""
    truth_heights: dict[int, list[float]] = defaultdict(list)
    classes: dict[int, str] = {}
    track_votes: dict[int, dict[int, int]] = defaultdict(lambda: defaultdict(int))
    last_height: dict[tuple[int, int], tuple[float, float]] = {}
    single: dict[int, list[float]] = defaultdict(list)
    for frame in run.frames:
        for t in frame.truth:
            truth_heights[t.object_id].append(t.height_m)
            classes[t.object_id] = t.cls
        cared = [t for t in frame.truth if cared_for(t, min_visibility, min_box_px)]
        if not cared:
            continue
        outputs = [o for o in frame.tracks if o.updated]
        for r, c in matched_at_iou([t.box for t in cared], [o.box for o in outputs]):
            key = (cared[r].object_id, outputs[c].track_id)
            track_votes[key[0]][key[1]] += 1
            last_height[key] = (outputs[c].height_m, outputs[c].height_std_m)
        for r, c in matched_at_iou([t.box for t in cared], [d.box for d in frame.detections]):
            if np.isfinite(frame.detections[c].height_m):
                single[cared[r].object_id].append(frame.detections[c].height_m)
    results = []
    for object_id, heights in truth_heights.items():
        # Stature: the gait's hip drop only lowers the head, so the truth is the largest value.
        true_height = float(np.max(heights))
        votes = track_votes.get(object_id, {})
        main_track = max(votes, key=votes.get) if votes else None
        tracked = last_height.get((object_id, main_track)) if main_track is not None else None
        results.append(ObjectHeight(
            sequence=run.name, object_id=object_id, cls=classes[object_id],
            camera_height_m=run.camera_height_m, weather=run.weather, true_height_m=true_height,
            matched_frames=int(sum(votes.values())),
            tracked_height_m=None if tracked is None else float(tracked[0]),
            tracked_std_m=None if tracked is None else float(tracked[1]),
            track_ids=sorted(votes),
            single_frame_errors_m=[float(h - true_height) for h in single.get(object_id, [])],
        ))
    return results


def height_summary(objects: list[ObjectHeight], min_frames: int) -> dict:
    """Median absolute errors, tracked vs single-frame, for the objects tracked long enough."""
    usable = [o for o in objects if o.tracked_height_m is not None and np.isfinite(o.tracked_height_m)
              and o.matched_frames >= min_frames]
    tracked = [abs(o.tracked_height_m - o.true_height_m) for o in usable]
    single = [abs(e) for o in usable for e in o.single_frame_errors_m]
    return {
        "objects": len(usable),
        "tracked_median_error_m": float(np.median(tracked)) if tracked else None,
        "tracked_p90_error_m": float(np.percentile(tracked, 90)) if tracked else None,
        "tracked_median_bias_m": (float(np.median([o.tracked_height_m - o.true_height_m for o in usable]))
                                  if usable else None),
        "single_frame_median_error_m": float(np.median(single)) if single else None,
        "single_frames": len(single),
    }


# --------------------------------------------------------------------------------------------
# Occlusions: hidden for a while, seen again
# --------------------------------------------------------------------------------------------

def occlusion_events(run: SequenceRun, min_visibility: float, min_hidden_frames: int,
                     min_box_px: float = 0.0) -> list[dict]:
    """Objects tracked, then hidden (visibility < 0.1) for a while, then tracked again: same id?

    Before and after, the object must be required as the MOT metrics require it (``cared_for``):
    a car a few pixels high on the horizon is don't-care there, and no occlusion event here.
    """
    history: dict[int, list[tuple[int, float, bool, int | None, float | None]]] = defaultdict(list)
    for index, frame in enumerate(run.frames):
        outputs = [o for o in frame.tracks if o.updated]
        matched = {frame.truth[r].object_id: outputs[c]
                   for r, c in matched_at_iou([t.box for t in frame.truth], [o.box for o in outputs])}
        for t in frame.truth:
            out = matched.get(t.object_id)
            history[t.object_id].append((index, t.visibility, cared_for(t, min_visibility, min_box_px),
                                         out.track_id if out else None, out.height_m if out else None))
    events = []
    for object_id, rows in history.items():
        hidden_run, before = 0, None
        for index, visibility, required, track_id, height in rows:
            if visibility < 0.1:
                hidden_run += 1
                continue
            if required and track_id is not None:
                if hidden_run >= min_hidden_frames and before is not None:
                    events.append({"sequence": run.name, "object_id": object_id,
                                   "hidden_frames": hidden_run, "id_before": before[0],
                                   "id_after": track_id, "kept_id": before[0] == track_id,
                                   "height_before_m": before[1], "height_after_m": height})
                before = (track_id, height)
                # Only a match ends the occlusion: an object seen again but not yet re-found
                # (or found by a new track only later) is still an event, kept or not.
                hidden_run = 0
    return events


# --------------------------------------------------------------------------------------------
# Misses: why a required object had no track box
# --------------------------------------------------------------------------------------------

MISS_KINDS = ("tracked", "detected, no track", "merged with others", "box off", "not detected")
# A detection overlapping a truth box at least this much (IoU) is about that object, if off.
MISS_NEAR_IOU = 0.2
# A detection covering this share of another object's box holds that object too.
MISS_COVER_SHARE = 0.3


def miss_breakdown(runs: list[SequenceRun], min_visibility: float, min_box_px: float = 0.0) -> dict[str, dict]:
    """Every required truth box, by what became of it, per group (class, box height, time of day,
    weather, camera height): tracked (a track box at IoU >= 0.5); detected but no track there;
    its detection merged with other objects; its detection's box off (IoU 0.2-0.5); not detected.

    It says where the missing HOTA is: in detection (the height map and the foreground) or in
    tracking.
    """
    from stages.association import intersection_matrix

    counts: dict[str, Counter] = defaultdict(Counter)
    for run in runs:
        for frame in run.frames:
            cared = [t for t in frame.truth if cared_for(t, min_visibility, min_box_px)]
            if not cared:
                continue
            outputs = [o for o in frame.tracks if o.updated]
            tracked = {r for r, _ in matched_at_iou([t.box for t in cared], [o.box for o in outputs])}
            detections = [d.box for d in frame.detections]
            visible = [t.box for t in frame.truth if t.visibility > 0.05]
            near = iou_matrix([t.box for t in cared], detections) if detections else np.zeros((len(cared), 0))
            for i, truth in enumerate(cared):
                best = int(np.argmax(near[i])) if near.shape[1] else -1
                overlap = near[i, best] if best >= 0 else 0.0
                if i in tracked:
                    kind = "tracked"
                elif overlap >= MATCH_IOU:
                    kind = "detected, no track"
                elif overlap >= MISS_NEAR_IOU:
                    areas = np.array([b[2] * b[3] for b in visible], dtype=float)
                    cover = intersection_matrix(visible, [detections[best]])[:, 0] / np.maximum(areas, 1e-9)
                    kind = "merged with others" if (cover > MISS_COVER_SHARE).sum() >= 2 else "box off"
                else:
                    kind = "not detected"
                h = truth.box[3]
                size = "< 40" if h < 40 else ("40-80" if h < 80 else ">= 80")
                for group in ("all", f"class {truth.cls}", f"box {size} px", f"{run.time_of_day}",
                              f"weather {run.weather}", f"camera at {run.camera_height_m:.1f} m"):
                    counts[group][kind] += 1
    return {group: {kind: int(c[kind]) for kind in MISS_KINDS} for group, c in counts.items()}


def format_misses(breakdown: dict[str, dict]) -> str:
    lines = ["  required boxes by what became of them (share of the group's boxes):",
             f"    {'group':<20}" + "".join(f"{kind:>20}" for kind in MISS_KINDS) + "   boxes"]
    for group in sorted(breakdown, key=lambda g: (g != "all", g)):
        row = breakdown[group]
        total = max(sum(row.values()), 1)
        lines.append(f"    {group:<20}" + "".join(f"{row[kind] / total:20.2f}" for kind in MISS_KINDS)
                     + f"   {sum(row.values()):5d}")
    return "\n".join(lines)


# --------------------------------------------------------------------------------------------
# Report
# --------------------------------------------------------------------------------------------

def sequence_groups(runs: list[SequenceRun]) -> dict[str, list[int]]:
    """Indices of the runs in each group a sequence belongs to whole: camera height, weather, time of day.

    Tracking is scored per group too, because it is lost unevenly (rain at night, a high
    camera's small people) and the overall number hides where.
    """
    groups: dict[str, list[int]] = defaultdict(list)
    for index, run in enumerate(runs):
        for group in (f"camera at {run.camera_height_m:.1f} m", f"weather {run.weather}", run.time_of_day):
            groups[group].append(index)
    return dict(sorted(groups.items()))


def evaluate(runs: list[SequenceRun], min_visibility: float = 0.3, min_frames: int = 10,
             use_trackeval: bool | None = None, min_box_px: float = 0.0) -> dict:
    datas = [mot_data(run, min_visibility, min_box_px) for run in runs]
    groups = sequence_groups(runs)
    mot, mot_by_group = mot_metrics_by_group(datas, groups, use_trackeval)
    mot_by_group = {group: dict(scores, sequences=len(groups[group])) for group, scores in mot_by_group.items()}
    objects = [o for run in runs for o in object_heights(run, min_visibility, min_box_px)]
    events = [e for run in runs for e in occlusion_events(run, min_visibility, min_hidden_frames=5,
                                                          min_box_px=min_box_px)]
    by_class = {cls: height_summary([o for o in objects if o.cls == cls], min_frames)
                for cls in sorted({o.cls for o in objects})}
    by_camera = {f"{h:.1f}": height_summary([o for o in objects if round(o.camera_height_m, 1) == h], min_frames)
                 for h in sorted({round(o.camera_height_m, 1) for o in objects})}
    by_weather = {w: height_summary([o for o in objects if o.weather == w], min_frames)
                  for w in sorted({o.weather for o in objects})}
    return {
        "min_visibility": min_visibility, "min_box_px": min_box_px, "min_frames": min_frames,
        "sequences": [r.name for r in runs],
        "frames": sum(len(r.frames) for r in runs),
        "mot": mot,
        "mot_by_group": mot_by_group,
        "height_all": height_summary(objects, min_frames),
        "height_by_class": by_class,
        "height_by_camera_height": by_camera,
        "height_by_weather": by_weather,
        "occlusions": events,
        "misses": miss_breakdown(runs, min_visibility, min_box_px),
        "objects": [asdict(o) for o in objects],
    }


def _cm(value: float | None) -> str:
    return "   -  " if value is None else f"{100 * value:6.1f}"


def format_report(report: dict) -> str:
    mot = report["mot"]
    lines = [
        f"eval-tracks: {len(report['sequences'])} sequences, {report['frames']} frames, "
        f"heights from {report.get('heights', '?')}"
        f"{' + geometry' if report.get('geometry') else ''}; don't-care: visibility < "
        f"{report['min_visibility']}, boxes < {report['min_box_px']:g} px",
        f"  HOTA {mot['HOTA']:.3f}  (DetA {mot['DetA']:.3f}, AssA {mot['AssA']:.3f})  "
        f"MOTA {mot['MOTA']:.3f}  IDF1 {mot['IDF1']:.3f}  ID switches {mot['IDSW']}  "
        f"FP {mot['false_positives']}  misses {mot['misses']} / {mot['gt_dets']}  [{mot['engine']}]",
        "  height error (cm), median over objects      tracked  single-frame  objects",
    ]

    def row(label: str, summary: dict) -> str:
        return (f"    {label:<38} {_cm(summary['tracked_median_error_m'])}   "
                f"{_cm(summary['single_frame_median_error_m'])}      {summary['objects']:4d}")

    by_group = report.get("mot_by_group", {})
    if len(report["sequences"]) > 1:
        lines.insert(2, "  tracking by group                           HOTA    IDF1  sequences")
        lines[3:3] = [f"    {group:<38} {mot['HOTA']:.3f}   {mot['IDF1']:.3f}     {mot['sequences']:4d}"
                      for group, mot in by_group.items()]
    lines.append(row("all", report["height_all"]))
    for cls, summary in report["height_by_class"].items():
        lines.append(row(f"class {cls}", summary))
    for height, summary in report["height_by_camera_height"].items():
        lines.append(row(f"camera at {height} m", summary))
    for weather, summary in report["height_by_weather"].items():
        lines.append(row(f"weather {weather}", summary))
    events = report["occlusions"]
    if events:
        kept = sum(e["kept_id"] for e in events)
        changes = [abs(e["height_after_m"] - e["height_before_m"]) for e in events
                   if e["kept_id"] and e["height_before_m"] is not None and e["height_after_m"] is not None
                   and np.isfinite(e["height_before_m"]) and np.isfinite(e["height_after_m"])]
        lines.append(f"  occlusions (hidden >= 5 frames): {len(events)}, id kept in {kept}; "
                     f"median height change {_cm(float(np.median(changes)) if changes else None).strip()} cm")
    return "\n".join(lines)


def _json_default(value):
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


# --------------------------------------------------------------------------------------------
# Picture of the per-track height series
# --------------------------------------------------------------------------------------------

def objects_followed(run: SequenceRun, min_visibility: float) -> dict[int, ObjectHeight]:
    """Track id -> the ground-truth object it matched (of two, the one matched longer)."""
    followed = {}
    for obj in sorted(object_heights(run, min_visibility), key=lambda o: o.matched_frames):
        for track_id in obj.track_ids:
            followed[track_id] = obj
    return followed


def plot_height_series(run: SequenceRun, path: Path, min_visibility: float) -> None:
    """Each confirmed track's height (line, ±1 std band) over frames, with its object's truth dashed.

    A track drawn in colour follows a ground-truth object (the one it matched most often) and
    its legend says which class and true height; tracks that follow no object (clutter,
    fragments) are thin and grey.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    series: dict[int, list[tuple[int, float, float]]] = defaultdict(list)
    single: dict[int, list[tuple[int, float]]] = defaultdict(list)
    for index, frame in enumerate(run.frames):
        for out in frame.tracks:
            if np.isfinite(out.height_m):
                series[out.track_id].append((index, out.height_m, out.height_std_m))
        updated = [o for o in frame.tracks if o.updated]
        if updated and frame.detections:
            # The detection a track was updated with is the one its box now overlaps most.
            iou = iou_matrix([o.box for o in updated], [d.box for d in frame.detections])
            for row, out in enumerate(updated):
                best = int(np.argmax(iou[row]))
                if iou[row, best] > 0.3 and np.isfinite(frame.detections[best].height_m):
                    single[out.track_id].append((index, frame.detections[best].height_m))
    followed = objects_followed(run, min_visibility)
    fig, (upright, others) = plt.subplots(1, 2, figsize=(13, 4.8), dpi=110, sharey=True,
                                          gridspec_kw={"width_ratios": [3, 2]})
    colours = plt.get_cmap("tab10")
    n = 0
    for track_id, points in sorted(series.items()):
        frames, heights, stds = (np.array(v) for v in zip(*points))
        obj = followed.get(track_id)
        if obj is None:
            others.plot(frames, heights, color="0.6", linewidth=0.8)
            continue
        ax = upright if obj.cls in ("person", "cyclist") else others
        colour = colours(n % 10)
        n += 1
        ax.plot(frames, heights, color=colour, linewidth=1.6,
                label=f"track {track_id}: {obj.cls}, truth {obj.true_height_m:.2f} m")
        ax.fill_between(frames, heights - stds, heights + stds, color=colour, alpha=0.2)
        ax.axhline(obj.true_height_m, color=colour, linestyle="--", linewidth=0.8)
        if single[track_id]:
            ax.scatter(*zip(*single[track_id]), color=colour, s=6, alpha=0.6)
    others.plot([], [], color="0.6", linewidth=0.8, label="tracks of no object")
    upright.set_title("people and cyclists", fontsize=9)
    others.set_title("vehicles and the rest", fontsize=9)
    for ax in (upright, others):
        ax.set_xlabel("frame")
        ax.legend(loc="upper left", fontsize=7, ncol=2)
    upright.set_ylabel("tracked height (m)")
    fig.suptitle(f"{run.name} (camera {run.camera_height_m:.1f} m, {run.weather}, {run.time_of_day}): "
                 "tracked height (line, ±1 std), single-frame (dots), truth (dashed)", fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
