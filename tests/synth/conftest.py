"""Small rendered sequences shared by the synth tests (rendered once per session)."""

from __future__ import annotations

import numpy as np
import pytest

from synth.sequence import SequenceOptions, plan_sequence


def small_options(**changes) -> SequenceOptions:
    base = dict(frames=3, fps=10.0, sizes=((96, 72),), time_of_day="day", weather="clear")
    base.update(changes)
    return SequenceOptions(**base)


def movers_fully_in_view(plan, t: float = 0.0, max_depth_m: float = 1e9) -> int:
    """How many movers have both their feet and their top inside the image at time t."""
    count = 0
    for m in plan.movers:
        if not m.present(t):
            continue
        xy, _ = m.ground_pose(t)
        uv, z = plan.camera.project(np.array([[xy[0], xy[1], 0.0], [xy[0], xy[1], m.nominal_height_m]]))
        cam = plan.camera
        inside = (uv >= 1).all() and (uv[:, 0] < cam.width - 1).all() and (uv[:, 1] < cam.height - 1).all()
        if (z > 0).all() and z.max() < max_depth_m and inside:
            count += 1
    return count


@pytest.fixture(scope="session")
def street_plan():
    """A day street crossing seen from 5 m, 320x240, with movers wholly in view, two of them close."""
    options = small_options(sizes=((320, 240),), layout="street_crossing", camera_height_m=5.0,
                            pedestrians=(8, 8), vehicles=(3, 3))
    for seed in range(3, 40):
        plan = plan_sequence(seed, 0, options)
        if movers_fully_in_view(plan) >= 6 and movers_fully_in_view(plan, max_depth_m=0.035 * plan.camera.K[1, 1]) >= 2:
            return plan
    raise AssertionError("no seed gives six movers in view, two of them at <= 3.5 cm per pixel")


@pytest.fixture(scope="session")
def street_frames(street_plan):
    from synth.generate import SequenceRenderer

    with SequenceRenderer(street_plan) as renderer:
        background = renderer.background()
        frames = [renderer.frame(i) for i in range(street_plan.options.frames)]
    return background, frames
