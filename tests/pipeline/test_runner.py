"""How one run reacts to a stop signal that arrives where Python cannot raise it, or late."""

import os
import signal

import pytest

from core.config import Config
from pipeline import runner
from pipeline.runner import run_pipeline


def sigterm_to_self() -> None:
    """SIGTERM to this process, its Python handler run before this returns."""
    os.kill(os.getpid(), signal.SIGTERM)
    for _ in range(1000):  # the handler runs at one of these bytecodes, still in the caller
        pass


class SignalledOnCollection:
    """Sends this process SIGTERM from its ``__del__``, where a handler's exception is swallowed."""

    def __del__(self):
        sigterm_to_self()


class OutsideHandlerRan(Exception):
    pass


@pytest.fixture
def sigterm_outside_the_run():
    """SIGTERM while the run's own handler is not in place raises here instead of ending pytest."""
    def handler(_signum, _frame):
        raise OutsideHandlerRan()

    previous = signal.signal(signal.SIGTERM, handler)
    yield
    signal.signal(signal.SIGTERM, previous)


@pytest.fixture
def config(tiny_model):
    config = Config()
    config.height.model, config.height.threads, config.output.progress = str(tiny_model), 1, False
    return config


def test_a_stop_swallowed_inside_a_del_still_stops_the_run_at_the_next_frame(
        tmp_path, box_video, config, sigterm_outside_the_run, capsys):
    def on_frame(frames, _total, _elapsed):
        if frames == 5:
            SignalledOnCollection()  # made and collected at once

    # Frames written as they are processed (no wait for boxes to smooth), so the counts are frames.
    config.tracking.smooth_s = config.tracking.fill_gaps_s = 0.0
    summary = run_pipeline(str(box_video), config, tmp_path / "run", on_frame=on_frame)
    assert summary.interrupted == "SIGTERM"
    assert summary.frames == 6
    assert "Exception ignored" not in capsys.readouterr().err
    rows = (tmp_path / "run.tracks.csv").read_text().splitlines()
    assert rows and all(int(row.split(",")[0]) < 6 for row in rows[1:])


def test_a_stop_arriving_while_the_outputs_close_waits_for_them(
        tmp_path, box_video, config, sigterm_outside_the_run, monkeypatch):
    from mcap.reader import make_reader

    close_all = runner.close_all

    def signalled_then_closed(parts):
        sigterm_to_self()
        close_all(parts)

    monkeypatch.setattr(runner, "close_all", signalled_then_closed)
    summary = run_pipeline(str(box_video), config, tmp_path / "run")
    assert summary.frames == 30 and not summary.interrupted  # every frame was processed
    with open(tmp_path / "run.mcap", "rb") as f:
        assert make_reader(f).get_summary() is not None  # written by a clean close
