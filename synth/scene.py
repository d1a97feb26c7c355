"""Static scene layouts ("areas"): ground, kerbs, buildings, clutter and the routes movers use.

Five families play the role of CARLA's towns: a street crossing, a plaza, a parking lot, a
sidewalk along a road and a campus path. Each is randomised from a layout seed (sizes,
textures, clutter, building heights), so one seed is one area, and the train/test split is
made on that seed.

All walkable and drivable surfaces lie on the plane z = 0: the height ground truth is then
world z, and the paper's Eq. 3 holds exactly. Painted layers (road on pavement, markings on
road) sit 0.3 mm and 0.6 mm above the plane so they never z-fight; they count as ground.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

LAYOUT_FAMILIES = ("street_crossing", "plaza", "parking_lot", "sidewalk_road", "campus_path")

# Semantic classes, indexed by the uint8 values of the semantic maps.
CLASS_NAMES = ("sky", "road", "pavement", "grass", "marking", "kerb", "building", "wall", "pole",
               "vegetation", "furniture", "parked_vehicle",
               "pedestrian", "cyclist", "car", "van", "truck", "bus")
CLASS_ID = {name: i for i, name in enumerate(CLASS_NAMES)}
GROUND_CLASSES = ("road", "pavement", "grass", "marking")

PATCH_TOP_M = 0.0003
MARKING_TOP_M = 0.0006


@dataclass
class Prim:
    """One static MuJoCo geom (sizes follow MuJoCo: half sizes for boxes, radius/half length)."""

    kind: str
    pos: tuple[float, float, float]
    size: tuple[float, ...]
    cls: str
    yaw: float = 0.0
    material: str = ""
    rgba: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)
    emission: float = 0.0
    """< 0: a lamp head that glows at dusk and night."""
    quat: tuple[float, float, float, float] | None = None
    """Full orientation (w, x, y, z); when given, ``yaw`` is ignored."""


@dataclass
class Route:
    """A polyline on the ground along which one kind of mover travels."""

    points: np.ndarray
    width: float
    kind: str  # "walk" | "drive" | "bike"
    two_way: bool = True

    @property
    def length(self) -> float:
        return float(np.linalg.norm(np.diff(self.points, axis=0), axis=1).sum())


@dataclass
class MaterialSpec:
    texture: str  # one of textures.TEXTURE_KINDS
    tile_m: float  # texture repeats every tile_m metres
    variant: int = 0


@dataclass
class Layout:
    family: str
    seed: int
    half_size: float
    base_material: str
    base_class: str
    prims: list[Prim] = field(default_factory=list)
    routes: list[Route] = field(default_factory=list)
    lamps: list[tuple[float, float, float]] = field(default_factory=list)
    materials: dict[str, MaterialSpec] = field(default_factory=dict)
    focus: list[tuple[float, float]] = field(default_factory=list)
    buildings: list[tuple[float, float, float, float, float]] = field(default_factory=list)
    """(cx, cy, hx, hy, height) of axis-aligned blocks, for camera line-of-sight checks."""
    crossing_roads: list[tuple[float, float, float]] = field(default_factory=list)
    """(y_center, half_width, sidewalk_width) of roads running along x: occlusion scenario."""


class _Builder:
    """Small helpers shared by the layout families."""

    def __init__(self, family: str, seed: int, half_size: float):
        self.rng = np.random.default_rng(seed)
        self.layout = Layout(family=family, seed=seed, half_size=half_size,
                             base_material="", base_class="pavement")
        self._variants: dict[str, int] = {}

    def material(self, texture: str, tile_m: float, variants: int = 1) -> str:
        """Register a material; with variants > 1 pick one of several looks of that texture."""
        variant = int(self.rng.integers(variants)) if variants > 1 else 0
        name = f"{texture}{variant}_{tile_m:g}"
        self.layout.materials[name] = MaterialSpec(texture, tile_m, variant)
        return name

    def base(self, material: str, cls: str) -> None:
        self.layout.base_material, self.layout.base_class = material, cls

    def patch(self, cx, cy, hx, hy, material, cls, yaw=0.0, top=PATCH_TOP_M, rgba=(1, 1, 1, 1)):
        """A painted ground area: a slab whose top face is ``top`` metres above the plane."""
        self.layout.prims.append(Prim("box", (cx, cy, top - 0.025), (hx, hy, 0.025), cls, yaw,
                                      material, rgba))

    def marking(self, cx, cy, hx, hy, yaw=0.0, colour=None):
        colour = colour or (0.92, 0.92, 0.88, 1.0)
        self.patch(cx, cy, hx, hy, "", "marking", yaw, MARKING_TOP_M, colour)

    def box(self, cx, cy, z0, hx, hy, hz, cls, yaw=0.0, material="", rgba=(0.6, 0.6, 0.6, 1)):
        self.layout.prims.append(Prim("box", (cx, cy, z0 + hz), (hx, hy, hz), cls, yaw, material, rgba))

    def kerb(self, x0, y0, x1, y1):
        cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
        length = math.hypot(x1 - x0, y1 - y0)
        yaw = math.atan2(y1 - y0, x1 - x0)
        grey = self.rng.uniform(0.55, 0.75)
        self.box(cx, cy, 0.0, length / 2, 0.1, 0.06, "kerb", yaw, rgba=(grey, grey, grey * 0.97, 1))

    def building(self, cx, cy, hx, hy, height=None):
        height = height if height is not None else float(self.rng.uniform(5.0, 24.0))
        facade = self.material("facade", float(self.rng.uniform(2.5, 3.5)), variants=4)
        self.box(cx, cy, 0.0, hx, hy, height / 2, "building", material=facade)
        # A roof slab in a plain colour, so the top is not a window grid.
        grey = self.rng.uniform(0.3, 0.6)
        self.box(cx, cy, height, hx, hy, 0.15, "building", rgba=(grey, grey, grey, 1))
        self.layout.buildings.append((cx, cy, hx, hy, height + 0.3))

    def wall(self, x0, y0, x1, y1, height=None):
        height = height if height is not None else float(self.rng.uniform(0.5, 2.2))
        cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
        length = math.hypot(x1 - x0, y1 - y0)
        yaw = math.atan2(y1 - y0, x1 - x0)
        material = self.material("brick", 1.5, variants=2) if self.rng.random() < 0.6 else \
            self.material("concrete", 2.0, variants=2)
        self.box(cx, cy, 0.0, length / 2, 0.15, height / 2, "wall", yaw, material)
        if abs(math.sin(yaw)) < 1e-6 or abs(math.cos(yaw)) < 1e-6:
            hx, hy = (length / 2, 0.15) if abs(math.cos(yaw)) > 0.5 else (0.15, length / 2)
            self.layout.buildings.append((cx, cy, hx, hy, height))

    def lamp(self, x, y, height=None):
        height = height if height is not None else float(self.rng.uniform(4.5, 7.0))
        grey = self.rng.uniform(0.2, 0.45)
        self.layout.prims.append(Prim("cylinder", (x, y, height / 2), (0.07, height / 2), "pole",
                                      rgba=(grey, grey, grey, 1)))
        self.layout.prims.append(Prim("box", (x, y, height + 0.08), (0.3, 0.15, 0.08), "pole",
                                      rgba=(0.9, 0.9, 0.8, 1), emission=-1.0))
        self.layout.lamps.append((x, y, height))

    def tree(self, x, y):
        trunk_h = float(self.rng.uniform(1.8, 3.5))
        crown = float(self.rng.uniform(1.2, 2.8))
        bark = (self.rng.uniform(0.25, 0.4), self.rng.uniform(0.17, 0.25), 0.1, 1)
        leaf = (self.rng.uniform(0.1, 0.3), self.rng.uniform(0.3, 0.55), self.rng.uniform(0.05, 0.2), 1)
        self.layout.prims.append(Prim("cylinder", (x, y, trunk_h / 2), (0.14, trunk_h / 2),
                                      "vegetation", rgba=bark))
        self.layout.prims.append(Prim("ellipsoid", (x, y, trunk_h + crown * 0.8),
                                      (crown, crown, crown * float(self.rng.uniform(0.9, 1.4))),
                                      "vegetation", rgba=leaf))

    def bench(self, x, y, yaw):
        wood = (self.rng.uniform(0.35, 0.6), self.rng.uniform(0.22, 0.4), 0.15, 1)
        self.box(x, y, 0.42, 0.9, 0.22, 0.03, "furniture", yaw, rgba=wood)
        dx, dy = -math.sin(yaw) * 0.22, math.cos(yaw) * 0.22
        self.box(x + dx, y + dy, 0.45, 0.9, 0.03, 0.22, "furniture", yaw, rgba=wood)
        for side in (-0.75, 0.75):
            self.box(x + math.cos(yaw) * side, y + math.sin(yaw) * side, 0.0, 0.04, 0.2, 0.21,
                     "furniture", yaw, rgba=(0.2, 0.2, 0.2, 1))

    def bin(self, x, y):
        colour = [(0.1, 0.3, 0.1, 1), (0.3, 0.3, 0.3, 1), (0.5, 0.2, 0.1, 1)][int(self.rng.integers(3))]
        self.layout.prims.append(Prim("cylinder", (x, y, 0.45), (0.28, 0.45), "furniture", rgba=colour))

    def bollard(self, x, y):
        self.layout.prims.append(Prim("cylinder", (x, y, 0.5), (0.08, 0.5), "pole",
                                      rgba=(0.25, 0.25, 0.25, 1)))

    def parked_car(self, x, y, yaw):
        """A static car (not a mover, instance 0), the same shape family as moving cars."""
        from synth.movers import vehicle_geoms  # local: movers imports this module

        from synth.movers import quat_mul, quat_yaw

        colour = car_colour(self.rng)
        for g in vehicle_geoms("car", self.rng, colour)[0]:
            px, py = g.pos[0], g.pos[1]
            wx = x + math.cos(yaw) * px - math.sin(yaw) * py
            wy = y + math.sin(yaw) * px + math.cos(yaw) * py
            quat = tuple(quat_mul(quat_yaw(yaw), np.asarray(g.quat)))
            self.layout.prims.append(Prim(g.kind, (wx, wy, g.pos[2]), g.size, "parked_vehicle",
                                          rgba=g.rgba, quat=quat))

    def route(self, points, width, kind, two_way=True):
        self.layout.routes.append(Route(np.asarray(points, float), width, kind, two_way))

    def clear_of_routes(self, x, y, margin=0.6) -> bool:
        for r in self.layout.routes:
            if _point_polyline_distance(np.array([x, y]), r.points) < r.width / 2 + margin:
                return False
        return True

    def scatter(self, count, place, region, tries=40):
        """Call place(x, y) at up to count random points of region (x0, y0, x1, y1) off routes."""
        x0, y0, x1, y1 = region
        placed = 0
        for _ in range(count * tries):
            if placed >= count:
                break
            x, y = self.rng.uniform(x0, x1), self.rng.uniform(y0, y1)
            if self.clear_of_routes(x, y) and not self._in_building(x, y):
                place(x, y)
                placed += 1

    def _in_building(self, x, y, margin=1.0):
        return any(abs(x - cx) < hx + margin and abs(y - cy) < hy + margin
                   for cx, cy, hx, hy, _ in self.layout.buildings)


def car_colour(rng: np.random.Generator) -> tuple[float, float, float, float]:
    palette = [(0.9, 0.9, 0.9), (0.1, 0.1, 0.1), (0.55, 0.55, 0.58), (0.6, 0.1, 0.1),
               (0.1, 0.2, 0.5), (0.75, 0.75, 0.78), (0.2, 0.35, 0.25), (0.85, 0.7, 0.2)]
    base = np.array(palette[int(rng.integers(len(palette)))]) * rng.uniform(0.85, 1.1)
    return (*np.clip(base, 0, 1).tolist(), 1.0)


def _point_polyline_distance(p: np.ndarray, points: np.ndarray) -> float:
    a, b = points[:-1], points[1:]
    ab = b - a
    t = np.clip(((p - a) * ab).sum(1) / np.maximum((ab * ab).sum(1), 1e-9), 0, 1)
    closest = a + t[:, None] * ab
    return float(np.linalg.norm(closest - p, axis=1).min())


# ---------------------------------------------------------------------------------------------
# The five families


def _street_crossing(b: _Builder) -> None:
    rng, H = b.rng, b.layout.half_size
    road_x = float(rng.uniform(7.0, 12.0))   # width of the road along x
    road_y = float(rng.uniform(6.0, 11.0))   # width of the road along y
    walk = float(rng.uniform(2.5, 5.0))
    b.base(b.material(str(rng.choice(["paving", "slabs", "concrete"])), float(rng.uniform(1.5, 3.0)),
                      variants=2), "pavement")
    asphalt = b.material("asphalt", 4.0, variants=2)
    ax, ay = road_y / 2, road_x / 2  # half extents of the intersection square
    b.patch(0, 0, H + 30, ay, asphalt, "road")
    for sign in (-1, 1):
        b.patch(0, sign * (ay + (H + 30 - ay) / 2), ax, (H + 30 - ay) / 2, asphalt, "road")
    # Zebra crossings where the sidewalks meet the roads, dashed centre lines, stop lines.
    stripe = 0.5
    for sign in (-1, 1):
        y_walk = sign * (ay + walk / 2)
        x_walk = sign * (ax + walk / 2)
        for k in range(int(road_y / (2 * stripe))):
            b.marking(-ax + stripe / 2 + 2 * k * stripe + 0.25, y_walk, stripe / 2, min(walk, 3.5) / 2)
        for k in range(int(road_x / (2 * stripe))):
            b.marking(x_walk, -ay + stripe / 2 + 2 * k * stripe + 0.25, min(walk, 3.5) / 2, stripe / 2)
        for k in range(12):
            x = sign * (ax + walk + 2 + 6 * k)
            if abs(x) < H + 20:
                b.marking(x, 0, 1.5, 0.07)
            y = sign * (ay + walk + 2 + 6 * k)
            if abs(y) < H + 20:
                b.marking(0, y, 0.07, 1.5)
    # Kerbs along the road edges, broken at the crossings.
    for sx in (-1, 1):
        for sy in (-1, 1):
            b.kerb(sx * (ax + walk), sy * ay, sx * (H + 30), sy * ay)
            b.kerb(sx * ax, sy * (ay + walk), sx * ax, sy * (H + 30))
    # Routes: lanes drive on the right, sidewalks are two-way.
    L = H + 40
    b.route([(-L, -ay / 2), (L, -ay / 2)], 0.6, "drive", two_way=False)
    b.route([(L, ay / 2), (-L, ay / 2)], 0.6, "drive", two_way=False)
    b.route([(ax / 2, -L), (ax / 2, L)], 0.6, "drive", two_way=False)
    b.route([(-ax / 2, L), (-ax / 2, -L)], 0.6, "drive", two_way=False)
    for sign in (-1, 1):
        b.route([(-L, sign * (ay + walk / 2)), (L, sign * (ay + walk / 2))], walk * 0.6, "walk")
        b.route([(sign * (ax + walk / 2), -L), (sign * (ax + walk / 2), L)], walk * 0.6, "walk")
    b.route([(-L, -ay + 0.9), (L, -ay + 0.9)], 0.3, "bike", two_way=False)
    b.route([(L, ay - 0.9), (-L, ay - 0.9)], 0.3, "bike", two_way=False)
    # Buildings on the four corner blocks, set back behind the sidewalks.
    for sx in (-1, 1):
        for sy in (-1, 1):
            x0, y0 = ax + walk + float(rng.uniform(0.5, 4.0)), ay + walk + float(rng.uniform(0.5, 4.0))
            x = x0
            while x < H:
                w = float(rng.uniform(8, 25))
                depth = float(rng.uniform(8, 20))
                b.building(sx * (x + w / 2), sy * (y0 + depth / 2), w / 2, depth / 2)
                x += w + float(rng.uniform(0, 6))
            y = y0 + float(rng.uniform(8, 20)) + 2
            while y < H:
                h = float(rng.uniform(8, 25))
                b.building(sx * (x0 + 6), sy * (y + h / 2), 6, h / 2)
                y += h + float(rng.uniform(0, 6))
    # Street furniture along the kerbs.
    for sx in (-1, 1):
        for sy in (-1, 1):
            for k in range(4):
                d = ax + walk + 4 + k * float(rng.uniform(9, 16))
                if d < H:
                    b.lamp(sx * d, sy * (ay + 0.5))
                d2 = ay + walk + 4 + k * float(rng.uniform(9, 16))
                if d2 < H and rng.random() < 0.7:
                    b.tree(sx * (ax + 0.9), sy * d2)
            b.bollard(sx * (ax + 0.35), sy * (ay + 0.35))
            b.bin(sx * (ax + walk - 0.4), sy * (ay + walk + 1.5))
    b.layout.focus = [(0.0, 0.0), (ax + walk / 2, ay + walk / 2), (-ax - walk, -ay - walk / 2),
                      (12.0, 0.0)]
    b.layout.crossing_roads = [(0.0, ay, walk)]


def _plaza(b: _Builder) -> None:
    rng, H = b.rng, b.layout.half_size
    P = float(rng.uniform(18, 30))  # plaza half size
    b.base(b.material(str(rng.choice(["slabs", "paving"])), float(rng.uniform(1.0, 3.0)), variants=3),
           "pavement")
    if rng.random() < 0.6:  # a patterned inner square
        b.patch(0, 0, P * 0.6, P * 0.6, b.material("paving", float(rng.uniform(0.8, 2.0)), 2), "pavement")
    road_w = float(rng.uniform(7, 10))
    road_y = -P - 3 - road_w / 2
    b.patch(0, road_y, H + 30, road_w / 2, b.material("asphalt", 4.0, 2), "road")
    b.kerb(-H - 30, road_y + road_w / 2, H + 30, road_y + road_w / 2)
    for k in range(-12, 13):
        b.marking(k * 6.0, road_y, 1.5, 0.07)
    L = H + 40
    b.route([(-L, road_y - road_w / 4), (L, road_y - road_w / 4)], 0.5, "drive", two_way=False)
    b.route([(L, road_y + road_w / 4), (-L, road_y + road_w / 4)], 0.5, "drive", two_way=False)
    # A central feature: fountain basin or monument.
    feature_r = float(rng.uniform(2.0, 4.5))
    if rng.random() < 0.5:
        b.layout.prims.append(Prim("cylinder", (0, 0, 0.3), (feature_r, 0.3), "wall",
                                   material=b.material("concrete", 2.0, 2)))
        b.layout.prims.append(Prim("cylinder", (0, 0, 0.61), (feature_r - 0.3, 0.01), "wall",
                                   rgba=(0.2, 0.35, 0.5, 1)))
    else:
        b.box(0, 0, 0, feature_r * 0.5, feature_r * 0.5, 0.6, "wall", material=b.material("concrete", 2.0, 2))
        b.box(0, 0, 1.2, 0.4, 0.4, float(rng.uniform(1.0, 2.5)), "wall", rgba=(0.5, 0.45, 0.4, 1))
    # Walking routes between random points of the plaza edge that miss the feature.
    for _ in range(int(rng.integers(8, 14))):
        for _ in range(30):
            a, c = rng.uniform(0, 2 * math.pi, 2)
            p0 = np.array([math.cos(a), math.sin(a)]) * P * 1.35
            p1 = np.array([math.cos(c), math.sin(c)]) * P * 1.35
            if _point_polyline_distance(np.zeros(2), np.stack([p0, p1])) > feature_r + 1.5:
                b.route([p0, p1], 1.2, "walk")
                break
    b.route([(-L, road_y + road_w / 2 + 1.5), (L, road_y + road_w / 2 + 1.5)], 2.0, "walk")
    b.route([(-P, P * 0.8), (P, -P * 0.7)], 0.8, "bike")
    # Buildings on three sides, with gaps.
    for side in range(3):
        pos = -H
        while pos < H:
            w = float(rng.uniform(10, 28))
            depth = float(rng.uniform(8, 16))
            gap = float(rng.uniform(0, 5))
            c = pos + w / 2
            setback = P + float(rng.uniform(3, 8)) + depth / 2
            if side == 0:
                b.building(c, setback, w / 2, depth / 2)
            elif side == 1:
                b.building(-setback, c, depth / 2, w / 2)
            else:
                b.building(setback, c, depth / 2, w / 2)
            pos += w + gap
    b.scatter(int(rng.integers(4, 10)), lambda x, y: b.tree(x, y), (-P, -P, P, P))
    b.scatter(int(rng.integers(3, 8)), lambda x, y: b.bench(x, y, float(rng.uniform(0, math.pi))), (-P, -P, P, P))
    b.scatter(int(rng.integers(2, 5)), b.bin, (-P, -P, P, P))
    b.scatter(int(rng.integers(4, 9)), b.lamp, (-P, -P, P, P))
    for k in range(-4, 5):
        b.bollard(k * 4.0 + 2.0, road_y + road_w / 2 + 0.5)
    b.layout.focus = [(0.0, 0.0), (P * 0.5, -P * 0.5), (-P * 0.4, P * 0.3), (0.0, road_y + road_w)]


def _parking_lot(b: _Builder) -> None:
    rng, H = b.rng, b.layout.half_size
    b.base(b.material("asphalt", 4.0, variants=3), "road")
    stall_w, stall_d, aisle = 2.5, 5.0, float(rng.uniform(6.0, 7.5))
    n_rows = int(rng.integers(2, 4))
    half_len = float(rng.uniform(20, 35))
    block = 2 * stall_d + aisle
    y = -n_rows * block / 2
    L = H + 40
    for row in range(n_rows):
        aisle_y = y + aisle / 2
        b.route([(-L, aisle_y - 1.5), (L, aisle_y - 1.5)], 0.3, "drive", two_way=False)
        b.route([(L, aisle_y + 1.5), (-L, aisle_y + 1.5)], 0.3, "drive", two_way=False)
        b.route([(-half_len - 5, aisle_y + aisle / 2 - 0.8), (half_len + 5, aisle_y + aisle / 2 - 0.8)],
                1.0, "walk")
        for side, y_stall in ((1, y + aisle + stall_d / 2), (-1, y - stall_d / 2)):
            if row > 0 and side == -1:
                continue
            for k in range(int(2 * half_len / stall_w) + 1):
                x = -half_len + k * stall_w
                b.marking(x, y_stall, 0.06, stall_d / 2 - 0.2)
                if k < int(2 * half_len / stall_w) and rng.random() < 0.6:
                    yaw = math.pi / 2 if rng.random() < 0.5 else -math.pi / 2
                    b.parked_car(x + stall_w / 2, y_stall + float(rng.uniform(-0.3, 0.3)), yaw)
        y += aisle + 2 * stall_d
    # Cross walkways from the lot to the building entrance.
    top = y + 3
    for x in rng.uniform(-half_len, half_len, 3):
        b.route([(x, -n_rows * block / 2 - 6), (x, top + 2)], 1.2, "walk")
    b.patch(0, top + 2.5, H + 30, 2.5, b.material("paving", 1.5, 2), "pavement")
    b.kerb(-H - 30, top, H + 30, top)
    b.route([(-L, top + 2.5), (L, top + 2.5)], 2.5, "walk")
    b.building(0, top + 5 + 10, float(rng.uniform(20, 45)), 10, float(rng.uniform(5, 12)))
    for k in range(-3, 4):
        b.lamp(k * float(rng.uniform(10, 14)), -n_rows * block / 2 - 2)
    for x in (-half_len - 4, half_len + 4):
        for k in range(3):
            b.tree(x + float(rng.uniform(-1, 1)), -n_rows * block / 2 + k * 7 + 2)
    b.scatter(6, b.bollard, (-half_len, top + 0.5, half_len, top + 1.0))
    b.layout.focus = [(0.0, 0.0), (half_len * 0.5, aisle / 2), (-half_len * 0.4, -block / 2), (0.0, top)]


def _sidewalk_road(b: _Builder) -> None:
    rng, H = b.rng, b.layout.half_size
    lanes = int(rng.integers(1, 3))
    lane_w = float(rng.uniform(3.0, 3.6))
    road_w = 2 * lanes * lane_w
    parking = rng.random() < 0.6
    walk_n, walk_s = float(rng.uniform(3, 6)), float(rng.uniform(2.5, 5))
    b.base(b.material(str(rng.choice(["paving", "slabs"])), float(rng.uniform(1.0, 2.5)), variants=3), "pavement")
    asphalt = b.material("asphalt", 4.0, 2)
    park_w = 2.2 if parking else 0.0
    half = road_w / 2 + park_w
    b.patch(0, 0, H + 30, half, asphalt, "road")
    for k in range(-14, 15):
        b.marking(k * 6.0, 0, 1.5, 0.07)
    for s in (-1, 1):
        b.kerb(-H - 30, s * half, H + 30, s * half)
        b.marking(0, s * (road_w / 2 - 0.2), H + 30, 0.06)
    L = H + 40
    for i in range(lanes):
        off = lane_w * (i + 0.5)
        b.route([(-L, -off), (L, -off)], 0.5, "drive", two_way=False)
        b.route([(L, off), (-L, off)], 0.5, "drive", two_way=False)
    b.route([(-L, -road_w / 2 + 0.8), (L, -road_w / 2 + 0.8)], 0.3, "bike", two_way=False)
    zebra_x = float(rng.uniform(-15, 15))
    for k in range(int(2 * half / 1.0)):
        b.marking(zebra_x, -half + 0.5 + k * 1.0, 1.75, 0.25)
    b.route([(zebra_x, -half - walk_s), (zebra_x, half + walk_n)], 2.5, "walk")
    b.route([(-L, half + walk_n / 2), (L, half + walk_n / 2)], walk_n * 0.6, "walk")
    b.route([(-L, -half - walk_s / 2), (L, -half - walk_s / 2)], walk_s * 0.6, "walk")
    if parking:
        x = -H
        while x < H:
            if abs(x - zebra_x) > 5 and rng.random() < 0.55:
                b.parked_car(x, half - 1.1, math.pi if rng.random() < 0.5 else 0.0)
            x += float(rng.uniform(5.5, 8))
    # Facades: a continuous row on the north side, sparser on the south.
    for s, walk, density in ((1, walk_n, 1.0), (-1, walk_s, 0.6)):
        x = -H - 10
        while x < H + 10:
            w = float(rng.uniform(6, 20))
            if rng.random() < density:
                depth = float(rng.uniform(8, 15))
                b.building(x + w / 2, s * (half + walk + depth / 2), w / 2, depth / 2)
            x += w + (0 if rng.random() < 0.7 else float(rng.uniform(1, 4)))
        for k in range(-6, 7):
            xx = k * float(rng.uniform(8, 12))
            if abs(xx - zebra_x) < 3:
                continue
            if k % 2:
                b.lamp(xx, s * (half + 0.5))
            elif rng.random() < 0.7:
                b.tree(xx, s * (half + 0.9))
    # A bus stop shelter on the north sidewalk.
    sx = zebra_x + float(rng.choice([-1, 1])) * float(rng.uniform(8, 20))
    y_shelter = half + walk_n - 0.8
    b.box(sx, y_shelter, 2.3, 2.0, 0.8, 0.05, "furniture", rgba=(0.3, 0.3, 0.35, 1))
    for dx in (-1.9, 1.9):
        b.box(sx + dx, y_shelter, 0, 0.05, 0.05, 1.15, "pole", rgba=(0.2, 0.2, 0.2, 1))
    b.bench(sx, y_shelter + 0.4, 0.0)
    b.layout.focus = [(0.0, 0.0), (zebra_x, 0.0), (sx, half + walk_n / 2), (-10.0, -half)]
    b.layout.crossing_roads = [(0.0, half, walk_n)]


def _campus_path(b: _Builder) -> None:
    rng, H = b.rng, b.layout.half_size
    b.base(b.material("grass", float(rng.uniform(1.5, 3.0)), variants=3), "grass")
    path_mat = b.material(str(rng.choice(["paving", "gravel", "concrete", "slabs"])),
                          float(rng.uniform(1.0, 2.5)), variants=2)
    L = H + 40
    # A few long straight paths through a common hub, plus a plaza patch at the hub.
    hub = rng.uniform(-8, 8, 2)
    angles = np.sort(rng.uniform(0, math.pi, int(rng.integers(2, 4))))
    for i, a in enumerate(angles):
        w = float(rng.uniform(2.5, 5.0))
        d = np.array([math.cos(a), math.sin(a)])
        c = hub + (0 if i == 0 else rng.uniform(-10, 10)) * np.array([-d[1], d[0]])
        b.patch(float(c[0]), float(c[1]), L, w / 2, path_mat, "pavement", yaw=float(a),
                top=PATCH_TOP_M * (1 + 0.3 * i))
        b.route([c - d * L, c + d * L], w * 0.6, "walk")
        if w > 3.5:
            b.route([c - d * L + 0.5 * w / 4 * np.array([-d[1], d[0]]),
                     c + d * L + 0.5 * w / 4 * np.array([-d[1], d[0]])], 0.3, "bike")
    b.patch(float(hub[0]), float(hub[1]), 6, 6, b.material("slabs", 2.0, 2), "pavement",
            top=PATCH_TOP_M * 2)
    # A service road along the south edge.
    road_y = -H * 0.7
    b.patch(0, road_y, H + 30, 3.5, b.material("asphalt", 4.0, 2), "road", top=PATCH_TOP_M * 3)
    b.route([(-L, road_y - 1.7), (L, road_y - 1.7)], 0.4, "drive", two_way=False)
    b.route([(L, road_y + 1.7), (-L, road_y + 1.7)], 0.4, "drive", two_way=False)
    b.kerb(-H - 30, road_y + 3.5, H + 30, road_y + 3.5)
    # Buildings at the north and east edges, low walls and hedges in between.
    x = -H
    while x < H:
        w = float(rng.uniform(15, 35))
        if rng.random() < 0.8:
            b.building(x + w / 2, H * 0.75 + 8, w / 2, 8, float(rng.uniform(8, 20)))
        x += w + float(rng.uniform(3, 12))
    b.building(H * 0.8 + 8, 0, 8, float(rng.uniform(10, 25)))
    region = (-H * 0.7, road_y + 5, H * 0.7, H * 0.7)
    b.scatter(int(rng.integers(10, 22)), b.tree, region)
    b.scatter(int(rng.integers(3, 7)), lambda x, y: b.wall(x, y, x + float(rng.uniform(4, 10)), y), region)
    b.scatter(int(rng.integers(4, 9)), lambda x, y: b.bench(x, y, float(rng.uniform(0, math.pi))), region)
    b.scatter(int(rng.integers(5, 9)), b.lamp, region)
    b.scatter(int(rng.integers(2, 5)), b.bin, region)
    b.layout.focus = [(float(hub[0]), float(hub[1])), (float(hub[0]) + 10, float(hub[1]) - 5),
                      (0.0, road_y + 4)]


_FAMILIES = {
    "street_crossing": _street_crossing,
    "plaza": _plaza,
    "parking_lot": _parking_lot,
    "sidewalk_road": _sidewalk_road,
    "campus_path": _campus_path,
}


def build_layout(family: str, seed: int) -> Layout:
    """One randomised area of the given family; the same (family, seed) gives the same area."""
    if family not in _FAMILIES:
        raise ValueError(f"unknown layout family {family!r} (known: {', '.join(LAYOUT_FAMILIES)})")
    builder = _Builder(family, seed, half_size=70.0)
    _FAMILIES[family](builder)
    return builder.layout
