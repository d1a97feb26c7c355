"""The contract between the pipeline and its parts: what a stage and a sink must offer.

A stage takes the frame's packet, fills in what it measures and hands the packet on; a sink
writes the finished packet somewhere. Both are plain classes that match these protocols by
shape (no base class to inherit): ``pipeline.stage_chain`` runs any list of them in order.

Why protocols and not a base class: a stage is tested on its own with a hand-made packet, and
it should not need anything from the pipeline to be one.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from core.packets import FramePacket


@runtime_checkable
class Stage(Protocol):
    """One step of the per-frame work: ``process`` fills in part of the packet and returns it."""

    def process(self, packet: FramePacket) -> FramePacket:
        """Read what earlier stages wrote into ``packet``, add this stage's result, return it."""
        ...

    def close(self) -> None:
        """Release what the stage holds (files, sessions); a no-op for most stages."""
        ...


@runtime_checkable
class PrimedStage(Stage, Protocol):
    """A stage that is shown frames read ahead before the first ``process`` call.

    ``prime`` receives the look-ahead images in the geometry the stage will see them (after
    every earlier stage's ``prime``) and returns them as the next stage should see them: the
    undistortion stage undistorts them, the object extractor seeds its background model with
    them and passes them on unchanged.
    """

    def prime(self, images: list[np.ndarray]) -> list[np.ndarray]:
        ...


@runtime_checkable
class Sink(Protocol):
    """Where finished packets go (rerun, MCAP, CSV): written once per frame, closed at the end.

    ``close`` must leave a readable file however the run ended (end of video, Ctrl-C, error).
    """

    def write(self, packet: FramePacket) -> None:
        ...

    def close(self) -> None:
        ...
