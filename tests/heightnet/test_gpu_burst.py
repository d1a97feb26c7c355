"""heightnet/gpu_burst.sh end to end on the CPU: the script a lent GPU machine runs, run here
small (two rendered cameras, two steps) so that it cannot rot between the sessions that get one."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch

REPO = Path(__file__).resolve().parents[2]
STATE = REPO / "heightnet" / "state" / "v2"


def test_a_burst_renders_trains_the_whole_network_and_writes_a_state_that_resumes_anywhere(tmp_path):
    pytest.importorskip("mujoco")
    state = tmp_path / "heightnet" / "state" / "v2"
    state.mkdir(parents=True)
    for name in ("checkpoint.pt", "log.csv", "curve.csv"):
        shutil.copy(STATE / name, state)
    env = {**os.environ, "PYTHON": sys.executable, "BURST_CHUNK": "2", "BURST_SIZES": "160x120"}
    done = subprocess.run(["bash", str(REPO / "heightnet" / "gpu_burst.sh"), "out", "200", "1", "cpu",
                           "--max-steps", "2"], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "training for" in done.stdout and (tmp_path / "data" / "burst_train" / "manifest.json").is_file()
    saved = torch.load(tmp_path / "out" / "checkpoint.pt", map_location="cpu", weights_only=False)
    committed = torch.load(state / "checkpoint.pt", map_location="cpu", weights_only=False)
    assert saved["step"] == committed["step"] + 2
    assert saved["config"]["batch_size"] == 32 and saved["config"]["head_only"] is False
    trunk = next(name for name in saved["ema"] if not name.startswith("detection_head."))
    assert not torch.equal(saved["model"][trunk], committed["model"][trunk])   # the trunk learnt too
    assert all(value.device.type == "cpu" for value in saved["ema"].values())
