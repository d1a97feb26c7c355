"""Tessellate MuJoCo-style primitives and merge them into a few meshes.

Why: llvmpipe spends ~80 us of CPU per draw call and MuJoCo draws every geom once per
pass (shadow map, lit pass, label passes), so a scene of 800 primitives cost 250 ms a frame.
Merging all static primitives that share a material and class into one mesh, and each
mover part into one mesh per material, cuts the draws ~10x. Flat colours survive merging
through a palette texture: every primitive's vertices point at the centre of its colour's
cell (constant UVs, so no mip blending). Textured surfaces get world-planar UVs per face.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

SEGMENTS = 14  # around cylinders, capsules and spheres
RINGS = 8  # from pole to equator... per hemisphere of spheres


@dataclass
class MeshData:
    vertices: list[np.ndarray] = field(default_factory=list)
    normals: list[np.ndarray] = field(default_factory=list)
    uvs: list[np.ndarray] = field(default_factory=list)
    faces: list[np.ndarray] = field(default_factory=list)
    _count: int = 0

    def add(self, v: np.ndarray, n: np.ndarray, f: np.ndarray, uv: np.ndarray) -> None:
        self.vertices.append(v)
        self.normals.append(n)
        self.uvs.append(uv)
        self.faces.append(f + self._count)
        self._count += len(v)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        return (np.concatenate(self.vertices), np.concatenate(self.normals),
                np.concatenate(self.uvs), np.concatenate(self.faces))

    def __bool__(self) -> bool:
        return self._count > 0


def quat_to_matrix(q) -> np.ndarray:
    w, x, y, z = np.asarray(q, float) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _box(h) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    hx, hy, hz = h
    verts, norms, faces = [], [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            n = np.zeros(3)
            n[axis] = sign
            u, v = [a for a in range(3) if a != axis]
            quad = []
            for su, sv in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                p = np.zeros(3)
                p[axis] = sign
                p[u], p[v] = su, sv
                quad.append(p * [hx, hy, hz])
            base = len(verts)
            verts += quad
            norms += [n] * 4
            # Counter-clockwise seen from outside.
            if np.dot(np.cross(quad[1] - quad[0], quad[2] - quad[0]), n) > 0:
                faces += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
            else:
                faces += [[base, base + 2, base + 1], [base, base + 3, base + 2]]
    return np.array(verts), np.array(norms), np.array(faces)


def _lathe(profile: list[tuple[float, float, float, float]], caps: bool) -> tuple:
    """Surface of revolution about z from (r, z, normal_r, normal_z) rings."""
    angles = np.linspace(0, 2 * math.pi, SEGMENTS, endpoint=False)
    c, s = np.cos(angles), np.sin(angles)
    verts, norms = [], []
    for r, z, nr, nz in profile:
        verts.append(np.stack([r * c, r * s, np.full(SEGMENTS, z)], 1))
        norms.append(np.stack([nr * c, nr * s, np.full(SEGMENTS, nz)], 1))
    verts, norms = np.concatenate(verts), np.concatenate(norms)
    faces = []
    for i in range(len(profile) - 1):
        for j in range(SEGMENTS):
            a, b = i * SEGMENTS + j, i * SEGMENTS + (j + 1) % SEGMENTS
            c0, d = a + SEGMENTS, b + SEGMENTS
            faces += [[a, b, d], [a, d, c0]]
    faces = np.array(faces)
    if caps:
        extra_v, extra_n, extra_f = [], [], []
        for ring, sign in ((0, -1.0), (len(profile) - 1, 1.0)):
            r, z = profile[ring][0], profile[ring][1]
            base = len(verts) + len(extra_v)
            extra_v += [[0, 0, z]] + list(np.stack([r * c, r * s, np.full(SEGMENTS, z)], 1))
            extra_n += [[0, 0, sign]] * (SEGMENTS + 1)
            for j in range(SEGMENTS):
                a, b = base + 1 + j, base + 1 + (j + 1) % SEGMENTS
                extra_f.append([base, b, a] if sign < 0 else [base, a, b])
        verts = np.concatenate([verts, np.array(extra_v)])
        norms = np.concatenate([norms, np.array(extra_n)])
        faces = np.concatenate([faces, np.array(extra_f)])
    return verts, norms, faces


def _ellipsoid(radii) -> tuple:
    """A UV sphere scaled to the radii, with poles at +-z (so the top is a vertex)."""
    profile = []
    for k in range(2 * RINGS + 1):
        phi = -math.pi / 2 + math.pi * k / (2 * RINGS)
        profile.append((math.cos(phi), math.sin(phi), math.cos(phi), math.sin(phi)))
    v, n, f = _lathe(profile, caps=False)
    radii = np.asarray(radii, float)
    v = v * radii
    n = n / radii
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return v, n, f


def _capsule(radius: float, half: float) -> tuple:
    profile = []
    for k in range(RINGS + 1):  # bottom hemisphere
        phi = -math.pi / 2 + (math.pi / 2) * k / RINGS
        profile.append((radius * math.cos(phi), -half + radius * math.sin(phi), math.cos(phi), math.sin(phi)))
    for k in range(RINGS + 1):  # top hemisphere
        phi = (math.pi / 2) * k / RINGS
        profile.append((radius * math.cos(phi), half + radius * math.sin(phi), math.cos(phi), math.sin(phi)))
    return _lathe(profile, caps=False)


def _cylinder(radius: float, half: float) -> tuple:
    return _lathe([(radius, -half, 1.0, 0.0), (radius, half, 1.0, 0.0)], caps=True)


def _fromto_frame(fromto) -> tuple[np.ndarray, np.ndarray, float]:
    a, b = np.asarray(fromto[:3], float), np.asarray(fromto[3:], float)
    d = b - a
    length = float(np.linalg.norm(d))
    z = d / length if length > 1e-9 else np.array([0.0, 0.0, 1.0])
    helper = np.array([1.0, 0, 0]) if abs(z[0]) < 0.9 else np.array([0, 1.0, 0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return (a + b) / 2, np.stack([x, y, z], 1), length / 2


def tessellate(kind: str, size, pos=(0, 0, 0), quat=(1, 0, 0, 0),
               fromto=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices, normals and faces of one primitive in its parent's frame."""
    rot = quat_to_matrix(quat)
    centre = np.asarray(pos, float)
    if fromto is not None:
        centre, rot, half = _fromto_frame(fromto)
        size = (size[0], half)
    if kind == "box":
        v, n, f = _box(size)
    elif kind == "cylinder":
        v, n, f = _cylinder(size[0], size[1])
    elif kind == "capsule":
        v, n, f = _capsule(size[0], size[1])
    elif kind == "sphere":
        v, n, f = _ellipsoid((size[0],) * 3)
    elif kind == "ellipsoid":
        v, n, f = _ellipsoid(size)
    else:
        raise ValueError(f"cannot tessellate {kind!r}")
    return v @ rot.T + centre, n @ rot.T, f


def planar_uv(vertices: np.ndarray, normals: np.ndarray, tile_m: float) -> np.ndarray:
    """World-aligned planar texture coordinates, chosen per vertex by its dominant normal axis."""
    axis = np.argmax(np.abs(normals), axis=1)
    u = np.where(axis == 0, vertices[:, 1], vertices[:, 0])
    v = np.where(axis == 2, vertices[:, 1], -vertices[:, 2])
    return np.stack([u, v], 1) / tile_m


class Palette:
    """Maps flat colours to cells of one texture atlas."""

    CELL = 4
    GRID = 32  # 1024 colours

    def __init__(self):
        self.colours: dict[tuple[int, int, int], int] = {}

    def uv(self, rgba) -> np.ndarray:
        key = tuple(int(round(float(c) * 255)) for c in rgba[:3])
        if key not in self.colours:
            if len(self.colours) >= self.GRID * self.GRID:
                key = min(self.colours, key=lambda k: sum((a - b) ** 2 for a, b in zip(k, key)))
            else:
                self.colours[key] = len(self.colours)
        i = self.colours[key]
        row, col = divmod(i, self.GRID)
        return np.array([(col + 0.5) / self.GRID, (row + 0.5) / self.GRID])

    def image(self) -> np.ndarray:
        size = self.GRID * self.CELL
        img = np.zeros((size, size, 3), np.uint8)
        for colour, i in self.colours.items():
            row, col = divmod(i, self.GRID)
            img[row * self.CELL:(row + 1) * self.CELL, col * self.CELL:(col + 1) * self.CELL] = colour
        return img


def mesh_xml(name: str, mesh: MeshData) -> str:
    v, n, uv, f = mesh.arrays()

    def fmt(a, digits):
        return " ".join(map(f"{{:.{digits}g}}".format, np.asarray(a).ravel().tolist()))

    return (f'<mesh name="{name}" inertia="shell" vertex="{fmt(v, 7)}" normal="{fmt(n, 4)}" '
            f'texcoord="{fmt(uv, 6)}" face="{" ".join(map(str, f.ravel().tolist()))}"/>')
