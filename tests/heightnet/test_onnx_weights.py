"""Weights read back from an exported model: the same network, trainable with BatchNorm frozen."""

import dataclasses

import numpy as np
import pytest
import torch

from heightnet.checkpoint import load_checkpoint, model_from_checkpoint
from heightnet.export import export_checkpoint, export_model
from heightnet.model import ExportedHeightNet, build_model
from heightnet.onnx_weights import load_onnx_weights, load_onnx_weights_shared, module_path
from heightnet.train import train
from core.config import TrainConfig
from core.errors import ModelError


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """A light model whose BatchNorms are not identities (so folding them changes the weights)."""
    torch.manual_seed(1)
    net = build_model("light", "relative")
    with torch.no_grad():
        for module in net.modules():
            if isinstance(module, torch.nn.BatchNorm2d):
                module.running_mean.uniform_(-0.5, 0.5)
                module.running_var.uniform_(0.5, 2.0)
                module.weight.uniform_(0.5, 1.5)
                module.bias.uniform_(-0.2, 0.2)
            elif isinstance(module, torch.nn.GroupNorm):
                module.weight.uniform_(0.5, 1.5)
                module.bias.uniform_(-0.2, 0.2)
    net.eval()
    path = tmp_path_factory.mktemp("onnx") / "model.onnx"
    export_model(net, path, 96, 64, trained_steps=300)
    return net, path


def test_module_path_drops_the_repeated_scope_prefixes():
    assert module_path("/net/encoder/to_16/to_16.0/to_16.0.0/body/body.0/Conv") == "encoder.to_16.0.0.body.0"
    assert module_path("/net/aspp/reduce/reduce.0/Mul") == "aspp.reduce.0"


def test_weights_from_onnx_reproduce_the_exported_network(exported):
    original, path = exported
    rebuilt = build_model("light", "relative")
    load_onnx_weights(rebuilt, path)
    image = torch.rand(1, 3, 64, 96, generator=torch.Generator().manual_seed(2))
    with torch.no_grad():
        want = ExportedHeightNet(original).eval()(image)
        got = ExportedHeightNet(rebuilt).eval()(image)
    for a, b in zip(want, got):
        assert float((a - b).abs().max()) < 1e-4
    # Not a copy of the state dict: the encoder's BatchNorms were folded into its convolutions.
    assert not torch.allclose(rebuilt.state_dict()["encoder.stem.0.weight"],
                              original.state_dict()["encoder.stem.0.weight"])


def test_a_cut_down_network_starts_from_what_it_shares_with_the_exported_one(exported):
    _, path = exported
    full = build_model("light", "relative")
    load_onnx_weights(full, path)
    half = build_model("light_half", "relative")
    fresh = load_onnx_weights_shared(half, path)
    assert fresh == ["heads.2.2.weight[1:]", "heads.2.2.bias[1:]"]
    theirs, ours = full.state_dict(), half.state_dict()
    for key, value in ours.items():
        if key.startswith("heads.2.2."):
            assert torch.equal(value[:1], theirs[key]), "the height residual channel is copied"
        else:
            assert torch.equal(value, theirs[key]), key
    # Its height before any fine-tuning: the same network less the last residual, so close.
    image = torch.rand(1, 3, 64, 96, generator=torch.Generator().manual_seed(3))
    with torch.no_grad():
        want = ExportedHeightNet(full).eval()(image)[0]
        got = ExportedHeightNet(half).eval()(image)[0]
    assert got.shape == want.shape
    assert float((got - want).abs().mean()) < 0.25 * float(want.abs().mean()) + 1e-3


def test_a_missing_damaged_or_foreign_file_is_a_model_error(tmp_path, exported):
    net = build_model("light", "relative")
    with pytest.raises(ModelError, match="not found"):
        load_onnx_weights(net, tmp_path / "none.onnx")
    (tmp_path / "bad.onnx").write_bytes(b"not a model")
    with pytest.raises(ModelError, match="cannot read"):
        load_onnx_weights(net, tmp_path / "bad.onnx")
    with pytest.raises(ModelError, match="does not fit"):
        load_onnx_weights(build_model("light", "relative", "resnext50_32x4d"), exported[1])


def test_training_from_onnx_starts_at_its_weights_and_keeps_batchnorm_frozen(tmp_path, exported,
                                                                              cached_sequences):
    _, path = exported
    config = TrainConfig(out=str(tmp_path / "run"), input_width=64, input_height=48, steps=2,
                         batch_size=2, checkpoint_every=1000, threads=1, init_onnx=str(path))
    start = build_model("light", "relative")
    load_onnx_weights(start, path)
    train(config, cached_sequences, progress=False)
    state = load_checkpoint(tmp_path / "run" / "checkpoint.pt")
    trained = model_from_checkpoint(state).state_dict()
    before = start.state_dict()
    for key in ("encoder.stem.1.running_mean", "encoder.stem.1.running_var"):
        assert torch.equal(trained[key], before[key])            # frozen: no batch statistics
    assert not torch.equal(trained["encoder.stem.0.weight"], before["encoder.stem.0.weight"])
    # Two small steps from the exported weights, not from a fresh initialisation.
    drift = float((trained["aspp.reduce.0.weight"] - before["aspp.reduce.0.weight"]).abs().max())
    assert drift < 0.05 and np.isfinite(drift)
    # A resumed run keeps them frozen, without being told again and without the ONNX file.
    train(dataclasses.replace(config, steps=3, init_onnx=""), cached_sequences, resume=True, progress=False)
    state = load_checkpoint(tmp_path / "run" / "checkpoint.pt")
    assert torch.equal(model_from_checkpoint(state).state_dict()["encoder.stem.1.running_mean"],
                       before["encoder.stem.1.running_mean"])
    # Exported, it counts the steps behind the weights it started from.
    report = export_checkpoint(tmp_path / "run" / "checkpoint.pt", tmp_path / "tuned.onnx")
    assert state["init_steps"] == 300 and report.metadata["heightpipe.trained_steps"] == "303"
