"""Running the stage chain over a generator sequence (the part of eval-tracks that is the pipeline)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from core.config import Config
from pipeline.eval_sequences import OracleHeights, build_eval_chain


def test_true_heights_learn_no_network_scale():
    """True height maps are metric and exact: the geometry stage must not rescale them, nor doubt
    their scale, and the height filter gives them no per-object bias (the model's keep theirs)."""
    camera = SimpleNamespace(width=320, height=240, K=np.diag([300.0, 300.0, 1.0]), R=np.eye(3),
                             t=np.array([0.0, 0.0, 5.0]), height_m=5.0)
    sequence = SimpleNamespace(meta=SimpleNamespace(camera=camera))
    chain = build_eval_chain(sequence, Config(), "oracle", geometry=True)
    assert [name for name, _ in chain.stages] == ["heights", "matching", "objects", "geometry", "tracking"]
    assert isinstance(chain.stage("heights"), OracleHeights)
    assert chain.stage("geometry").network_scale is None
    assert chain.stage("tracking").tracker.config.network_bias_share == 0.0
    assert Config().tracking.network_bias_share > 0.0
