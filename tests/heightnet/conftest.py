"""Shared fixtures: a tiny fake synth dataset (tests/heightnet/fake_synth.py) and its cache."""

from __future__ import annotations

import pytest

from fake_synth import fake_sequences
from heightnet.data import build_cache


@pytest.fixture(scope="session")
def cached_sequences(tmp_path_factory):
    return build_cache(fake_sequences(count=2, frames=4), tmp_path_factory.mktemp("cache"))


@pytest.fixture(scope="session")
def exported_model(tmp_path_factory):
    """A light model exported at a small input size (weights untrained: shapes and plumbing)."""
    import torch

    from heightnet.export import export_model
    from heightnet.model import build_model

    torch.manual_seed(0)
    net = build_model("light", "relative").eval()
    path = tmp_path_factory.mktemp("onnx") / "heightnet.onnx"
    report = export_model(net, path, 96, 64, data_hash="abc123", trained_steps=7)
    return net, report
