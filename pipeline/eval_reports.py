"""What ``heightpipe eval-tracks`` prints and draws: the report table, the misses and wrong-detection
(and wrong track box) tables, the height picture."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np

from pipeline.eval_metrics import MISS_KINDS, WRONG_KINDS, ObjectHeight, iou_matrix, object_heights
from pipeline.eval_sequences import SequenceRun


def format_misses(breakdown: dict[str, dict]) -> str:
    """``eval_metrics.miss_breakdown``: what became of each group's required boxes."""
    return _shares_table("required boxes by what became of them (share of the group's boxes)",
                         MISS_KINDS, breakdown, width=20, count="boxes")


def format_wrong_detections(breakdown: dict[str, dict]) -> str:
    """``eval_metrics.wrong_detection_breakdown``: what lies under each group's wrong detections."""
    return _shares_table("wrong detections by what lies under them (share of the group's wrong detections)",
                         WRONG_KINDS, breakdown, width=28, count="wrong")


def format_wrong_tracks(breakdown: dict[str, dict]) -> str:
    """``eval_metrics.wrong_detection_breakdown(..., tracks=True)``: what lies under the track boxes
    the MOT metrics count as false positives."""
    return _shares_table("wrong track boxes (MOT false positives) by what lies under them (share of the group's)",
                         WRONG_KINDS, breakdown, width=28, count="wrong")


def _shares_table(title: str, kinds: tuple[str, ...], breakdown: dict[str, dict], width: int, count: str) -> str:
    """One row per group ("all" first): the share of each kind, then the group's count."""
    lines = [f"  {title}:", f"    {'group':<20}" + "".join(f"{kind:>{width}}" for kind in kinds) + f"   {count}"]
    for group in sorted(breakdown, key=lambda g: (g != "all", g)):
        row = breakdown[group]
        total = max(sum(row.values()), 1)
        lines.append(f"    {group:<20}" + "".join(f"{row[kind] / total:{width}.2f}" for kind in kinds)
                     + f"   {sum(row.values()):5d}")
    return "\n".join(lines)


def format_localisation(rows: dict[str, dict], reported: dict) -> str:
    """``eval_localisation.localisation_headroom`` under the reported scores: what each part of
    the boxes, put right, would add."""
    keys = ("HOTA", "DetA", "AssA", "IDF1")
    lines = ["  scores with the boxes put right (each box about a required object given that part of the "
             "object's true box):",
             (f"    {'':<26}" + "".join(f"{key:<16}" for key in keys)).rstrip(),
             (f"    {'boxes as reported':<26}" + "".join(f"{reported[key]:<16.3f}" for key in keys)).rstrip()]
    for name, row in rows.items():
        lines.append(f"    {name + ' right':<26}" + "".join(
            f"{f'{row[key]:.3f} ({row[key] - reported[key]:+.3f})':<16}" for key in keys).rstrip())
    return "\n".join(lines)


def format_detections(table: dict[str, dict]) -> str:
    """The detection scores (``eval_metrics.detection_scores``): recall and precision before
    tracking, of any class and with the class right (class-), per group."""
    widths = {"recall": 8, "precision": 11, "class_recall": 14, "class_precision": 17}

    def share(value: float | None, width: int) -> str:
        return f"{'-' if value is None else f'{value:.3f}':>{width}}"

    lines = [f"  {'detection before tracking (IoU 0.5)':<40}"
             + "".join(f"{key.replace('_', '-'):>{width}}" for key, width in widths.items())
             + f"{'boxes':>8}{'detections':>12}"]
    for group, row in table.items():
        lines.append(f"    {group:<38}" + "".join(share(row[key], width) for key, width in widths.items())
                     + f"{row['truths']:8d}{row['detections']:12d}")
    return "\n".join(lines)


def _cm(value: float | None) -> str:
    return "   -  " if value is None else f"{100 * value:6.1f}"


def format_report(report: dict) -> str:
    mot = report["mot"]
    lines = [
        f"eval-tracks: {len(report['sequences'])} sequences, {report['frames']} frames, "
        f"heights from {report.get('heights', '?')}"
        f"{' + geometry' if report.get('geometry') else ''}"
        f"{', camera height only' if report.get('camera') == 'height' else ''}; don't-care: visibility < "
        f"{report['min_visibility']}, boxes < {report['min_box_px']:g} px, unclaimed boxes on parked vehicles",
        f"  HOTA {mot['HOTA']:.3f}  (DetA {mot['DetA']:.3f}, AssA {mot['AssA']:.3f})  "
        f"MOTA {mot['MOTA']:.3f}  IDF1 {mot['IDF1']:.3f}  ID switches {mot['IDSW']}  "
        f"FP {mot['false_positives']}  misses {mot['misses']} / {mot['gt_dets']}  [{mot['engine']}]",
    ]
    lines.append("  at IoU threshold " + "   ".join(
        f"{alpha}: DetA {v['DetA']:.2f} AssA {v['AssA']:.2f}" for alpha, v in mot["by_iou"].items()))

    def row(label: str, summary: dict) -> str:
        return (f"    {label:<38} {_cm(summary['tracked_median_error_m'])}   "
                f"{_cm(summary['single_frame_median_error_m'])}      {summary['objects']:4d}")

    by_group = report.get("mot_by_group", {})
    if len(report["sequences"]) > 1:
        lines.append("  tracking by group                           HOTA    IDF1  sequences")
        lines += [f"    {group:<38} {mot['HOTA']:.3f}   {mot['IDF1']:.3f}     {mot['sequences']:4d}"
                  for group, mot in by_group.items()]
    if report.get("detection"):
        lines.append(format_detections(report["detection"]))
    lines.append("  height error (cm), median over objects      tracked  single-frame  objects")
    lines.append(row("all", report["height_all"]))
    for cls, summary in report["height_by_class"].items():
        lines.append(row(f"class {cls}", summary))
    for height, summary in report["height_by_camera_height"].items():
        lines.append(row(f"camera at {height} m", summary))
    for weather, summary in report["height_by_weather"].items():
        lines.append(row(f"weather {weather}", summary))
    cover = report["height_all"]
    if cover.get("uncertainty_objects"):
        lines.append(f"  height uncertainty: the truth within the track's ±1 std for "
                     f"{100 * cover['within_1_std']:.0f} % of objects, ±2 std {100 * cover['within_2_std']:.0f} % "
                     f"(68 / 95 % if honest; {cover['uncertainty_objects']} objects)")
    events = report["occlusions"]
    if events:
        kept = sum(e["kept_id"] for e in events)
        changes = [abs(e["height_after_m"] - e["height_before_m"]) for e in events
                   if e["kept_id"] and e["height_before_m"] is not None and e["height_after_m"] is not None
                   and np.isfinite(e["height_before_m"]) and np.isfinite(e["height_after_m"])]
        lines.append(f"  occlusions (hidden >= 5 frames): {len(events)}, id kept in {kept}; "
                     f"median height change {_cm(float(np.median(changes)) if changes else None).strip()} cm")
    return "\n".join(lines)


def json_default(value):
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
        updated = frame.seen_tracks
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
