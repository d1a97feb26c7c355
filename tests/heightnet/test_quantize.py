"""INT8 quantisation of an exported height model (tiny, untrained networks; fake synth frames)."""

from __future__ import annotations

import numpy as np
import pytest

from fake_synth import fake_sequences
from heightnet.quantize import SynthCalibration, main, quantize
from media import export_contact_net
from stages.heightnet_model import PREVIOUS_INPUT, HeightNetModel


@pytest.fixture
def train_frames(monkeypatch):
    """Two fake train sequences of four frames stand in for a synth dataset's train split."""
    sequences = fake_sequences(count=2, frames=4)
    monkeypatch.setattr("synth.dataset.list_sequences", lambda data, split: sequences)
    return sequences


@pytest.fixture(scope="module")
def motion_v2(tmp_path_factory):
    """A v2 network whose detection head reads motion: two inputs, the frame and the one before."""
    import torch

    from heightnet.contact_model import ContactArchitecture, ContactNet

    torch.manual_seed(0)
    net = ContactNet(ContactArchitecture(widths=(8, 8, 16, 16), detection=True, detection_motion=True)).eval()
    return export_contact_net(tmp_path_factory.mktemp("v2"), net, 64, 64)


def test_a_motion_reading_v2_is_calibrated_with_each_frame_and_the_one_before(train_frames, motion_v2):
    model = HeightNetModel(motion_v2, threads=1)
    reader = SynthCalibration("unused", model, frames=4)
    feeds = [reader.get_next() for _ in range(4)]
    assert reader.get_next() is None
    prepared = [[model.preprocess(seq.frame(i).rgb[..., ::-1].copy()) for i in range(len(seq))] for seq in train_frames]
    # two frames a sequence, after its first (the one frame of a run with no change before it)
    for feed, (seq, index) in zip(feeds, [(0, 1), (0, 2), (1, 1), (1, 2)]):
        assert set(feed) == {model.input_name, PREVIOUS_INPUT}
        np.testing.assert_array_equal(feed[model.input_name], prepared[seq][index])
        np.testing.assert_array_equal(feed[PREVIOUS_INPUT], prepared[seq][index - 1])


def test_a_lone_frame_is_its_own_frame_before(motion_v2, monkeypatch):
    monkeypatch.setattr("synth.dataset.list_sequences", lambda data, split: fake_sequences(count=1, frames=1))
    model = HeightNetModel(motion_v2, threads=1)
    feed = SynthCalibration("unused", model, frames=4).get_next()
    np.testing.assert_array_equal(feed[PREVIOUS_INPUT], feed[model.input_name])


def test_a_one_input_model_is_fed_its_image_alone(train_frames, exported_model):
    _, report = exported_model
    model = HeightNetModel(report.path, threads=1)
    reader = SynthCalibration("unused", model, frames=3)
    feeds = [reader.get_next() for _ in range(3)]
    assert all(set(feed) == {model.input_name} for feed in feeds) and reader.get_next() is None


def test_a_quantised_v2_keeps_both_inputs_its_metadata_and_runs(train_frames, motion_v2, tmp_path):
    import onnx

    out = tmp_path / "int8.onnx"
    assert quantize(motion_v2, "unused", out, frames=4) == 4
    ops = {node.op_type for node in onnx.load(str(out)).graph.node}
    assert "QuantizeLinear" in ops and "DequantizeLinear" in ops
    fp32, int8 = HeightNetModel(motion_v2, threads=1), HeightNetModel(out, threads=1)
    assert int8.takes_previous and int8.info == fp32.info
    image = train_frames[0].frame(1).rgb[..., ::-1].copy()
    a, b = fp32.run(image), int8.run(image)
    assert b.offsets.shape == a.offsets.shape and np.isfinite(b.offsets).all()


def test_a_missing_model_is_one_line(tmp_path, monkeypatch):
    monkeypatch.setattr("sys.argv", ["quantize", "data", "--model", str(tmp_path / "none.onnx"),
                                     "--out", str(tmp_path / "out.onnx")])
    with pytest.raises(SystemExit) as stop:
        main()
    assert str(stop.value).startswith("heightpipe: error: ") and "none.onnx" in str(stop.value)
    assert "\n" not in str(stop.value)
