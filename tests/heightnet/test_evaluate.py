import csv

from fake_synth import fake_sequences
from heightnet.evaluate import run_evaluation


def test_eval_writes_table_rows_per_camera_height_with_ablation_side_by_side(exported_model, tmp_path):
    _, report = exported_model
    sequences = fake_sequences(count=2, frames=2, camera_heights=(3.5, 9.2))
    table = run_evaluation(sequences, [("main", report.path), ("ablation", report.path)],
                           tmp_path, threads=1)
    assert "| main | 350 |" in table and "| main | 920 |" in table and "| ablation | 920 |" in table
    assert "Mover pixels" in table and "All above-ground pixels" in table
    rows = list(csv.DictReader((tmp_path / "table.csv").open()))
    assert [r["camera_height_cm"] for r in rows] == ["350", "920", "all"] * 2
    for row in rows:
        assert 0 <= float(row["mover_delta1"]) <= float(row["mover_delta3"]) <= 1
        assert float(row["mover_rmse_cm"]) >= float(row["mover_mae_cm"])
    assert (tmp_path / "figure4.png").stat().st_size > 0
    assert (tmp_path / "table.md").read_text() == table
