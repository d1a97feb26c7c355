"""The train/test split by layout seed, and the command line's handling of bad input."""

from __future__ import annotations

import pytest

from pipeline.cli import main as cli_main
from synth.sequence import SequenceOptions, layout_split, sequence_layout
from synth.writer import select_indices


def test_train_and_test_never_share_a_layout_seed():
    options = SequenceOptions(test_fraction=0.3)
    train = select_indices(0, 40, options, "train")
    test = select_indices(0, 15, options, "test")
    train_layouts = {sequence_layout(0, i, options)[1] for i in train}
    test_layouts = {sequence_layout(0, i, options)[1] for i in test}
    assert train_layouts and test_layouts and not train_layouts & test_layouts
    assert all(layout_split(s, 0.3) == "test" for s in test_layouts)


def test_split_share_follows_test_fraction():
    seeds = range(4000)
    share = sum(layout_split(s, 0.2) == "test" for s in seeds) / len(seeds)
    assert 0.17 < share < 0.23


def test_every_family_appears():
    options = SequenceOptions()
    families = {sequence_layout(0, i, options)[0] for i in range(0, 25, 5)}
    assert len(families) == 5


@pytest.mark.parametrize("argv, message", [
    (["--size", "320by240"], "expected WxH"),
    (["--size", "8x8"], "32..4096"),
    (["--frames", "0"], "--frames"),
    (["--workers", "0"], "--workers"),
    (["--scenario", "occlusion", "--frames", "10"], "at least 6 s"),
])
def test_bad_input_exits_2_with_a_message(tmp_path, capsys, argv, message):
    code = cli_main(["synth", "--out", str(tmp_path / "out"), "--no-progress", *argv])
    assert code == 2
    err = capsys.readouterr().err
    assert err.startswith("heightpipe: error:") and message in err
    assert not (tmp_path / "out").exists()
