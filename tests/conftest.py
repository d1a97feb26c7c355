"""Fixtures shared by all tests; the helpers behind them live in tests/media.py."""

from __future__ import annotations

from pathlib import Path

import pytest

from media import make_tiny_height_model, write_moving_box_video


@pytest.fixture
def tiny_model(tmp_path) -> Path:
    return make_tiny_height_model(tmp_path / "tiny.onnx")


@pytest.fixture
def box_video(tmp_path) -> Path:
    return write_moving_box_video(tmp_path / "box.mp4")
