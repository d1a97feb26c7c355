"""One sequence, from seeds to rendered frames.

``plan_sequence`` turns (root seed, sequence index, options) into every random decision:
area, camera, light and weather, and the movers with their routes and timing. It is pure
NumPy and cheap. ``render_sequence`` renders a plan frame by frame with MuJoCo.

Seeds: every sequence derives its own seed from the root seed and its index, and the area
from a layout seed shared by ``views_per_layout`` consecutive sequences (like the paper's
five cameras per CARLA town). The split is a hash of the layout seed, so train and test
never share an area.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field

import numpy as np

from synth.camera import (FOV_RANGE_DEG, HEIGHT_RANGE_M, PAPER_HEIGHTS_M, PITCH_RANGE_DEG, ROLL_MAX_DEG,
                          SynthCamera, make_camera)
from synth.movers import Mover, make_cyclist, make_pedestrian, make_vehicle
from synth.scene import LAYOUT_FAMILIES, Layout, Route, build_layout, car_colour
from synth.weather import Environment, sample_environment


def derive_seed(*parts) -> int:
    """A stable 31-bit seed from any mix of ints and strings (independent of PYTHONHASHSEED)."""
    digest = hashlib.sha256(repr(parts).encode()).digest()
    return int.from_bytes(digest[:4], "little") & 0x7FFFFFFF


def layout_split(layout_seed: int, test_fraction: float) -> str:
    """'test' for a fixed share of layout seeds, 'train' for the rest."""
    digest = hashlib.sha256(f"heightpipe-split:{layout_seed}".encode()).digest()
    u = int.from_bytes(digest[:8], "little") / 2.0 ** 64
    return "test" if u < test_fraction else "train"


@dataclass
class SequenceOptions:
    frames: int = 60
    fps: float = 10.0
    sizes: tuple[tuple[int, int], ...] = ((320, 240),)
    preset: str = ""  # "" or "paper"
    scenario: str = ""  # "" or "occlusion"
    views_per_layout: int = 5
    test_fraction: float = 0.2
    shadows: bool = True
    msaa: int = 0
    post_effects: bool = True
    layout: str = ""  # force a family
    time_of_day: str = ""  # force, e.g. "day"
    weather: str = ""
    camera_height_m: float = 0.0  # force
    pedestrians: tuple[int, int] = (5, 16)
    vehicles: tuple[int, int] = (1, 6)
    cyclists: tuple[int, int] = (0, 3)


@dataclass
class SequencePlan:
    name: str
    index: int
    seed: int
    layout: Layout
    layout_seed: int
    split: str
    camera: SynthCamera
    env: Environment
    movers: list[Mover]
    options: SequenceOptions
    focus: np.ndarray
    notes: dict = field(default_factory=dict)

    def meta(self) -> dict:
        o = self.options
        return {
            "name": self.name, "index": self.index, "seed": self.seed, "layout": self.layout.family,
            "layout_seed": self.layout_seed, "split": self.split, "fps": o.fps, "frames": o.frames,
            "weather": self.env.weather, "time_of_day": self.env.time_of_day, "scenario": o.scenario,
            "camera": self.camera.to_json(), "environment": self.env.to_json(),
            "render": {"shadows": self.env.shadows, "msaa": o.msaa, "post_effects": o.post_effects},
            "movers": [{"id": m.id, "class": m.cls, "nominal_height_m": round(m.nominal_height_m, 4),
                        "speed_mps": round(m.speed, 3), "length_m": round(m.length_m, 3),
                        "width_m": round(m.width_m, 3)} for m in self.movers],
            "notes": self.notes,
        }


def sequence_layout(root_seed: int, index: int, options: SequenceOptions) -> tuple[str, int]:
    """(family, layout seed) of sequence ``index``; families take turns so all five appear."""
    k = index // max(1, options.views_per_layout)
    layout_seed = derive_seed(root_seed, "layout", k)
    family = options.layout or LAYOUT_FAMILIES[k % len(LAYOUT_FAMILIES)]
    if options.scenario == "occlusion":
        family = "street_crossing"
    return family, layout_seed


def plan_sequence(root_seed: int, index: int, options: SequenceOptions) -> SequencePlan:
    seed = derive_seed(root_seed, "sequence", index)
    family, layout_seed = sequence_layout(root_seed, index, options)
    layout = build_layout(family, layout_seed)
    rng_cam, rng_env, rng_movers = (np.random.default_rng([seed, k]) for k in range(3))
    width, height = options.sizes[int(rng_cam.integers(len(options.sizes)))]
    if options.camera_height_m > 0:
        cam_h = options.camera_height_m
    elif options.preset == "paper":
        cam_h = PAPER_HEIGHTS_M[index % len(PAPER_HEIGHTS_M)]
    else:
        cam_h = float(rng_cam.uniform(*HEIGHT_RANGE_M))
    env = sample_environment(rng_env, options.time_of_day or None, options.weather or None, options.shadows)
    notes: dict = {}
    movers: list[Mover] = []
    if options.scenario == "occlusion":
        camera, focus, movers, notes = _occlusion_scenario(layout, rng_cam, rng_movers, width, height, options)
    else:
        camera, focus = _sample_camera(layout, rng_cam, cam_h, width, height)
    _add_random_movers(layout, camera, rng_movers, options, movers,
                       skip_routes=notes.get("reserved_routes", []))
    notes.pop("reserved_routes", None)
    return SequencePlan(name=f"seq{index:05d}", index=index, seed=seed, layout=layout, layout_seed=layout_seed,
                        split=layout_split(layout_seed, options.test_fraction), camera=camera, env=env,
                        movers=movers, options=options, focus=focus, notes=notes)


# --- camera ------------------------------------------------------------------------------------

def _blocked(layout: Layout, a: np.ndarray, b: np.ndarray, za: float, zb: float) -> bool:
    """Does the 3D segment a->b (heights za, zb) pass through a building block?"""
    for cx, cy, hx, hy, h in layout.buildings:
        for s in np.linspace(0.0, 1.0, 40):
            p = a + (b - a) * s
            if abs(p[0] - cx) < hx and abs(p[1] - cy) < hy and za + (zb - za) * s < h:
                return True
    return False


def _in_clutter(layout: Layout, eye: np.ndarray, margin: float = 2.0) -> bool:
    """Is the camera inside or right next to a tree crown, lamp head or other static object?"""
    from synth.meshes import quat_to_matrix

    for prim in layout.prims:
        if prim.cls in ("road", "pavement", "grass", "marking", "building", "kerb"):
            continue
        quat = prim.quat if prim.quat is not None else (math.cos(prim.yaw / 2), 0.0, 0.0, math.sin(prim.yaw / 2))
        local = quat_to_matrix(quat).T @ (eye - np.asarray(prim.pos))
        if prim.kind == "box":
            gap = float(np.linalg.norm(np.maximum(np.abs(local) - np.asarray(prim.size), 0.0)))
        elif prim.kind == "cylinder":
            gap = math.hypot(max(math.hypot(local[0], local[1]) - prim.size[0], 0.0),
                             max(abs(local[2]) - prim.size[1], 0.0))
        else:
            gap = float(np.linalg.norm(local)) - max(prim.size)
        if gap < margin:
            return True
    return False


def _sample_camera(layout: Layout, rng: np.random.Generator, cam_h: float, width: int, height: int):
    best = None
    for attempt in range(150):
        focus = np.asarray(layout.focus[int(rng.integers(len(layout.focus)))], float) + rng.uniform(-6, 6, 2)
        pitch = float(rng.uniform(*PITCH_RANGE_DEG))
        fov = float(rng.uniform(*FOV_RANGE_DEG))
        yaw = float(rng.uniform(0, 360))
        roll = float(np.clip(rng.normal(0, 1.2), -ROLL_MAX_DEG, ROLL_MAX_DEG))
        dist = cam_h / math.tan(math.radians(pitch))
        heading = np.array([math.cos(math.radians(yaw)), math.sin(math.radians(yaw))])
        pos_xy = focus - heading * dist
        camera = make_camera(np.array([pos_xy[0], pos_xy[1], cam_h]), yaw, pitch, roll, fov, width, height)
        # Reject cameras inside a building or with a building between them and the focus.
        near_xy = pos_xy + heading * 0.3
        inside = _blocked(layout, pos_xy, near_xy, cam_h, cam_h)
        if inside or _blocked(layout, near_xy, focus, cam_h, 1.0) or _in_clutter(layout, camera.position):
            continue
        # Prefer views where people and traffic can appear: enough route length in view.
        seen = sum(hi - lo for r in layout.routes
                   for lo, hi in [visible_interval(r.points, camera, max_dist=50.0) or (0.0, 0.0)])
        if seen >= 40.0:
            return camera, focus
        if best is None or seen > best[0]:
            best = (seen, camera, focus)
    if best is None:  # every try was inside a building: take the last view anyway
        return camera, focus
    return best[1], best[2]


# --- movers --------------------------------------------------------------------------------------

def _resample(points: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Points every ``step`` metres along a polyline and their arc lengths."""
    seg = np.diff(points, axis=0)
    seg_len = np.linalg.norm(seg, axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg_len)])
    s = np.arange(0.0, cum[-1], step)
    idx = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
    frac = (s - cum[idx]) / np.maximum(seg_len[idx], 1e-9)
    return points[idx] + seg[idx] * frac[:, None], s


def visible_interval(points: np.ndarray, camera: SynthCamera, max_dist: float = 80.0) -> tuple[float, float] | None:
    """Arc-length range of a route whose ground (or 1 m above it) projects inside the image."""
    pts, s = _resample(points, 0.5)
    if len(pts) == 0:
        return None
    ok = np.zeros(len(pts), bool)
    for z in (0.0, 1.0):
        world = np.column_stack([pts, np.full(len(pts), z)])
        uv, depth = camera.project(world)
        ok |= ((depth > 0.5) & (uv[:, 0] >= 0) & (uv[:, 0] < camera.width)
               & (uv[:, 1] >= 0) & (uv[:, 1] < camera.height))
    ok &= np.linalg.norm(pts - camera.position[:2], axis=1) < max_dist
    if not ok.any():
        return None
    return float(s[ok].min()), float(s[ok].max())


def _stature(rng: np.random.Generator) -> float:
    if rng.random() < 0.13:
        return float(rng.uniform(1.0, 1.45))
    return float(np.clip(rng.normal(1.71, 0.09), 1.5, 2.0))


def _directed(route: Route, rng: np.random.Generator) -> np.ndarray:
    if route.two_way and rng.random() < 0.5:
        return route.points[::-1].copy()
    return route.points.copy()


def _add_random_movers(layout: Layout, camera: SynthCamera, rng: np.random.Generator,
                       options: SequenceOptions, movers: list[Mover], skip_routes=()) -> None:
    duration = options.frames / options.fps
    next_id = max([m.id for m in movers], default=0) + 1
    by_kind: dict[str, list[tuple[np.ndarray, Route]]] = {"walk": [], "drive": [], "bike": []}
    for i, route in enumerate(layout.routes):
        if i in skip_routes:
            continue
        for pts in ([route.points, route.points[::-1]] if route.two_way else [route.points]):
            interval = visible_interval(pts, camera)
            if interval is not None:
                by_kind[route.kind].append((pts.copy(), route, interval))

    def start_arc(interval, speed):
        lo, hi = interval
        return float(rng.uniform(lo - speed * duration * 0.9, hi))

    # Pedestrians: singles, standing people and groups.
    n_ped = int(rng.integers(options.pedestrians[0], options.pedestrians[1] + 1))
    walks = by_kind["walk"]
    count = 0
    while walks and count < n_ped:
        pts, route, interval = walks[int(rng.integers(len(walks)))]
        group = int(rng.choice([1, 2, 3, 4], p=[0.72, 0.16, 0.08, 0.04]))
        standing = group == 1 and rng.random() < 0.15
        speed = 0.0 if standing else float(rng.uniform(0.9, 1.6))
        s0 = float(rng.uniform(*interval)) if standing else start_arc(interval, speed)
        lateral = float(rng.uniform(-route.width / 2, route.width / 2)) * 0.8
        for k in range(group):
            stature = _stature(rng)
            offset = float(np.clip(lateral + (k - (group - 1) / 2) * 0.65,
                                   -route.width / 2 - 0.3, route.width / 2 + 0.3))
            movers.append(make_pedestrian(next_id, rng, stature, pts, offset,
                                          speed * (1.0 if group == 1 else 0.85), s0 + rng.uniform(-0.4, 0.4),
                                          yaw0=float(rng.uniform(-math.pi, math.pi))))
            next_id += 1
            count += 1
    # Cyclists: bike lanes, else walking routes.
    n_bike = int(rng.integers(options.cyclists[0], options.cyclists[1] + 1))
    bikes = by_kind["bike"] or walks
    for _ in range(n_bike if bikes else 0):
        pts, route, interval = bikes[int(rng.integers(len(bikes)))]
        speed = float(rng.uniform(3.0, 6.5))
        movers.append(make_cyclist(next_id, rng, float(rng.uniform(1.6, 1.9)), pts,
                                   float(rng.uniform(-route.width / 2, route.width / 2)), speed,
                                   start_arc(interval, speed)))
        next_id += 1
    # Vehicles: per lane one speed and safe gaps, so they never run into each other.
    n_veh = int(rng.integers(options.vehicles[0], options.vehicles[1] + 1))
    lanes = by_kind["drive"]
    if lanes and n_veh:
        per_lane = np.bincount(rng.integers(len(lanes), size=n_veh), minlength=len(lanes))
        slow = layout.family == "parking_lot"
        for (pts, route, interval), n in zip(lanes, per_lane):
            if n == 0:
                continue
            speed = float(rng.uniform(2.0, 4.5) if slow else rng.uniform(6.0, 13.0))
            s = start_arc(interval, speed)
            prev_half = 0.0
            for _ in range(n):
                cls = str(rng.choice(["car", "van", "truck", "bus"], p=[0.72, 0.14, 0.07, 0.07]))
                if slow:
                    cls = "car" if rng.random() < 0.85 else "van"
                v = make_vehicle(next_id, cls, rng, car_colour(rng), pts, 0.0, speed, 0.0)
                s -= prev_half + v.length_m / 2 + float(rng.uniform(4.0, 20.0)) if prev_half else 0.0
                v.s0 = s
                prev_half = v.length_m / 2
                movers.append(v)
                next_id += 1


# --- the occlusion scenario ------------------------------------------------------------------

def _occlusion_scenario(layout: Layout, rng_cam, rng: np.random.Generator, width: int, height: int,
                        options: SequenceOptions):
    """A bus passes between the camera and a walking pedestrian, hiding them for ~2 s.

    The camera looks across a road running along x. It stands far enough back that the
    line of sight to the top of the pedestrian's head passes under the vehicle's roof at the
    vehicle's far side: (y_far - y_cam) / (y_ped - y_cam) >= (h - H_veh + margin) / (h - S).
    """
    y_road, half_road, walk = layout.crossing_roads[0]
    duration = options.frames / options.fps
    cam_h = options.camera_height_m or float(rng_cam.choice([3.5, 5.0, 6.4]))
    stature = float(np.clip(rng.normal(1.72, 0.07), 1.55, 1.9))
    veh_cls = "bus"  # a truck's lower cab and the gap behind it would let the head show
    L = layout.half_size + 40
    veh = make_vehicle(2, veh_cls, rng, car_colour(rng), np.zeros((2, 2)), 0.0, 1.0, 0.0)
    veh_w, veh_h = veh.width_m, veh.nominal_height_m
    lane_y = y_road - half_road / 2  # eastbound lane (drives +x) on the camera's side
    y_ped = y_road + half_road + walk / 2
    y_far = lane_y + veh_w / 2
    cab_h = veh_h - 0.05  # stay clear of the roof edge
    ratio = (cam_h - cab_h + 0.25) / (cam_h - stature)
    y_cam = (y_far - ratio * y_ped) / (1 - ratio) - float(rng_cam.uniform(1.0, 3.0))
    y_cam = min(y_cam, y_road - half_road - 1.0)
    x_cam = float(rng_cam.uniform(-1.5, 1.5))
    yaw = 90.0 + float(rng_cam.uniform(-12, 12))
    x_ped_mid = x_cam + (y_ped - y_cam) / math.tan(math.radians(yaw))
    pitch = float(np.clip(math.degrees(math.atan2(cam_h - 1.0, y_ped - y_cam)) + rng_cam.uniform(-2, 4),
                          *PITCH_RANGE_DEG))
    fov = float(rng_cam.uniform(50, 80))
    camera = make_camera(np.array([x_cam, y_cam, cam_h]), yaw, pitch, 0.0, fov, width, height)
    t_mid = duration * 0.5
    ped_speed = float(rng.uniform(1.0, 1.4))
    # Pedestrian walks +x along the far sidewalk, at x_ped_mid when t = t_mid.
    ped_route = np.array([[-L, y_ped], [L, y_ped]])
    ped = make_pedestrian(1, rng, stature, ped_route, 0.0, ped_speed, (x_ped_mid + L) - ped_speed * t_mid)
    # The vehicle's centre crosses the line of sight at t_mid.
    x_cross = x_cam + (x_ped_mid - x_cam) * (lane_y - y_cam) / (y_ped - y_cam)
    veh.route = np.array([[-L, lane_y], [L, lane_y]])
    # Slow enough that the pedestrian stays fully hidden ~2 s (the hidden span is about
    # the vehicle length minus the pedestrian's shadow on it, at the relative speed).
    veh.speed = float(np.clip((veh.length_m - 1.5) / rng.uniform(1.5, 1.9) + ped_speed * 0.5, 3.0, 7.0))
    veh_speed = veh.speed
    veh.s0 = (x_cross + L) - veh_speed * t_mid
    # Nothing static (trees, poles, bins) may hide the pedestrian: only the vehicle should.
    walked = [x_ped_mid - ped_speed * t_mid - 1.0, x_ped_mid + ped_speed * (duration - t_mid) + 1.0]
    _clear_view(layout, np.array([x_cam, y_cam]), [np.array([x, y_ped]) for x in walked])
    lane_index = next(i for i, r in enumerate(layout.routes)
                      if r.kind in ("drive", "bike") and abs(r.points[0, 1] - lane_y) < 1.5
                      and r.points[-1, 0] > r.points[0, 0])
    reserved = [i for i, r in enumerate(layout.routes)
                if r.kind in ("drive", "bike") and abs(r.points[0, 1] - lane_y) < half_road]
    reserved.append(lane_index)
    notes = {"occluded_id": 1, "occluder_id": 2, "occlusion_mid_s": t_mid, "reserved_routes": reserved}
    return camera, np.array([x_ped_mid, y_ped]), [ped, veh], notes


def _clear_view(layout: Layout, eye: np.ndarray, targets: list[np.ndarray], margin: float = 3.5) -> None:
    """Drop static clutter near the triangle between the camera and a stretch of pavement."""
    a, b, c = eye, targets[0], targets[1]

    def cross(u, v):
        return float(u[0] * v[1] - u[1] * v[0])

    def inside(p):
        d1 = cross(b - a, p - a)
        d2 = cross(c - b, p - b)
        d3 = cross(a - c, p - c)
        return not ((min(d1, d2, d3) < 0) and (max(d1, d2, d3) > 0))

    def near(p):
        return inside(p) or min(_segment_distance(p, u, v) for u, v in ((a, b), (b, c), (c, a))) < margin

    keep = []
    for prim in layout.prims:
        clutter = prim.cls in ("vegetation", "pole", "furniture", "wall", "parked_vehicle")
        if not (clutter and near(np.array(prim.pos[:2]))):
            keep.append(prim)
    layout.prims = keep
    layout.lamps = [lamp for lamp in layout.lamps if not near(np.array(lamp[:2]))]


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    ab = b - a
    t = float(np.clip(np.dot(p - a, ab) / max(np.dot(ab, ab), 1e-9), 0.0, 1.0))
    return float(np.linalg.norm(a + t * ab - p))
