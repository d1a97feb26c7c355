"""``heightpipe eval-tracks DATA --against BASE.json``: a run's heights over the objects both runs count.

The height table of one report counts the objects tracked in at least ``--min-frames`` frames,
so any change that tracks more or fewer objects changes which objects are in it: one vehicle more
at 44 cm moved a median of 22 vehicles from 17 to 23 cm while every height stayed the same
(docs/results.md, 2026-12-05, fifteenth session). Comparing two runs fairly means pairing their
objects (by sequence and object id) and taking both medians over the objects both count, then
saying separately how many objects only one of them counts. Tracking and detection scores are
set side by side as they are.
"""

from __future__ import annotations

import numpy as np

from core.errors import HeightpipeError

# Two errors within this of each other are the same (a millimetre: float noise of the filter).
SAME_M = 0.001
# Report keys that must agree for two reports to be compared object by object.
MUST_AGREE = ("sequences", "min_visibility", "min_box_px", "min_frames")


def check_comparable(settings: dict, base: dict) -> None:
    """``HeightpipeError`` unless ``settings`` (a report, or its ``MUST_AGREE`` keys known before the
    sequences run) and ``base`` were made on the same sequences with the same don't-care and
    ``--min-frames`` settings: else their objects would not be the same objects."""
    for key in MUST_AGREE:
        if settings.get(key) != base.get(key):
            raise HeightpipeError(f"--against: the base report differs in {key!r} "
                                  f"({base.get(key)!r} there, {settings.get(key)!r} here): run both the same way")


def _counted(report: dict) -> dict[tuple[str, int], dict]:
    """(sequence, object id) -> object, for the objects the report's height table counts."""
    return {(o["sequence"], int(o["object_id"])): o for o in report["objects"]
            if o["tracked_height_m"] is not None and np.isfinite(o["tracked_height_m"])
            and o["matched_frames"] >= report["min_frames"]}


def _error(obj: dict) -> float:
    return abs(obj["tracked_height_m"] - obj["true_height_m"])


def _median(values: list[float]) -> float | None:
    return float(np.median(values)) if values else None


def compare_reports(report: dict, base: dict) -> dict:
    """``report`` against ``base`` (both ``eval_metrics.evaluate``'s, as ``--json`` writes them).

    Raises ``HeightpipeError`` when they were made on other sequences or with other don't-care or
    ``--min-frames`` settings (``check_comparable``).
    """
    check_comparable(report, base)
    ours, theirs = _counted(report), _counted(base)
    common = sorted(ours.keys() & theirs.keys())
    rows = {}
    for name, keep in [("all", lambda o: True)] + [
            (f"class {cls}", lambda o, cls=cls: o["cls"] == cls)
            for cls in sorted({ours[key]["cls"] for key in common})]:
        pairs = [(_error(ours[key]), _error(theirs[key])) for key in common if keep(ours[key])]
        rows[name] = {
            "objects": len(pairs),
            "median_error_m": _median([a for a, _ in pairs]),
            "base_median_error_m": _median([b for _, b in pairs]),
            "better": sum(a < b - SAME_M for a, b in pairs),
            "worse": sum(a > b + SAME_M for a, b in pairs),
        }
    only_ours = [_error(ours[key]) for key in ours.keys() - theirs.keys()]
    only_theirs = [_error(theirs[key]) for key in theirs.keys() - ours.keys()]
    return {
        "mot": {key: (report["mot"][key], base["mot"][key]) for key in ("HOTA", "IDF1", "IDSW", "false_positives")},
        "detection": {key: (report["detection"]["all"][key], base["detection"]["all"][key])
                      for key in ("recall", "precision")} if report.get("detection") and base.get("detection") else {},
        "heights": rows,
        "only_this_run": {"objects": len(only_ours), "median_error_m": _median(only_ours)},
        "only_base": {"objects": len(only_theirs), "median_error_m": _median(only_theirs)},
    }


def _cm(value: float | None) -> str:
    return "   -  " if value is None else f"{100 * value:6.1f}"


def _pair(name: str, values: tuple, fmt: str) -> str:
    """``name this / base``, each value in ``fmt`` ("-" where a report has none)."""
    return f"{name} " + " / ".join("-" if value is None else format(value, fmt) for value in values)


def format_comparison(comparison: dict, base_name: str) -> str:
    """The comparison as printed under the report (this run first, then the base)."""
    mot, detection = comparison["mot"], comparison["detection"]
    scores = [_pair("HOTA", mot["HOTA"], ".3f"), _pair("IDF1", mot["IDF1"], ".3f"),
              _pair("ID switches", mot["IDSW"], "d"), _pair("FP", mot["false_positives"], "d")]
    if detection:
        scores += [_pair("detection recall", detection["recall"], ".3f"),
                   _pair("precision", detection["precision"], ".3f")]
    lines = [f"  against {base_name} (this run / base)", "    " + "  ".join(scores),
             "  height error (cm) over the objects both count   this run    base  better  worse  objects"]
    for name, row in comparison["heights"].items():
        lines.append(f"    {name:<44} {_cm(row['median_error_m'])}  {_cm(row['base_median_error_m'])}"
                     f"  {row['better']:6d} {row['worse']:6d}   {row['objects']:6d}")
    ours, theirs = comparison["only_this_run"], comparison["only_base"]
    lines.append(f"  counted by one run only: this run {ours['objects']} "
                 f"(median {_cm(ours['median_error_m']).strip()} cm), "
                 f"base {theirs['objects']} (median {_cm(theirs['median_error_m']).strip()} cm)")
    return "\n".join(lines)
