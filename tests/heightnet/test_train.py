import csv
import dataclasses

import pytest

from heightnet.checkpoint import load_checkpoint
from heightnet.train import train
from core.config import TrainConfig
from core.errors import ConfigError


def small_config(tmp_path, **changes):
    return dataclasses.replace(TrainConfig(out=str(tmp_path / "run"), input_width=64, input_height=48,
                                           steps=5, batch_size=2, checkpoint_every=2, threads=1),
                               **changes)


def test_smoke_training_writes_checkpoint_log_and_plot_and_resumes(tmp_path, cached_sequences):
    config = small_config(tmp_path)
    first = train(config, cached_sequences, data_hash="h", progress=False, max_steps=3)
    run = tmp_path / "run"
    assert first.steps == 3 and load_checkpoint(run / "checkpoint.pt")["step"] == 3
    assert (run / "loss.png").stat().st_size > 0
    with pytest.raises(ConfigError, match="--resume"):
        train(config, cached_sequences, progress=False)
    second = train(config, cached_sequences, data_hash="h", resume=True, progress=False)
    assert second.steps == 5
    state = load_checkpoint(run / "checkpoint.pt")
    assert state["step"] == 5 and state["data_hash"] == "h" and state["architecture"] == "light"
    rows = list(csv.DictReader((run / "log.csv").open()))
    assert [int(r["step"]) for r in rows] == [3, 5]
    assert all(float(r["total"]) > 0 for r in rows)


def test_resume_refuses_a_different_architecture(tmp_path, cached_sequences):
    train(small_config(tmp_path), cached_sequences, progress=False, max_steps=1)
    with pytest.raises(ConfigError, match="input_width"):
        train(small_config(tmp_path, input_width=80), cached_sequences, resume=True, progress=False)


def test_bad_input_size_is_a_config_error(tmp_path, cached_sequences):
    with pytest.raises(ConfigError, match="multiples of 16"):
        train(small_config(tmp_path, input_width=70), cached_sequences, progress=False)


def test_thirty_steps_reduce_the_logged_loss(tmp_path, cached_sequences):
    config = small_config(tmp_path, steps=30, lr=3e-3, checkpoint_every=1000)
    train(config, cached_sequences, progress=False)
    rows = list(csv.DictReader((tmp_path / "run" / "log.csv").open()))
    assert float(rows[-1]["total"]) < float(rows[0]["total"])
