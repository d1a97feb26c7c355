"""eval-tracks --against: two reports' heights compared over the objects both count."""

from __future__ import annotations

import json

import pytest

from core.errors import HeightpipeError
from pipeline.eval_compare import compare_reports, format_comparison


def _object(sequence: str, object_id: int, cls: str, true_m: float, tracked_m: float | None,
            frames: int = 20) -> dict:
    return {"sequence": sequence, "object_id": object_id, "cls": cls, "true_height_m": true_m,
            "tracked_height_m": tracked_m, "matched_frames": frames}


def _report(objects: list[dict], hota: float = 0.4, recall: float = 0.5) -> dict:
    return {"sequences": ["seq1", "seq2"], "min_visibility": 0.3, "min_box_px": 20.0, "min_frames": 10,
            "mot": {"HOTA": hota, "IDF1": 0.5, "IDSW": 3, "false_positives": 10},
            "detection": {"all": {"recall": recall, "precision": 0.6}},
            "objects": objects}


def test_heights_are_compared_over_the_objects_both_runs_count():
    base = _report([
        _object("seq1", 1, "person", 1.70, 1.60),            # 10 cm
        _object("seq1", 2, "person", 1.80, 1.74),            # 6 cm
        _object("seq2", 1, "vehicle", 1.50, 1.70),           # 20 cm
        _object("seq2", 2, "person", 1.60, 1.20, frames=5),  # too few frames: not counted
    ])
    ours = _report([
        _object("seq1", 1, "person", 1.70, 1.65),            # 5 cm: better
        _object("seq1", 2, "person", 1.80, 1.74),            # 6 cm: the same
        _object("seq2", 1, "vehicle", 1.50, 1.80),           # 30 cm: worse
        _object("seq2", 2, "person", 1.60, 1.56),            # counted here only (4 cm)
        _object("seq2", 3, "person", 1.60, None),            # never tracked
    ], hota=0.45)
    comparison = compare_reports(ours, base)
    rows = comparison["heights"]
    assert rows["all"]["objects"] == 3
    assert rows["all"]["median_error_m"] == pytest.approx(0.06)
    assert rows["all"]["base_median_error_m"] == pytest.approx(0.10)
    assert (rows["all"]["better"], rows["all"]["worse"]) == (1, 1)
    assert rows["class person"]["objects"] == 2
    assert rows["class person"]["median_error_m"] == pytest.approx(0.055)
    assert rows["class person"]["base_median_error_m"] == pytest.approx(0.08)
    assert rows["class vehicle"]["median_error_m"] == pytest.approx(0.30)
    assert comparison["only_this_run"]["objects"] == 1
    assert comparison["only_this_run"]["median_error_m"] == pytest.approx(0.04)
    assert comparison["only_base"] == {"objects": 0, "median_error_m": None}
    assert comparison["mot"]["HOTA"] == (0.45, 0.4)

    text = format_comparison(comparison, "base.json")
    assert "against base.json" in text
    assert "HOTA 0.450 / 0.400" in text
    assert "this run 1 (median 4.0 cm), base 0" in text


@pytest.mark.parametrize("key, value", [
    ("sequences", ["seq1"]),
    ("min_frames", 5),
    ("min_visibility", 0.5),
])
def test_reports_made_on_other_data_or_settings_are_not_compared(key, value):
    base = _report([])
    ours = dict(_report([]), **{key: value})
    with pytest.raises(HeightpipeError, match=key):
        compare_reports(ours, base)


@pytest.mark.parametrize("content, message", [
    (None, "cannot read"),
    ("{not json", "is not JSON"),
    (json.dumps({"mot": {}}), "not an eval-tracks --json report"),
])
def test_a_bad_base_report_is_one_clear_line_before_any_sequence_runs(tmp_path, capsys, content, message):
    from pipeline.cli import main

    base = tmp_path / "base.json"
    if content is not None:
        base.write_text(content)
    code = main(["eval-tracks", str(tmp_path / "no_such_data"), "--against", str(base)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0
    assert len(err) == 1 and err[0].startswith("heightpipe: error: --against") and message in err[0]
