"""Render a planned sequence frame by frame: RGB, labels, depth and per-object truth."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator

import numpy as np

from synth.dataset import ObjectTruth
from synth.render import SceneRenderer, amodal_groups, build_scene
from synth.sequence import SequencePlan
from synth.weather import apply_post_effects


@dataclass
class RenderedFrame:
    index: int
    time_s: float
    rgb: np.ndarray  # after post effects
    rgb_clean: np.ndarray  # straight from the renderer
    depth_m: np.ndarray
    instance: np.ndarray
    semantic: np.ndarray
    objects: list[ObjectTruth]


@dataclass
class Background:
    depth_m: np.ndarray
    semantic: np.ndarray


class SequenceRenderer:
    """Context manager: compile the plan's scene, then render frames on demand."""

    def __init__(self, plan: SequencePlan):
        self.plan = plan
        cam = plan.camera
        self.scene = build_scene(plan.layout, plan.movers, cam, plan.env, msaa=plan.options.msaa,
                                 focus=plan.focus)
        self.renderer = SceneRenderer(self.scene, cam.width, cam.height, fog=plan.env.fog_end_m > 0)
        self._post_rng = np.random.default_rng([plan.seed, 99])
        self._class_of = {m.id: m.cls for m in plan.movers}
        self._movers = {m.id: m for m in plan.movers}

    def close(self) -> None:
        self.renderer.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def background(self) -> Background:
        labels = self.renderer.render_background()
        semantic = np.where(labels.geom >= 0, self.scene.geom_class[np.maximum(labels.geom, 0)], 0).astype(np.uint8)
        return Background(depth_m=labels.depth_m, semantic=semantic)

    def frame(self, index: int) -> RenderedFrame:
        plan, cam, r = self.plan, self.plan.camera, self.renderer
        t = index / plan.options.fps
        tops = r.set_movers(plan.movers, t)
        rgb_clean = r.render_rgb()
        labels = r.render_labels()
        hit = labels.geom >= 0
        gid = np.maximum(labels.geom, 0)
        instance = np.where(hit, self.scene.geom_instance[gid], 0).astype(np.uint16)
        semantic = np.where(hit, self.scene.geom_class[gid], 0).astype(np.uint8)
        boxes = r.projected_boxes(cam, list(tops))
        masks = r.render_amodal(amodal_groups(boxes, cam.width, cam.height))
        visible_counts = np.bincount(instance.ravel(), minlength=max(self._movers, default=0) + 1)
        objects = []
        for mid, mask in masks.items():
            full = int(mask.sum())
            if full == 0:
                continue
            ys, xs = np.nonzero(mask)
            x0, x1, y0, y1 = int(xs.min()), int(xs.max()), int(ys.min()), int(ys.max())
            xy, _ = self._movers[mid].ground_pose(t)
            objects.append(ObjectTruth(
                id=mid, cls=self._class_of[mid], box=(float(x0), float(y0), float(x1 - x0 + 1), float(y1 - y0 + 1)),
                visible_fraction=min(1.0, int(visible_counts[mid]) / full), height_m=float(tops[mid]),
                ground_xy_m=(float(xy[0]), float(xy[1]))))
        objects.sort(key=lambda o: o.id)
        rgb = apply_post_effects(rgb_clean, plan.env, self._post_rng) if plan.options.post_effects else rgb_clean
        return RenderedFrame(index=index, time_s=t, rgb=rgb, rgb_clean=rgb_clean, depth_m=labels.depth_m,
                             instance=instance, semantic=semantic, objects=objects)

    def frames(self) -> Iterator[RenderedFrame]:
        for i in range(self.plan.options.frames):
            yield self.frame(i)
