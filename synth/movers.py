"""Movers: pedestrians with walking legs and arms, cyclists, cars, vans, trucks and buses.

Each mover is a few rigid parts; every part is its own MuJoCo mocap body whose world pose is
computed here for a time t. Legs and arms are separate parts so the silhouette and the top
of the head move as in real gait: the hip drops ~4 cm at each double support, so the
apparent height oscillates at twice the step frequency (the true height per frame is
reported, not just the stature).

Movers travel along a layout route at constant speed; before their start and after the
route's end they are absent (``poses`` returns None), which is how they enter and leave view.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

MOVER_CLASSES = ("pedestrian", "cyclist", "car", "van", "truck", "bus")


# --- quaternions (w, x, y, z), MuJoCo's order ------------------------------------------------

def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return np.array([aw * bw - ax * bx - ay * by - az * bz,
                     aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw])


def quat_axis(axis: tuple[float, float, float], angle: float) -> np.ndarray:
    s = math.sin(angle / 2)
    return np.array([math.cos(angle / 2), axis[0] * s, axis[1] * s, axis[2] * s])


def quat_yaw(yaw: float) -> np.ndarray:
    return quat_axis((0.0, 0.0, 1.0), yaw)


def quat_pitch(beta: float) -> np.ndarray:
    """Rotation about the local y (lateral) axis; beta < 0 swings a hanging limb forward."""
    return quat_axis((0.0, 1.0, 0.0), beta)


IDENTITY = (1.0, 0.0, 0.0, 0.0)
WHEEL_QUAT = tuple(quat_axis((1.0, 0.0, 0.0), math.pi / 2))  # cylinder axis along y


@dataclass
class Geom:
    """One geom in its part's local frame (x forward, y left, z up)."""

    kind: str
    pos: tuple[float, float, float]
    size: tuple[float, ...]
    rgba: tuple[float, float, float, float]
    quat: tuple[float, float, float, float] = IDENTITY
    fromto: tuple[float, ...] | None = None
    light: str = ""
    """'head' / 'tail' for vehicle lamps that glow at night."""
    finish: str = "matte"
    """'matte', 'paint' or 'glass': how shiny the surface is."""


@dataclass
class Mover:
    """Data shared by all mover kinds; subclasses implement ``part_poses``."""

    id: int
    cls: str
    nominal_height_m: float
    route: np.ndarray  # (k, 2) polyline, already in travel direction
    offset_m: float  # lateral offset from the route (left positive)
    speed: float  # m/s
    s0: float  # arc length at t = 0 (may be negative: enters later)
    parts: list[list[Geom]] = field(default_factory=list)
    length_m: float = 0.5
    width_m: float = 0.5
    yaw0: float = 0.0  # heading for standing pedestrians

    def _cumulative(self) -> np.ndarray:
        return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(self.route, axis=0), axis=1))])

    def arc(self, t: float) -> float:
        return self.s0 + self.speed * t

    def present(self, t: float) -> bool:
        s = self.arc(t)
        return 0.0 <= s <= self._cumulative()[-1]

    def ground_pose(self, t: float) -> tuple[np.ndarray, float]:
        """(x, y) of the mover's ground centre and its heading at time t."""
        cum = self._cumulative()
        s = float(np.clip(self.arc(t), 0.0, cum[-1]))
        i = int(np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(self.route) - 2))
        a, b = self.route[i], self.route[i + 1]
        seg = b - a
        seg_len = max(float(np.linalg.norm(seg)), 1e-9)
        direction = seg / seg_len
        left = np.array([-direction[1], direction[0]])
        xy = a + direction * (s - cum[i]) + left * self.offset_m
        yaw = math.atan2(direction[1], direction[0]) if self.speed > 0 else self.yaw0
        return xy, yaw

    def poses(self, t: float) -> list[tuple[np.ndarray, np.ndarray]] | None:
        """World (pos, quat) of every part at time t, or None when absent."""
        if not self.present(t):
            return None
        xy, yaw = self.ground_pose(t)
        return self.part_poses(t, xy, yaw)

    def part_poses(self, t, xy, yaw):  # pragma: no cover - abstract
        raise NotImplementedError


def _place(xy: np.ndarray, yaw: float, local: np.ndarray) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([xy[0] + c * local[0] - s * local[1], xy[1] + s * local[0] + c * local[1], local[2]])


# --- pedestrians -------------------------------------------------------------------------------

SKIN = [(0.95, 0.8, 0.68), (0.87, 0.68, 0.52), (0.72, 0.52, 0.38), (0.5, 0.35, 0.25), (0.35, 0.24, 0.17)]
HAIR = [(0.08, 0.06, 0.05), (0.3, 0.2, 0.1), (0.6, 0.45, 0.25), (0.55, 0.55, 0.55), (0.85, 0.75, 0.5)]


def _clothes(rng: np.random.Generator) -> tuple[float, float, float, float]:
    if rng.random() < 0.4:  # dark or grey clothes are common
        g = rng.uniform(0.08, 0.5)
        return (g, g, g * rng.uniform(0.9, 1.15), 1.0)
    return (*rng.uniform(0.1, 0.95, 3).tolist(), 1.0)


@dataclass
class Pedestrian(Mover):
    leg_length: float = 0.9
    thigh_length: float = 0.42
    hip_half_width: float = 0.09
    shoulder_half_width: float = 0.2
    shoulder_height: float = 0.5  # above the hip
    step_length: float = 0.7
    swing_amplitude: float = 0.4
    phase0: float = 0.0

    def part_poses(self, t, xy, yaw):
        phase = self.phase0 + (math.pi * self.arc(t) / self.step_length if self.speed > 0 else 0.0)
        amplitude = self.swing_amplitude if self.speed > 0 else 0.0
        # Per leg: hip angle (forward positive) and knee flexion, which peaks mid-swing
        # (while the leg moves forward) and is ~0 in stance.
        legs = []
        for leg_phase in (phase, phase + math.pi):
            hip_angle = amplitude * math.sin(leg_phase)
            knee = 1.1 * (amplitude / 0.4) * max(0.0, math.cos(leg_phase)) ** 1.5
            legs.append((hip_angle, knee))
        stance = min(legs, key=lambda hk: hk[1])[0]
        # A rigid stance leg would drop the hip by L(1 - cos theta); real gait about half that.
        hip_z = self.leg_length - 0.55 * self.leg_length * (1.0 - math.cos(stance))
        q_yaw = quat_yaw(yaw)
        poses = [(_place(xy, yaw, np.array([0.0, 0.0, hip_z])), q_yaw)]
        for side, (hip_angle, knee) in zip((1, -1), legs):
            joint = np.array([0.0, side * self.hip_half_width, hip_z])
            thigh_dir = np.array([math.sin(hip_angle), 0.0, -math.cos(hip_angle)])
            knee_pos = joint + thigh_dir * self.thigh_length
            poses.append((_place(xy, yaw, joint), quat_mul(q_yaw, quat_pitch(-hip_angle))))
            poses.append((_place(xy, yaw, knee_pos), quat_mul(q_yaw, quat_pitch(-(hip_angle - knee)))))
        arm_swing = 0.8 * amplitude * math.sin(phase)
        for side, swing in ((1, -arm_swing), (-1, arm_swing)):
            joint = _place(xy, yaw, np.array([0.0, side * self.shoulder_half_width, hip_z + self.shoulder_height]))
            poses.append((joint, quat_mul(q_yaw, quat_pitch(-swing))))
        return poses


def make_pedestrian(mover_id: int, rng: np.random.Generator, stature: float, route, offset, speed,
                    s0, yaw0=0.0) -> Pedestrian:
    """A pedestrian whose top (hair or hat) is exactly ``stature`` when standing upright."""
    child = stature < 1.45
    k = stature / 1.75
    build = rng.uniform(0.85, 1.2)
    head_h = stature * (0.155 if child else 0.13)
    leg = stature * (0.47 if child else 0.52)
    thigh = 0.47 * leg
    shoulder_z = stature * (0.8 if child else 0.82)
    torso_hw = 0.17 * k * build
    torso_d = 0.1 * k * build
    arm_r, leg_r = 0.045 * k * build, 0.065 * k * build
    skin = (*SKIN[int(rng.integers(len(SKIN)))], 1.0)
    hair = (*HAIR[int(rng.integers(len(HAIR)))], 1.0)
    shirt, trousers = _clothes(rng), _clothes(rng)
    shoes = (*(np.array([0.1, 0.08, 0.07]) + rng.uniform(0, 0.5) * rng.random(3)).tolist(), 1.0)
    hx, hy, hz = 0.36 * head_h, 0.32 * head_h, 0.5 * head_h
    top = stature - leg  # relative to the hip
    hair_z = top - 1.04 * hz
    upper = [
        Geom("box", (0.0, 0.0, (shoulder_z - leg) / 2 - 0.02), (torso_d, torso_hw, (shoulder_z - leg) / 2 + 0.04), shirt),
        Geom("capsule", (0, 0, 0), (torso_d,), shirt,
             fromto=(0.0, -torso_hw + 0.05, shoulder_z - leg - 0.03, 0.0, torso_hw - 0.05, shoulder_z - leg - 0.03)),
        Geom("cylinder", (0.0, 0.0, shoulder_z - leg + 0.04), (0.045 * k, 0.05), skin),
        Geom("ellipsoid", (0.0, 0.0, hair_z - 0.015), (hx, hy, hz), skin),
    ]
    headwear = rng.random()
    if headwear < 0.1 and not child:  # cap with a brim
        cap = _clothes(rng)
        upper += [Geom("ellipsoid", (-0.005, 0.0, top - 0.55 * hz), (1.07 * hx, 1.07 * hy, 0.55 * hz), cap),
                  Geom("box", (hx * 0.9, 0.0, top - 0.5 * hz), (0.45 * hx, 0.8 * hy, 0.012), cap)]
    elif headwear < 0.18:  # beanie or hood
        upper.append(Geom("ellipsoid", (-0.01, 0.0, hair_z), (1.1 * hx, 1.1 * hy, 1.04 * hz), _clothes(rng)))
    else:
        upper.append(Geom("ellipsoid", (-0.012, 0.0, hair_z), (1.06 * hx, 1.06 * hy, 1.04 * hz), hair))
    garment = rng.random()
    if garment < 0.22 and not child:  # long coat over the thighs
        coat = _clothes(rng)
        low = -0.28 * leg
        upper.append(Geom("box", (0.0, 0.0, (low + shoulder_z - leg - 0.04) / 2),
                          (torso_d + 0.02, torso_hw + 0.015, (shoulder_z - leg - 0.04 - low) / 2), coat))
        shirt = coat
    elif garment < 0.32:  # skirt or dress
        upper.append(Geom("cylinder", (0.0, 0.0, -0.16 * leg), (torso_hw * 0.95, 0.2 * leg), trousers))
    if rng.random() < 0.3 and not child:
        bag = _clothes(rng)
        upper.append(Geom("box", (-torso_d - 0.08, 0.0, (shoulder_z - leg) * 0.6), (0.08, 0.14 * k, 0.18 * k), bag))
    elif rng.random() < 0.2 and not child:  # hand or shopping bag at the side
        bag = _clothes(rng)
        upper.append(Geom("box", (0.0, (torso_hw + 0.09) * (1 if rng.random() < 0.5 else -1), -0.12 * leg),
                          (0.12, 0.04, 0.15), bag))
    shin = leg - thigh
    legs = []
    for _ in range(2):
        legs.append([Geom("capsule", (0, 0, 0), (leg_r,), trousers, fromto=(0.0, 0.0, 0.0, 0.0, 0.0, -thigh))])
        legs.append([Geom("capsule", (0, 0, 0), (leg_r * 0.85,), trousers,
                          fromto=(0.0, 0.0, 0.0, 0.0, 0.0, -(shin - leg_r * 0.85))),
                     Geom("box", (0.05 * k, 0.0, -(shin - 0.035 * k)), (0.12 * k, 0.05 * k, 0.035 * k), shoes)])
    arms = []
    arm_len = 0.38 * stature
    upper_arm = (arm_len - 2 * arm_r) * 0.55
    elbow = float(rng.uniform(0.1, 0.45))
    hand = np.array([math.sin(elbow), 0.0, -math.cos(elbow)]) * (arm_len - upper_arm - arm_r)
    for _ in range(2):
        arms.append([Geom("capsule", (0, 0, 0), (arm_r,), shirt, fromto=(0.0, 0.0, 0.0, 0.0, 0.0, -upper_arm)),
                     Geom("capsule", (0, 0, 0), (arm_r * 0.9,), shirt if rng.random() < 0.6 else skin,
                          fromto=(0.0, 0.0, -upper_arm, hand[0], 0.0, -upper_arm + hand[2]))])
    step = 0.41 * stature * float(np.clip(math.sqrt(max(speed, 0.1) / 1.35), 0.75, 1.2))
    return Pedestrian(
        id=mover_id, cls="pedestrian", nominal_height_m=stature, route=route, offset_m=offset,
        speed=speed, s0=s0, parts=[upper, legs[0], legs[1], legs[2], legs[3], arms[0], arms[1]],
        length_m=0.35, width_m=2 * torso_hw + 4 * arm_r, yaw0=yaw0,
        leg_length=leg, thigh_length=thigh, hip_half_width=0.09 * k, shoulder_half_width=torso_hw + arm_r,
        shoulder_height=shoulder_z - leg - 0.06, step_length=step,
        swing_amplitude=math.asin(min(0.9, step / (2 * leg))), phase0=float(rng.uniform(0, 2 * math.pi)))


# --- cyclists ----------------------------------------------------------------------------------

@dataclass
class Cyclist(Mover):
    hip: tuple[float, float, float] = (-0.15, 0.0, 0.95)
    thigh: float = 0.47
    shin: float = 0.47
    wheel_radius: float = 0.34
    phase0: float = 0.0

    def part_poses(self, t, xy, yaw):
        q_yaw = quat_yaw(yaw)
        poses = [(np.array([xy[0], xy[1], 0.0]), q_yaw)]
        crank = self.phase0 + self.arc(t) / self.wheel_radius / 2.5
        hip = np.array(self.hip)
        for side, offset in ((1, 0.0), (-1, math.pi)):
            angle = crank + offset
            foot = np.array([0.17 * math.cos(angle), side * 0.12, 0.3 + 0.17 * math.sin(angle)])
            h = hip + np.array([0.0, side * 0.1, 0.0])
            knee = _knee(h, foot, self.thigh, self.shin)
            for start, end in ((h, knee), (knee, foot)):
                d = end - start
                beta = math.atan2(-d[0], -d[2])
                poses.append((_place(xy, yaw, start), quat_mul(q_yaw, quat_pitch(beta))))
        return poses


def _knee(hip: np.ndarray, foot: np.ndarray, a: float, b: float) -> np.ndarray:
    """Two-bone IK in the sagittal (x-z) plane with the knee pointing forward."""
    d = foot - hip
    dist = float(np.clip(math.hypot(d[0], d[2]), abs(a - b) + 1e-6, a + b - 1e-6))
    along = (a * a - b * b + dist * dist) / (2 * dist)
    up = math.sqrt(max(a * a - along * along, 0.0))
    ux, uz = d[0] / dist, d[2] / dist
    # Perpendicular in the x-z plane on the forward side.
    px, pz = -uz, ux
    if px < 0:
        px, pz = -px, -pz
    return np.array([hip[0] + ux * along + px * up, hip[1] + d[1] * along / dist, hip[2] + uz * along + pz * up])


def make_cyclist(mover_id: int, rng: np.random.Generator, top_height: float, route, offset, speed,
                 s0) -> Cyclist:
    wheel = float(rng.uniform(0.32, 0.36))
    frame_c = (*rng.uniform(0.05, 0.9, 3).tolist(), 1.0)
    dark = (0.08, 0.08, 0.08, 1.0)
    shirt, trousers = _clothes(rng), _clothes(rng)
    skin = (*SKIN[int(rng.integers(len(SKIN)))], 1.0)
    helmet = (*rng.uniform(0.1, 0.95, 3).tolist(), 1.0) if rng.random() < 0.6 else \
        (*HAIR[int(rng.integers(len(HAIR)))], 1.0)
    hip_z = float(rng.uniform(0.92, 1.02))
    hip = np.array([-0.15, 0.0, hip_z])
    lean = math.radians(float(rng.uniform(15, 35)))
    hz = 0.12
    # top = shoulder_z + 0.05 + 2*hz  ->  torso length from the target height
    torso = float(np.clip((top_height - hip_z - 0.05 - 2 * hz) / math.cos(lean), 0.35, 0.8))
    shoulder = hip + torso * np.array([math.sin(lean), 0.0, math.cos(lean)])
    head = shoulder + np.array([0.06, 0.0, 0.05 + hz])
    grip_z = float(min(shoulder[2] - 0.15, 1.05))
    bike = [
        Geom("cylinder", (0.53, 0.0, wheel), (wheel, 0.02), dark, WHEEL_QUAT),
        Geom("cylinder", (-0.53, 0.0, wheel), (wheel, 0.02), dark, WHEEL_QUAT),
        Geom("capsule", (0, 0, 0), (0.022,), frame_c, fromto=(-0.53, 0, wheel, 0.0, 0, 0.3)),
        Geom("capsule", (0, 0, 0), (0.022,), frame_c, fromto=(0.0, 0, 0.3, -0.15, 0, hip_z - 0.08)),
        Geom("capsule", (0, 0, 0), (0.022,), frame_c, fromto=(-0.15, 0, hip_z - 0.08, 0.42, 0, hip_z - 0.1)),
        Geom("capsule", (0, 0, 0), (0.022,), frame_c, fromto=(0.0, 0, 0.3, 0.42, 0, hip_z - 0.1)),
        Geom("capsule", (0, 0, 0), (0.022,), frame_c, fromto=(0.42, 0, grip_z, 0.53, 0, wheel)),
        Geom("capsule", (0, 0, 0), (0.018,), dark, fromto=(0.42, -0.24, grip_z, 0.42, 0.24, grip_z)),
        Geom("box", (-0.17, 0.0, hip_z - 0.04), (0.12, 0.06, 0.03), dark),
        # Rider: torso, head, arms to the handlebar.
        Geom("capsule", (0, 0, 0), (0.14,), shirt, fromto=(*hip + [0, 0, 0.1], *shoulder - [0.03, 0, 0.06])),
        Geom("ellipsoid", tuple(head - [0, 0, 0.01]), (0.1, 0.085, hz - 0.01), skin),
        Geom("ellipsoid", tuple(head + [-0.01, 0, 0.0]), (0.11, 0.095, hz), helmet),
    ]
    for side in (1, -1):
        bike.append(Geom("capsule", (0, 0, 0), (0.045,), shirt,
                         fromto=(*shoulder + [0, side * 0.17, 0], 0.42, side * 0.22, grip_z)))
    legs = []
    for _ in range(2):
        legs.append([Geom("capsule", (0, 0, 0), (0.07,), trousers, fromto=(0, 0, 0, 0, 0, -0.47))])
        legs.append([Geom("capsule", (0, 0, 0), (0.055,), trousers, fromto=(0, 0, 0, 0, 0, -0.47)),
                     Geom("box", (0.05, 0, -0.47), (0.1, 0.045, 0.035), dark)])
    return Cyclist(id=mover_id, cls="cyclist", nominal_height_m=float(head[2] + hz), route=route,
                   offset_m=offset, speed=speed, s0=s0, parts=[bike] + legs, length_m=1.75, width_m=0.6,
                   hip=tuple(hip), wheel_radius=wheel, phase0=float(rng.uniform(0, 2 * math.pi)))


# --- vehicles ----------------------------------------------------------------------------------

VEHICLE_SIZE = {  # length, width, height ranges in metres
    "car": ((3.9, 4.8), (1.7, 1.9), (1.4, 1.6)),
    "van": ((4.8, 5.8), (1.9, 2.05), (1.9, 2.4)),
    "truck": ((7.0, 10.0), (2.4, 2.55), (2.8, 4.0)),
    "bus": ((10.0, 12.5), (2.5, 2.55), (2.9, 3.6)),
}


def vehicle_geoms(cls: str, rng: np.random.Generator, colour) -> tuple[list[Geom], tuple[float, float, float]]:
    """Box-and-cylinder vehicle in its local frame (origin on the ground at its centre)."""
    (l0, l1), (w0, w1), (h0, h1) = VEHICLE_SIZE[cls]
    L, W, H = float(rng.uniform(l0, l1)), float(rng.uniform(w0, w1)), float(rng.uniform(h0, h1))
    glass = (0.1, 0.13, 0.17, 1.0)
    dark = (0.06, 0.06, 0.06, 1.0)
    colour = tuple(colour)
    head = (0.95, 0.95, 0.85, 1.0)
    tail = (0.7, 0.05, 0.05, 1.0)
    g: list[Geom] = []
    if cls == "car":
        r = float(rng.uniform(0.3, 0.34))
        belt = 0.52 * H + 0.12
        g.append(Geom("box", (0.0, 0.0, (0.28 + belt) / 2), (L / 2, W / 2, (belt - 0.28) / 2), colour, finish="paint"))
        cab_l = L * float(rng.uniform(0.45, 0.55))
        cab_x = -L * float(rng.uniform(0.02, 0.1))
        g.append(Geom("box", (cab_x, 0.0, (belt + H - 0.04) / 2), (cab_l / 2, W / 2 - 0.08, (H - 0.04 - belt) / 2), glass, finish="glass"))
        g.append(Geom("box", (cab_x, 0.0, H - 0.02), (cab_l / 2 - 0.1, W / 2 - 0.12, 0.02), colour, finish="paint"))
        lamp_z, wheel_x = belt - 0.12, (L / 2 - 0.8)
        wheels = [(wheel_x, s) for s in (-1, 1)] + [(-wheel_x, s) for s in (-1, 1)]
    elif cls == "van":
        r = 0.35
        g.append(Geom("box", (0.0, 0.0, (0.32 + H) / 2), (L / 2, W / 2, (H - 0.32) / 2), colour, finish="paint"))
        g.append(Geom("box", (L / 2 - 0.55, 0.0, (1.15 + H - 0.2) / 2), (0.56, W / 2 + 0.01, (H - 0.2 - 1.15) / 2), glass, finish="glass"))
        lamp_z, wheel_x = 0.8, L / 2 - 0.9
        wheels = [(wheel_x, s) for s in (-1, 1)] + [(-wheel_x, s) for s in (-1, 1)]
    elif cls == "truck":
        r = 0.5
        cab_l, cab_h = 2.3, min(H, float(rng.uniform(2.6, 3.1)))
        g.append(Geom("box", (L / 2 - cab_l / 2, 0.0, (0.45 + cab_h) / 2), (cab_l / 2, W / 2 - 0.05, (cab_h - 0.45) / 2), colour, finish="paint"))
        g.append(Geom("box", (L / 2 - 0.3, 0.0, (1.5 + cab_h - 0.2) / 2), (0.31, W / 2 - 0.04, (cab_h - 0.2 - 1.5) / 2), glass, finish="glass"))
        cargo = (*rng.uniform(0.4, 0.95, 3).tolist(), 1.0)
        g.append(Geom("box", (-cab_l / 2 - 0.1, 0.0, (0.9 + H) / 2), ((L - cab_l - 0.2) / 2, W / 2, (H - 0.9) / 2), cargo, finish="paint"))
        g.append(Geom("box", (0.0, 0.0, 0.7), (L / 2 - 0.1, W / 2 - 0.3, 0.2), dark))
        lamp_z, wheel_x = 0.8, L / 2 - 1.2
        wheels = [(wheel_x, s) for s in (-1, 1)] + [(-wheel_x + dx, s) for s in (-1, 1) for dx in (0.0, 1.1)]
    elif cls == "bus":
        r = 0.5
        g.append(Geom("box", (0.0, 0.0, (0.35 + H) / 2), (L / 2, W / 2, (H - 0.35) / 2), colour, finish="paint"))
        g.append(Geom("box", (0.0, 0.0, (1.25 + H - 0.35) / 2), (L / 2 - 0.3, W / 2 + 0.01, (H - 0.35 - 1.25) / 2), glass, finish="glass"))
        g.append(Geom("box", (L / 2 - 0.05, 0.0, (1.0 + H - 0.3) / 2), (0.06, W / 2 - 0.1, (H - 0.3 - 1.0) / 2), glass, finish="glass"))
        lamp_z, wheel_x = 0.7, L / 2 - 2.4
        wheels = [(wheel_x, s) for s in (-1, 1)] + [(-wheel_x + 1.0, s) for s in (-1, 1)]
    else:
        raise ValueError(f"not a vehicle class: {cls!r}")
    for x, side in wheels:
        g.append(Geom("cylinder", (x, side * (W / 2 - 0.15), r), (r, 0.13), dark, WHEEL_QUAT))
    for side in (-1, 1):
        g.append(Geom("box", (L / 2 + 0.005, side * (W / 2 - 0.28), lamp_z), (0.02, 0.15, 0.06), head, light="head"))
        g.append(Geom("box", (-L / 2 - 0.005, side * (W / 2 - 0.2), lamp_z), (0.02, 0.12, 0.06), tail, light="tail"))
    return g, (L, W, H)


@dataclass
class Vehicle(Mover):
    def part_poses(self, t, xy, yaw):
        return [(np.array([xy[0], xy[1], 0.0]), quat_yaw(yaw))]


def make_vehicle(mover_id: int, cls: str, rng: np.random.Generator, colour, route, offset, speed,
                 s0) -> Vehicle:
    geoms, (L, W, H) = vehicle_geoms(cls, rng, colour)
    return Vehicle(id=mover_id, cls=cls, nominal_height_m=H, route=route, offset_m=offset, speed=speed,
                   s0=s0, parts=[geoms], length_m=L, width_m=W)
