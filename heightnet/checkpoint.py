"""Checkpoint files: everything needed to resume training or rebuild the network for export."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from heightnet.model import HeightNet, build_model
from core.errors import ModelError


def save_checkpoint(path: Path, state: dict[str, Any]) -> None:
    """Write atomically: a kill during the write leaves the previous checkpoint intact."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    torch.save(state, tmp)
    tmp.replace(path)


def load_checkpoint(path: Path) -> dict[str, Any]:
    path = Path(path)
    if not path.is_file():
        raise ModelError(f"checkpoint not found: {path}")
    try:
        return torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # torch raises many types for a damaged file
        raise ModelError(f"cannot read checkpoint {path}: {exc}") from None


def model_from_checkpoint(checkpoint: dict[str, Any]) -> HeightNet:
    net = build_model(checkpoint["architecture"], checkpoint["target"], checkpoint.get("backbone", ""))
    net.load_state_dict(checkpoint["model"])
    return net
