"""Movers: gait makes the apparent height oscillate; the occlusion scenario hides a pedestrian."""

from __future__ import annotations

import numpy as np

from synth.camera import make_camera
from synth.generate import SequenceRenderer
from synth.movers import make_cyclist, make_pedestrian, make_vehicle
from synth.render import SceneRenderer, build_scene
from synth.scene import build_layout
from synth.sequence import plan_sequence
from synth.weather import sample_environment
from tests.synth.conftest import small_options


def _tops(movers, times):
    layout = build_layout("plaza", 1)
    camera = make_camera(np.array([0.0, -20.0, 6.0]), 90.0, 20.0, 0.0, 60.0, 64, 48)
    env = sample_environment(np.random.default_rng(0), "day", "clear")
    with SceneRenderer(build_scene(layout, movers, camera, env), 64, 48, fog=False) as renderer:
        return np.array([[renderer.set_movers(movers, t)[m.id] for m in movers] for t in times])


def test_walking_pedestrian_bobs_and_standing_one_does_not():
    rng = np.random.default_rng(0)
    route = np.array([[-30.0, 0.0], [30.0, 0.0]])
    walker = make_pedestrian(1, rng, 1.78, route, 0.0, 1.4, 10.0)
    child = make_pedestrian(2, rng, 1.12, route, 1.0, 1.1, 10.0)
    stander = make_pedestrian(3, rng, 1.65, route, -1.0, 0.0, 20.0)
    tops = _tops([walker, child, stander], np.arange(0.0, 3.0, 0.05))
    for column, stature in ((0, 1.78), (1, 1.12)):
        assert tops[:, column].max() <= stature + 1e-6
        assert tops[:, column].max() > stature - 0.005  # upright at mid-stance
        assert 0.015 < np.ptp(tops[:, column]) < 0.07  # a few cm of vertical bob
    assert np.ptp(tops[:, 2]) < 1e-9 and abs(tops[0, 2] - 1.65) < 1e-6


def test_vehicle_and_cyclist_heights_in_range():
    rng = np.random.default_rng(1)
    route = np.array([[-30.0, 0.0], [30.0, 0.0]])
    ranges = {"car": (1.4, 1.6), "van": (1.9, 2.4), "truck": (2.8, 4.0), "bus": (2.9, 3.6)}
    movers = [make_vehicle(i + 1, cls, rng, (0.5, 0.5, 0.5, 1), route, 0.0, 8.0, 20.0)
              for i, cls in enumerate(ranges)]
    movers.append(make_cyclist(9, rng, 1.75, route, 2.0, 5.0, 20.0))
    tops = _tops(movers, [0.0, 0.5])
    for i, (lo, hi) in enumerate(ranges.values()):
        assert lo - 1e-6 <= tops[0, i] <= hi + 1e-6
        assert tops[0, i] == tops[1, i]
    assert 1.55 < tops[0, -1] < 1.95


def test_occlusion_scenario_hides_the_pedestrian_about_two_seconds():
    options = small_options(frames=36, fps=4.0, sizes=((160, 120),), scenario="occlusion", time_of_day="",
                            weather="", camera_height_m=5.0, pedestrians=(0, 0), vehicles=(0, 0), cyclists=(0, 0))
    plan = plan_sequence(5, 0, options)
    hidden_id = plan.notes["occluded_id"]
    visibility = []
    with SequenceRenderer(plan) as renderer:
        for i in range(options.frames):
            truth = {o.id: o for o in renderer.frame(i).objects}
            visibility.append(truth[hidden_id].visible_fraction if hidden_id in truth else None)
    assert None not in visibility  # in view (boxes kept) all along, even when hidden
    hidden = [v == 0.0 for v in visibility]
    longest = max(len(run) for run in "".join("x" if h else " " for h in hidden).split(" "))
    assert 1.5 <= longest / options.fps <= 3.5
    assert visibility[0] > 0.9 and visibility[-1] > 0.9
