"""Scores of tracked sequences against their ground truth: MOT metrics, height errors, occlusions, misses.

* HOTA, MOTA, IDF1 and ID switches (class-agnostic boxes, IoU 0.5 for CLEAR / Identity),
  computed by trackeval when the optional ``eval`` extra is installed and otherwise by the
  built-in implementation below, which follows trackeval's code.
* Height error per ground-truth object: the final height of the track that followed it versus
  the truth, next to the single-frame estimates (detections) versus the truth.
* Occlusions: objects hidden for a while and seen again, whether their track kept its id and
  its height.
* Misses: every required box by what became of it.
* Detections: recall and precision of object extraction's boxes before tracking, class-agnostic
  and class-aware, per class, box height, camera height, weather and time of day.

Ground-truth boxes that are mostly hidden or too small are "don't care": neither required nor
penalised, and a track box on one is dropped (as MOTChallenge does with occluded boxes). Parked
vehicles are don't-care regions (as KITTI's DontCare areas): the generator draws them but gives
them no box, so a box no required object claims that lies mostly on a parked vehicle's pixels is
dropped too, neither a true nor a false positive.
"""

from __future__ import annotations

import contextlib
import io
from collections import Counter, defaultdict
from dataclasses import asdict, dataclass

import numpy as np

from core.errors import HeightpipeError
from pipeline.eval_sequences import EVAL_CLASSES, DetectionBox, SequenceRun, TruthBox

MATCH_IOU = 0.5
# An unmatched box lying at least this share on don't-care region pixels (parked vehicles) is left
# out: a car's box is mostly car, a walker's box beside a parked car mostly not.
REGION_SHARE = 0.5
HOTA_ALPHAS = np.arange(0.05, 0.99, 0.05)
# The localisation thresholds the report shows DetA and AssA at: HOTA is their mean over all 19, so
# a run that finds objects but boxes them loosely is told apart from one that misses them.
SHOWN_ALPHAS = (0.05, 0.25, 0.5, 0.75, 0.95)


# --------------------------------------------------------------------------------------------
# MOT metrics: HOTA, CLEAR (MOTA, IDSW), Identity (IDF1)
# --------------------------------------------------------------------------------------------

def iou_matrix(boxes_a, boxes_b) -> np.ndarray:
    from stages.association import iou_matrix as _iou

    return _iou(boxes_a, boxes_b)


def matched_at_iou(boxes_a, boxes_b, min_iou: float = MATCH_IOU) -> list[tuple[int, int]]:
    """One-to-one (Hungarian on IoU) pairs of ``a`` and ``b`` indices whose IoU reaches ``min_iou``
    (``MATCH_IOU``: the matching of CLEAR and Identity, used for everything here that asks "which
    track is this")."""
    from scipy.optimize import linear_sum_assignment

    if len(boxes_a) == 0 or len(boxes_b) == 0:
        return []
    iou = iou_matrix(boxes_a, boxes_b)
    return [(int(r), int(c)) for r, c in zip(*linear_sum_assignment(-iou)) if iou[r, c] >= min_iou]


def cared_for(truth: TruthBox, min_visibility: float, min_box_px: float) -> bool:
    """Whether a ground-truth box is required (else don't-care): visible enough and big enough."""
    return truth.visibility >= min_visibility and truth.box[3] >= min_box_px


def on_dont_care(cared: list[TruthBox], ignored: list[TruthBox], boxes,
                 region: np.ndarray | None = None) -> set[int]:
    """Indices of the ``boxes`` (x, y, w, h) that best explain a don't-care truth box (one-to-one
    over all the truth, IoU >= ``MATCH_IOU``) or, claimed by no required box, lie mostly on the
    don't-care ``region`` (``FrameRecord.region``): neither true nor false positives, so left
    out of the scores."""
    from scipy.optimize import linear_sum_assignment

    if len(boxes) == 0 or (not ignored and region is None):
        return set()
    iou = iou_matrix([t.box for t in cared + ignored], boxes)
    rows, cols = linear_sum_assignment(-iou) if iou.size else ([], [])
    matched = {int(c): int(r) for r, c in zip(rows, cols) if iou[r, c] >= MATCH_IOU}
    drop = {c for c, r in matched.items() if r >= len(cared)}
    if region is not None:
        drop |= {c for c, box in enumerate(boxes)
                 if c not in matched and region_share(region, box) >= REGION_SHARE}
    return drop


def region_share(region: np.ndarray, box) -> float:
    """The share of a box (x, y, w, h) lying on a region given as ``np.packbits`` rows."""
    height, width = region.shape[0], region.shape[1] * 8
    x, y, w, h = box
    x0, y0 = max(int(np.floor(x)), 0), max(int(np.floor(y)), 0)
    x1, y1 = min(int(np.ceil(x + w)), width), min(int(np.ceil(y + h)), height)
    area = max(w * h, 1e-9)
    if x1 <= x0 or y1 <= y0:
        return 0.0
    return float(np.unpackbits(region[y0:y1], axis=1)[:, x0:x1].sum() / area)


def mot_data(run: SequenceRun, min_visibility: float, min_box_px: float = 0.0) -> dict:
    """One sequence in trackeval's per-sequence format, with don't-care boxes removed."""
    gt_ids, tracker_ids, similarity = [], [], []
    for frame in run.frames:
        cared = [t for t in frame.truth if cared_for(t, min_visibility, min_box_px)]
        ignored = [t for t in frame.truth if not cared_for(t, min_visibility, min_box_px)]
        outputs = frame.seen_tracks
        drop = on_dont_care(cared, ignored, [o.box for o in outputs], frame.region)
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
            "by_iou": _at_thresholds(hota),
            "MOTA": float(clear["MOTA"]), "IDSW": int(clear["IDSW"]), "IDF1": float(identity["IDF1"]),
            "gt_dets": int(clear["CLR_TP"] + clear["CLR_FN"]), "false_positives": int(clear["CLR_FP"]),
            "misses": int(clear["CLR_FN"]),
        }

    return combined(range(len(datas))), {group: combined(indices) for group, indices in groups.items()}


def _at_thresholds(hota: dict) -> dict[str, dict[str, float]]:
    """DetA and AssA at each of ``SHOWN_ALPHAS`` (keys "0.05" ...), from arrays over ``HOTA_ALPHAS``."""
    shown = {}
    for alpha in SHOWN_ALPHAS:
        a = int(np.argmin(np.abs(HOTA_ALPHAS - alpha)))
        shown[f"{alpha:.2f}"] = {"DetA": float(hota["DetA"][a]), "AssA": float(hota["AssA"][a])}
    return shown


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
        outputs = frame.seen_tracks
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
        **uncertainty_cover(usable),
    }


def uncertainty_cover(objects: list[ObjectHeight]) -> dict:
    """How honest the tracks' reported height uncertainty is: the share of objects whose true
    height lies within their track's final ±1 and ±2 standard deviations (68 % and 95 % if the
    errors are as wide as said; a smaller share means the run claims more than it knows)."""
    scored = [o for o in objects if o.tracked_std_m is not None and np.isfinite(o.tracked_std_m)]
    z = [abs(o.tracked_height_m - o.true_height_m) / max(o.tracked_std_m, 1e-9) for o in scored]
    return {"within_1_std": float(np.mean(np.asarray(z) <= 1.0)) if z else None,
            "within_2_std": float(np.mean(np.asarray(z) <= 2.0)) if z else None,
            "uncertainty_objects": len(z)}


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
        outputs = frame.seen_tracks
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

SIZE_BANDS_PX = (40.0, 80.0, 160.0)
"""Edges of the box-height bands (pixels) that the misses and the detection scores are broken down by."""


def size_group(box) -> str:
    """The group of a box by its height in pixels: "box < 40 px", "box 40-80 px", ... "box >= 160 px"."""
    edges = SIZE_BANDS_PX
    band = int(np.searchsorted(edges, box[3], side="right"))
    if band == 0:
        return f"box < {edges[0]:g} px"
    if band == len(edges):
        return f"box >= {edges[-1]:g} px"
    return f"box {edges[band - 1]:g}-{edges[band]:g} px"


SIZE_GROUPS = tuple(size_group((0, 0, 0, h)) for h in (0.0, *SIZE_BANDS_PX))

STANDING_MPS = 0.3
"""Slower than this on the ground is standing: the generator's walkers go 0.9-1.6 m/s, its
standing people 0 (a background model primed with them in view cannot see them: issue 21 asks
for their recall by name)."""
MOTION_GROUPS = (f"standing (< {STANDING_MPS:g} m/s)", "moving")


def motion_groups(truth: TruthBox) -> tuple[str, ...]:
    """A truth box's group by its ground speed: standing or moving (none where it is unknown)."""
    if not np.isfinite(truth.speed_mps):
        return ()
    return (MOTION_GROUPS[0] if truth.speed_mps < STANDING_MPS else MOTION_GROUPS[1],)


def scene_groups(run: SequenceRun) -> tuple[str, str, str]:
    """The groups a whole sequence belongs to: camera height, weather, time of day."""
    return f"camera at {run.camera_height_m:.1f} m", f"weather {run.weather}", run.time_of_day


MISS_KINDS = ("tracked", "detected, no track", "merged with others", "box off", "not detected")


@dataclass(frozen=True)
class MissConstants:
    """How a miss is told apart (the rule is in docs/design.md, Configuration; ``MATCH_IOU`` and
    ``HOTA_ALPHAS`` are the published metrics' definitions, not choices of ours)."""

    miss_near_iou: float = 0.2
    """A detection overlapping a truth box at least this much (IoU) is about that object, if off:
    below the 0.5 a match needs, above what a neighbour's box reaches."""
    miss_cover_share: float = 0.3
    """A detection covering this share of another object's box holds that object too."""
    min_seen_share: float = 0.05
    """An object less visible than this is under no box (wholly hidden: nothing of it to hold)."""
    wrong_cover_share: float = 0.5
    """A wrong detection covering this share of an object's box is a box on that object (off, or
    on several); one covering less lies on part of it."""


CONSTANTS = MissConstants()


def covered_shares(boxes, box) -> np.ndarray:
    """The share of each of ``boxes`` (x, y, w, h) that ``box`` covers."""
    from stages.association import intersection_matrix

    areas = np.array([b[2] * b[3] for b in boxes], dtype=float)
    return intersection_matrix(boxes, [box])[:, 0] / np.maximum(areas, 1e-9)


def holds_several(boxes, box) -> bool:
    """Whether ``box`` covers ``CONSTANTS.miss_cover_share`` of two or more of ``boxes``: one box
    over a group, not on any one of them."""
    return int((covered_shares(boxes, box) > CONSTANTS.miss_cover_share).sum()) >= 2


def miss_breakdown(runs: list[SequenceRun], min_visibility: float, min_box_px: float = 0.0) -> dict[str, dict]:
    """Every required truth box, by what became of it, per group (class, box height, standing or
    moving, time of day, weather, camera height): tracked (a track box at IoU >= 0.5); detected
    but no track there; its detection merged with other objects; its detection's box off (IoU
    0.2-0.5); not detected.

    It says where the missing HOTA is: in detection (the height map and the foreground) or in
    tracking.
    """
    counts: dict[str, Counter] = defaultdict(Counter)
    for run in runs:
        for frame in run.frames:
            cared = [t for t in frame.truth if cared_for(t, min_visibility, min_box_px)]
            if not cared:
                continue
            outputs = frame.seen_tracks
            tracked = {r for r, _ in matched_at_iou([t.box for t in cared], [o.box for o in outputs])}
            detections = [d.box for d in frame.detections]
            visible = [t.box for t in frame.truth if t.visibility > CONSTANTS.min_seen_share]
            near = iou_matrix([t.box for t in cared], detections) if detections else np.zeros((len(cared), 0))
            for i, truth in enumerate(cared):
                best = int(np.argmax(near[i])) if near.shape[1] else -1
                overlap = near[i, best] if best >= 0 else 0.0
                if i in tracked:
                    kind = "tracked"
                elif overlap >= MATCH_IOU:
                    kind = "detected, no track"
                elif overlap >= CONSTANTS.miss_near_iou:
                    kind = "merged with others" if holds_several(visible, detections[best]) else "box off"
                else:
                    kind = "not detected"
                for group in ("all", f"class {truth.cls}", size_group(truth.box), *motion_groups(truth),
                              *scene_groups(run)):
                    counts[group][kind] += 1
    return {group: {kind: int(c[kind]) for kind in MISS_KINDS} for group, c in counts.items()}


def scored_detections(truth: list[TruthBox], detections: list[DetectionBox], min_visibility: float,
                      min_box_px: float = 0.0, region: np.ndarray | None = None):
    """(required truth boxes, the detections that are scored, their one-to-one matches at IoU 0.5):
    a detection that best explains a don't-care truth box, or lies unclaimed on the don't-care
    ``region``, is neither correct nor wrong, as in the MOT metrics."""
    cared = [t for t in truth if cared_for(t, min_visibility, min_box_px)]
    ignored = [t for t in truth if not cared_for(t, min_visibility, min_box_px)]
    drop = on_dont_care(cared, ignored, [d.box for d in detections], region)
    detections = [d for i, d in enumerate(detections) if i not in drop]
    return cared, detections, matched_at_iou([t.box for t in cared], [d.box for d in detections])


WRONG_KINDS = ("on don't-care objects only", "holds several objects", "off a required object",
               "on part of an object", "on nothing")
"""What lies under a detection the detection table counts wrong (``wrong_detection_breakdown``)."""


def wrong_detection_kind(detection_box, truth: list[TruthBox], min_visibility: float,
                         min_box_px: float = 0.0) -> str:
    """What lies under one wrong detection (one of ``WRONG_KINDS``).

    The objects under it are the visible ones it covers (``CONSTANTS.wrong_cover_share`` of their
    box) or overlaps (IoU >= ``CONSTANTS.miss_near_iou``). Only don't-care ones (small, mostly
    hidden): a box the MOT rule forgives only at IoU 0.5, which a box on a 5 x 17 px walker or on a
    hidden walker's visible half rarely reaches. Else it holds several objects, covers one
    required object with a box too big or shifted, or lies on part of one; or on nothing.
    """
    visible = [t for t in truth if t.visibility > CONSTANTS.min_seen_share]
    if not visible:
        return WRONG_KINDS[4]
    boxes = [t.box for t in visible]
    covered = covered_shares(boxes, detection_box) >= CONSTANTS.wrong_cover_share
    under = covered | (iou_matrix(boxes, [detection_box])[:, 0] >= CONSTANTS.miss_near_iou)
    if not under.any():
        return WRONG_KINDS[4]
    required = np.array([cared_for(t, min_visibility, min_box_px) for t in visible])
    if not (under & required).any():
        return WRONG_KINDS[0]
    if covered.sum() >= 2:
        return WRONG_KINDS[1]
    if (covered & required).any():
        return WRONG_KINDS[2]
    return WRONG_KINDS[3]


def wrong_detection_breakdown(runs: list[SequenceRun], min_visibility: float,
                              min_box_px: float = 0.0, tracks: bool = False) -> dict[str, dict]:
    """Every detection the detection table counts wrong, by what lies under it
    (``wrong_detection_kind``), per group (all, the class it claims, box height, time of day,
    weather, camera height); with ``tracks``, every track box the MOT metrics score (a track seen
    that frame) that matches no required box at IoU 0.5 instead: CLEAR's false positives (its
    matching also keeps last frame's pairs, so its count may differ by a few), which cost IDF1.

    Low precision has different cures: boxes on groups or on parts of objects are the detector's,
    boxes on nothing its false alarms, and boxes on don't-care objects mostly the evaluation's.
    """
    counts: dict[str, Counter] = defaultdict(Counter)
    for run in runs:
        for frame in run.frames:
            boxes = frame.seen_tracks if tracks else frame.detections
            _, detections, pairs = scored_detections(frame.truth, boxes, min_visibility, min_box_px, frame.region)
            correct = {c for _, c in pairs}
            for j, detection in enumerate(detections):
                if j in correct:
                    continue
                kind = wrong_detection_kind(detection.box, frame.truth, min_visibility, min_box_px)
                for group in ("all", f"class {detection.cls}", size_group(detection.box), *scene_groups(run)):
                    counts[group][kind] += 1
    return {group: {kind: int(c[kind]) for kind in WRONG_KINDS} for group, c in counts.items()}


# --------------------------------------------------------------------------------------------
# Detections: object extraction's boxes before tracking
# --------------------------------------------------------------------------------------------

DETECTION_COUNTS = ("truths", "found", "found_class", "detections", "correct", "correct_class")
"""Per group: required truth boxes; of them, matched by a detection (any class) and by a detection
of their class; detections (those on a don't-care box left out); of them, matched to a required
truth box (any class) and to one of their own class."""


def frame_detection_counts(truth: list[TruthBox], detections: list[DetectionBox],
                           min_visibility: float, min_box_px: float = 0.0,
                           region: np.ndarray | None = None) -> dict[str, Counter]:
    """One frame's detections against its required truth boxes, counted per group (``DETECTION_COUNTS``).

    One-to-one matching at IoU >= 0.5 (``matched_at_iou``), once over all boxes (class-agnostic)
    and once within each class (class-aware: a detection only counts for an object of its class).
    A truth box is counted in its class's and size's groups, a detection in those of the class
    and size it claims; "all" holds both. A detection that best explains a don't-care truth box,
    or lies unclaimed on the don't-care ``region``, is neither correct nor wrong, as in the MOT
    metrics.
    """
    cared, detections, pairs = scored_detections(truth, detections, min_visibility, min_box_px, region)
    same_class = []
    for cls in sorted({t.cls for t in cared} & {d.cls for d in detections}):
        rows = [i for i, t in enumerate(cared) if t.cls == cls]
        cols = [j for j, d in enumerate(detections) if d.cls == cls]
        same_class += [(rows[r], cols[c]) for r, c in
                       matched_at_iou([cared[i].box for i in rows], [detections[j].box for j in cols])]
    found, found_cls = {r for r, _ in pairs}, {r for r, _ in same_class}
    correct, correct_cls = {c for _, c in pairs}, {c for _, c in same_class}
    counts: dict[str, Counter] = defaultdict(Counter)
    for i, t in enumerate(cared):
        for group in ("all", f"class {t.cls}", size_group(t.box), *motion_groups(t)):
            counts[group].update(truths=1, found=int(i in found), found_class=int(i in found_cls))
    for j, d in enumerate(detections):
        for group in ("all", f"class {d.cls}", size_group(d.box)):
            counts[group].update(detections=1, correct=int(j in correct), correct_class=int(j in correct_cls))
    return counts


def _share(part: int, whole: int) -> float | None:
    return part / whole if whole else None


def detection_scores(runs: list[SequenceRun], min_visibility: float, min_box_px: float = 0.0) -> dict[str, dict]:
    """Recall and precision of the detections (before tracking), per group: all; class (person,
    cyclist, vehicle); box height band; standing or moving (recall only: a detection has no
    speed); and, sequence by sequence, camera height, weather, time of day (the groups of the
    HOTA table).

    ``recall`` = required truth boxes matched / required truth boxes, ``precision`` = detections
    matched / detections; ``class_recall`` and ``class_precision`` the same when a match needs the
    class right too. None where the group has nothing to divide by. Summed over all frames.

    Next to HOTA it separates the two ways tracking is lost: an object the detector never gave
    the tracker (low recall here) versus one detected and then not followed (association).
    """
    totals: dict[str, Counter] = defaultdict(Counter)
    for run in runs:
        for frame in run.frames:
            for group, counts in frame_detection_counts(frame.truth, frame.detections,
                                                        min_visibility, min_box_px, frame.region).items():
                totals[group].update(counts)
                if group == "all":
                    for scene in scene_groups(run):
                        totals[scene].update(counts)

    def order(group: str) -> tuple:
        classes = [f"class {c}" for c in EVAL_CLASSES]
        for rank, known in enumerate((["all"], classes, list(SIZE_GROUPS), list(MOTION_GROUPS))):
            if group in known:
                return rank, known.index(group), group
        if group.startswith("class "):
            return 1, len(classes), group
        return 4, 0, group

    table = {}
    for group in sorted(totals, key=order):
        c = totals[group]
        table[group] = {**{k: int(c[k]) for k in DETECTION_COUNTS},
                        "recall": _share(c["found"], c["truths"]),
                        "precision": _share(c["correct"], c["detections"]),
                        "class_recall": _share(c["found_class"], c["truths"]),
                        "class_precision": _share(c["correct_class"], c["detections"])}
    return table


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
        for group in scene_groups(run):
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
        "detection": detection_scores(runs, min_visibility, min_box_px),
        "wrong_detections": wrong_detection_breakdown(runs, min_visibility, min_box_px),
        "wrong_tracks": wrong_detection_breakdown(runs, min_visibility, min_box_px, tracks=True),
        "objects": [asdict(o) for o in objects],
    }
