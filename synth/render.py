"""MuJoCo scene assembly and off-screen rendering (EGL, or OSMesa as a fallback).

Per frame: one lit RGB pass (shadow map, optional MSAA) and one non-antialiased label pass
that gives segmentation and depth together (depth read after an MSAA pass is wrong at edges).
Per sequence: one background pass with the mover geom group switched off. For the
per-object visible fraction, "amodal" passes draw movers alone, in as few passes as keep
their projected boxes apart, so each object's full silhouette is counted once.

MuJoCo facts this relies on: depth is read back as reversed-Z floats scaled by ``stat.extent``,
cameras are placed with ``mj_camlight``, and segmentation ids index the scene's geoms.
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

import math  # noqa: E402
from dataclasses import dataclass  # noqa: E402

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from synth import meshes, textures  # noqa: E402
from synth.camera import SynthCamera, mujoco_xyaxes  # noqa: E402
from synth.movers import Mover  # noqa: E402
from synth.scene import CLASS_ID, GROUND_CLASSES, Layout  # noqa: E402
from synth.weather import Environment, sun_direction  # noqa: E402

EXTENT_M = 100.0
ZNEAR, ZFAR = 0.001, 6.0  # fractions of EXTENT_M: 0.1 m .. 600 m
MOVER_GROUP = 2
HIDDEN_POS = np.array([1.0e4, 1.0e4, -1.0e3])


def _f(values) -> str:
    return " ".join(f"{float(v):.6g}" for v in values)


@dataclass
class SceneModel:
    """A compiled scene plus the look-up tables from geom id to labels."""

    model: mujoco.MjModel
    geom_instance: np.ndarray  # (ngeom,) uint16, mover id or 0
    geom_class: np.ndarray  # (ngeom,) uint8 semantic class
    mover_ids: list[int]
    mover_mocap: dict[int, list[int]]  # mover id -> mocap index of each part
    mover_vertices: dict[int, list[np.ndarray]]  # mover id -> local vertices of each part


def _finish_material(finish: str, light: str) -> str:
    if light in ("head", "tail"):
        return f"pal_{light}"
    return {"paint": "pal_paint", "glass": "pal_glass"}.get(finish, "pal_matte")


def build_scene(layout: Layout, movers: list[Mover], camera: SynthCamera, env: Environment,
                msaa: int = 0, shadow_size: int = 2048, focus: np.ndarray | None = None) -> SceneModel:
    """Write the MJCF for one sequence and compile it (textures are PNG byte assets).

    Static primitives are merged into one mesh per (material, class); each mover part into
    one mesh per material (see synth/meshes.py for why).
    """
    palette = meshes.Palette()
    assets: dict[str, bytes] = {}
    night = env.lamps_on
    materials = [
        f'<texture name="sky" type="skybox" builtin="gradient" rgb1="{_f(env.sky_top)}" '
        f'rgb2="{_f(env.sky_horizon)}" width="256" height="256"/>',
        '<texture name="palette" type="2d" file="palette.png"/>',
        '<material name="pal_matte" texture="palette" specular="0.08" shininess="0.15"/>',
        '<material name="pal_paint" texture="palette" specular="0.35" shininess="0.5"/>',
        '<material name="pal_glass" texture="palette" specular="0.6" shininess="0.8"/>',
        f'<material name="pal_lamp" texture="palette" emission="{1.0 if night else 0.15}" specular="0"/>',
        f'<material name="pal_head" texture="palette" emission="{1.0 if night else 0.0}" specular="0.3"/>',
        f'<material name="pal_tail" texture="palette" emission="{0.8 if night else 0.0}" specular="0.3"/>',
    ]
    for name, spec in sorted(layout.materials.items()):
        tex_rng = np.random.default_rng([layout.seed, textures.TEXTURE_KINDS.index(spec.texture), spec.variant])
        assets[f"{name}.png"] = textures.png_bytes(textures.make_texture(spec.texture, tex_rng, 128))
        rep = 1.0 / spec.tile_m
        materials.append(f'<texture name="t_{name}" type="2d" file="{name}.png"/>')
        materials.append(f'<material name="{name}" texture="t_{name}" specular="0.05" shininess="0.1"/>')
        materials.append(f'<material name="{name}_plane" texture="t_{name}" texuniform="true" '
                         f'texrepeat="{rep:.6g} {rep:.6g}" specular="0.05" shininess="0.1"/>')

    mesh_xml: list[str] = []
    geom_class: list[int] = []
    geom_instance: list[int] = []
    world: list[str] = []
    focus = np.zeros(2) if focus is None else np.asarray(focus, float)
    # Sun (or moon): a directional light centred over the area the camera sees, so the
    # shadow map's +-shadowclip square covers it.
    sun_dir = sun_direction(env)
    sun_pos = np.array([focus[0], focus[1], 0.0]) - sun_dir * 80.0
    world.append(f'<light name="sun" directional="true" castshadow="{str(env.shadows).lower()}" '
                 f'pos="{_f(sun_pos)}" dir="{_f(sun_dir)}" diffuse="{_f(env.sun_rgb)}" '
                 f'specular="{_f(np.array(env.sun_rgb) * 0.2)}" ambient="0 0 0"/>')
    if night and layout.lamps:
        lamps = sorted(layout.lamps, key=lambda p: (p[0] - focus[0]) ** 2 + (p[1] - focus[1]) ** 2)[:6]
        for x, y, h in lamps:
            world.append(f'<light directional="false" castshadow="false" pos="{_f((x, y, h - 0.05))}" '
                         f'dir="0 0 -1" cutoff="70" exponent="1" attenuation="0.3 0.05 0.004" '
                         f'diffuse="{_f(env.lamp_rgb)}" specular="0.1 0.1 0.1"/>')
    # Flat ground layers receive shadows but need not cast them: in the shadow pass each would
    # fill the whole shadow map.
    world.append(f'<geom name="ground" type="plane" size="400 400 1" material="{layout.base_material}_plane" '
                 f'castshadow="false"/>')
    geom_class.append(CLASS_ID[layout.base_class])
    geom_instance.append(0)

    static: dict[tuple[str, str], meshes.MeshData] = {}
    for p in layout.prims:
        quat = p.quat if p.quat is not None else (math.cos(p.yaw / 2), 0.0, 0.0, math.sin(p.yaw / 2))
        v, n, f = meshes.tessellate(p.kind, p.size, p.pos, quat)
        if p.material:
            material = p.material
            uv = meshes.planar_uv(v, n, layout.materials[p.material].tile_m)
        else:
            material = "pal_lamp" if p.emission < 0 else "pal_matte"
            uv = np.tile(palette.uv(p.rgba), (len(v), 1))
        static.setdefault((material, p.cls), meshes.MeshData()).add(v, n, f, uv)
    for k, ((material, cls), data) in enumerate(sorted(static.items())):
        mesh_xml.append(meshes.mesh_xml(f"s{k}", data))
        cast = ' castshadow="false"' if cls in GROUND_CLASSES else ""
        world.append(f'<geom type="mesh" mesh="s{k}" material="{material}"{cast}/>')
        geom_class.append(CLASS_ID[cls])
        geom_instance.append(0)

    mover_mocap: dict[int, list[int]] = {}
    mover_vertices: dict[int, list[np.ndarray]] = {}
    mocap_index = 0
    for mover in movers:
        mover_mocap[mover.id], mover_vertices[mover.id] = [], []
        for k, part in enumerate(mover.parts):
            by_material: dict[str, meshes.MeshData] = {}
            for g in part:
                v, n, f = meshes.tessellate(g.kind, g.size, g.pos, g.quat, g.fromto)
                uv = np.tile(palette.uv(g.rgba), (len(v), 1))
                by_material.setdefault(_finish_material(g.finish, g.light), meshes.MeshData()).add(v, n, f, uv)
            body = [f'<body name="m{mover.id}_{k}" mocap="true" pos="{_f(HIDDEN_POS)}">']
            part_vertices = []
            for material, data in sorted(by_material.items()):
                name = f"m{mover.id}_{k}_{material}"
                mesh_xml.append(meshes.mesh_xml(name, data))
                part_vertices.append(data.arrays()[0])
                body.append(f'<geom type="mesh" mesh="{name}" material="{material}" group="{MOVER_GROUP}"/>')
                geom_class.append(CLASS_ID[mover.cls])
                geom_instance.append(mover.id)
            body.append("</body>")
            world.append("".join(body))
            mover_mocap[mover.id].append(mocap_index)
            mover_vertices[mover.id].append(np.concatenate(part_vertices))
            mocap_index += 1
    assets["palette.png"] = textures.png_bytes(palette.image())

    x_axis, y_axis = mujoco_xyaxes(camera)
    world.append(f'<camera name="cctv" pos="{_f(camera.position)}" xyaxes="{_f(x_axis)} {_f(y_axis)}" '
                 f'fovy="{camera.fovy_deg:.9g}"/>')
    fog_start = env.fog_start_m / EXTENT_M if env.fog_end_m > 0 else 0.0
    fog_end = env.fog_end_m / EXTENT_M if env.fog_end_m > 0 else 1.0
    xml = f"""<mujoco model="heightpipe_synth">
<compiler angle="radian" inertiafromgeom="false"/>
<statistic extent="{EXTENT_M}" center="0 0 0"/>
<visual>
  <global offwidth="{camera.width}" offheight="{camera.height}"/>
  <quality shadowsize="{shadow_size}" offsamples="{msaa}"/>
  <map znear="{ZNEAR}" zfar="{ZFAR}" fogstart="{fog_start:.6g}" fogend="{fog_end:.6g}" shadowclip="0.5" haze="0.15"/>
  <headlight active="1" ambient="{_f(env.ambient_rgb)}" diffuse="0 0 0" specular="0 0 0"/>
  <rgba fog="{_f(env.fog_rgb)} 1" haze="{_f(env.sky_horizon)} 1"/>
</visual>
<default><geom contype="0" conaffinity="0"/></default>
<asset>{"".join(materials)}{"".join(mesh_xml)}</asset>
<worldbody>{"".join(world)}</worldbody>
</mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml, assets)
    if model.ngeom != len(geom_class):
        raise RuntimeError(f"geom bookkeeping mismatch: {model.ngeom} != {len(geom_class)}")
    return SceneModel(model=model, geom_instance=np.asarray(geom_instance, np.uint16),
                      geom_class=np.asarray(geom_class, np.uint8), mover_ids=[m.id for m in movers],
                      mover_mocap=mover_mocap, mover_vertices=mover_vertices)


def _gl_context(width: int, height: int):
    """An off-screen context: EGL unless MUJOCO_GL=osmesa, whatever mujoco picked at import."""
    if os.environ.get("MUJOCO_GL", "egl").lower() == "osmesa":
        from mujoco.osmesa import GLContext
    else:
        from mujoco.egl import GLContext
    return GLContext(width, height)


@dataclass
class LabelPass:
    depth_m: np.ndarray  # float32, inf where nothing was hit
    geom: np.ndarray  # int32 geom id, -1 where nothing was hit


class SceneRenderer:
    """Owns one GL context and renders one compiled scene from its single camera."""

    def __init__(self, scene: SceneModel, width: int, height: int, fog: bool):
        self.scene = scene
        self.model = scene.model
        self.data = mujoco.MjData(self.model)
        self.width, self.height = width, height
        self._gl = _gl_context(width, height)
        self._gl.make_current()
        self._con = mujoco.MjrContext(self.model, mujoco.mjtFontScale.mjFONTSCALE_50)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._con)
        self._con.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR  # reversed Z: 1 near, 0 far
        self._vscene = mujoco.MjvScene(self.model, maxgeom=self.model.ngeom + 50)
        self._opt = mujoco.MjvOption()
        self._cam = mujoco.MjvCamera()
        self._cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._cam.fixedcamid = 0
        self._rect = mujoco.MjrRect(0, 0, width, height)
        self._fog = fog
        self._rgb = np.empty((height, width, 3), np.uint8)
        self._depth = np.empty((height, width), np.float32)
        self._mocap_pos = np.tile(HIDDEN_POS, (self.model.nmocap, 1))
        self._mocap_quat = np.tile([1.0, 0, 0, 0], (self.model.nmocap, 1))
        self._world_vertices: dict[int, np.ndarray] = {}
        self._apply_mocap(self._mocap_pos)

    def close(self) -> None:
        if self._con is not None:
            self._gl.make_current()
            self._con.free()
            self._gl.free()
            self._con = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # -- state ----------------------------------------------------------------------------------
    def _apply_mocap(self, pos: np.ndarray) -> None:
        self.data.mocap_pos[:] = pos
        self.data.mocap_quat[:] = self._mocap_quat
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_camlight(self.model, self.data)

    def set_movers(self, movers: list[Mover], t: float) -> dict[int, float]:
        """Pose every mover for time t; returns the true top height of each present mover.

        The top is the highest vertex of the mover's meshes: exactly the surface rendered.
        """
        self._mocap_pos[:] = HIDDEN_POS
        self._mocap_quat[:] = [1.0, 0, 0, 0]
        self._world_vertices = {}
        for mover in movers:
            poses = mover.poses(t)
            if poses is None:
                continue
            world = []
            for idx, local, (pos, quat) in zip(self.scene.mover_mocap[mover.id],
                                               self.scene.mover_vertices[mover.id], poses):
                self._mocap_pos[idx] = pos
                self._mocap_quat[idx] = quat
                world.append(local @ meshes.quat_to_matrix(quat).T + pos)
            self._world_vertices[mover.id] = np.concatenate(world)
        self._apply_mocap(self._mocap_pos)
        return {mid: float(v[:, 2].max()) for mid, v in self._world_vertices.items()}

    # -- passes ---------------------------------------------------------------------------------
    def _update(self, static: bool, movers_on: bool) -> None:
        self._opt.geomgroup[0] = int(static)
        self._opt.geomgroup[MOVER_GROUP] = int(movers_on)
        mujoco.mjv_updateScene(self.model, self.data, self._opt, None, self._cam,
                               mujoco.mjtCatBit.mjCAT_ALL, self._vscene)

    def _set_flags(self, labels: bool) -> None:
        flags = self._vscene.flags
        flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = labels
        flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = labels
        flags[mujoco.mjtRndFlag.mjRND_SHADOW] = not labels
        flags[mujoco.mjtRndFlag.mjRND_FOG] = self._fog and not labels
        flags[mujoco.mjtRndFlag.mjRND_SKYBOX] = not labels

    def render_rgb(self) -> np.ndarray:
        self._gl.make_current()
        self._update(static=True, movers_on=True)
        self._set_flags(labels=False)
        mujoco.mjr_render(self._rect, self._vscene, self._con)
        mujoco.mjr_readPixels(self._rgb, None, self._rect, self._con)
        return np.flipud(self._rgb).copy()

    def _label_pass(self, want_depth: bool) -> LabelPass:
        self._set_flags(labels=True)
        mujoco.mjr_render(self._rect, self._vscene, self._con)
        mujoco.mjr_readPixels(self._rgb, self._depth if want_depth else None, self._rect, self._con)
        rgb = np.flipud(self._rgb).astype(np.int32)
        segid = rgb[..., 0] + (rgb[..., 1] << 8) + (rgb[..., 2] << 16)  # scene geom index + 1
        lut = np.full(self._vscene.ngeom + 1, -1, np.int32)
        for i in range(self._vscene.ngeom):
            g = self._vscene.geoms[i]
            if g.objtype == mujoco.mjtObj.mjOBJ_GEOM:
                lut[g.segid + 1] = g.objid
        geom = lut[np.clip(segid, 0, self._vscene.ngeom)]
        depth = np.full((self.height, self.width), np.inf, np.float32)
        if want_depth:
            depth = self._linear_depth(np.flipud(self._depth))
            depth[geom < 0] = np.inf
        return LabelPass(depth_m=depth, geom=geom)

    def _linear_depth(self, buffer: np.ndarray) -> np.ndarray:
        """Reversed-Z depth buffer -> planar z-depth in metres (as mujoco.Renderer does)."""
        extent = self.model.stat.extent
        znear = np.float32(self.model.vis.map.znear * extent)
        zfar = np.float32(self.model.vis.map.zfar * extent)
        c = -(zfar + znear) / (zfar - znear)
        d = -(np.float32(2) * zfar * znear) / (zfar - znear)
        c = np.float32(-0.5) * c - np.float32(0.5)
        d = np.float32(-0.5) * d
        return (d / (buffer.astype(np.float64) + c)).astype(np.float32)

    def render_labels(self) -> LabelPass:
        """Depth and geom ids of everything, movers included (same mover poses as render_rgb)."""
        self._gl.make_current()
        self._update(static=True, movers_on=True)
        return self._label_pass(want_depth=True)

    def render_background(self) -> LabelPass:
        """Depth and geom ids with all movers removed."""
        self._gl.make_current()
        self._update(static=True, movers_on=False)
        return self._label_pass(want_depth=True)

    def render_amodal(self, groups: list[list[int]]) -> dict[int, np.ndarray]:
        """Full (unoccluded) silhouette mask of each mover, drawing each group alone."""
        self._gl.make_current()
        saved = self._mocap_pos.copy()
        masks: dict[int, np.ndarray] = {}
        for group in groups:
            pos = np.tile(HIDDEN_POS, (self.model.nmocap, 1))
            for mid in group:
                idx = self.scene.mover_mocap[mid]
                pos[idx] = saved[idx]
            self._apply_mocap(pos)
            self._update(static=False, movers_on=True)
            labels = self._label_pass(want_depth=False)
            inst = np.where(labels.geom >= 0, self.scene.geom_instance[np.maximum(labels.geom, 0)], 0)
            for mid in group:
                masks[mid] = inst == mid
        self._apply_mocap(saved)
        return masks

    def projected_boxes(self, camera: SynthCamera, mover_ids: list[int]) -> dict[int, tuple[float, ...] | None]:
        """Image box of each posed mover from its projected mesh vertices (None: behind the camera).

        The box of the projected vertices is the box of the silhouette, so it is exact (before
        clipping to the image); a mover crossing the camera plane gets the whole image.
        """
        boxes: dict[int, tuple[float, ...] | None] = {}
        for mid in mover_ids:
            uv, z = camera.project(self._world_vertices[mid])
            if (z <= 0.05).any():
                boxes[mid] = None if (z <= 0.05).all() else (-math.inf, -math.inf, math.inf, math.inf)
                continue
            boxes[mid] = (float(uv[:, 0].min()), float(uv[:, 1].min()), float(uv[:, 0].max()), float(uv[:, 1].max()))
        return boxes


def amodal_groups(boxes: dict[int, tuple[float, ...] | None], width: int, height: int) -> list[list[int]]:
    """Greedy colouring: movers whose projected boxes overlap go to different passes."""
    groups: list[list[int]] = []
    group_boxes: list[list[tuple[float, ...]]] = []
    for mid, box in boxes.items():
        if box is None or box[2] < 0 or box[3] < 0 or box[0] >= width or box[1] >= height:
            continue
        for g, gb in zip(groups, group_boxes):
            if all(box[2] < o[0] or o[2] < box[0] or box[3] < o[1] or o[3] < box[1] for o in gb):
                g.append(mid)
                gb.append(box)
                break
        else:
            groups.append([mid])
            group_boxes.append([box])
    return groups
