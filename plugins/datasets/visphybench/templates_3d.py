"""The 3D subset of the generated VisPhyBench: 12 templates, 30 scenes (ids ``NN_tmpl_VV``).

Like the paper's 3D subset (Three.js + Cannon): spheres rolling down ramps (wedges) into U-shaped
containers, boxes knocked off planks, sphere collisions, stacks toppling, a seesaw, compound
shapes falling, balls launched with an initial velocity. Every scene has a dynamic red sphere
``red_ball`` (the action ball, #f34f46) and uses the flat PHYRE palette (dynamic gray / green /
blue, static black / purple); a fixed perspective camera looks at the scene over a grey floor
under a white sky; 75 frames at 15 fps (4 cannon steps of 1/60 s per frame).

`Template.make(rng, variant)` is deterministic in its arguments: the variant picks the discrete
arrangement, the generator the continuous parameters (sizes, positions, speeds, materials).
Candidates are screened by `validity_problems_3d` and described by `difficulty_features_3d`.
Contact values are explicit for every pair that can touch (friction min(μa, μb), restitution
max(ea, eb) of the per-body values, written out so cannon's product rule is never used);
friction is in cannon-es units (see `_mat`: sliding boxes need μ of a few 1e-3).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from visphy_core.spec3d import (
    FLOOR_ID,
    IDENTITY_QUAT,
    PROFILE_3D,
    PROFILE_NAME,
    RED_RGB,
    bounding_radius,
    category_of_3d,
    local_hull_points,
    quat_from_axis_angle,
    shape_parts,
    transform_points_3d,
    validate_spec_3d,
)
from visphy_core.scene import SPEC_SCHEMA

try:  # share the dataclass with the 2D templates when they exist (and import cleanly)
    from visphy_plugins.datasets.visphybench.templates_2d import Template
except Exception:  # noqa: BLE001 - missing or mid-edit: an identical local dataclass
    @dataclass(frozen=True)
    class Template:  # type: ignore[no-redef]
        template_id: int
        family: str
        n_variants: int
        description: str
        make: Callable[[np.random.Generator, int], dict]

PALETTE_3D: dict[str, tuple[int, int, int]] = {
    "red": RED_RGB, "gray": (185, 202, 210), "green": (107, 206, 187), "blue": (24, 119, 242),
    "black": (0, 0, 0), "purple": (75, 74, 164), "white": (255, 255, 255),
}
FLOOR_RGB = (150, 150, 150)
FLOOR_MATERIAL = {"friction": 0.4, "restitution": 0.1}
G = 9.82
GAP = 0.002          # bodies resting on something start this far above it
QUAT_Y_PI = [0.0, 1.0, 0.0, 0.0]
K_SPHERE = 2.0 / 3.0  # cannon-es sphere inertia (AABB approximation): I = 2/3 m r²

# validity thresholds (MISSION §5 / the brief)
OVERLAP_M = 1e-3
MIN_MOTION_M = 0.05
FLOOR_TUNNEL_M = -0.05
REGION_M = 50.0
SPEED_CAP_M_S = 50.0
PERTURB_M = 1e-3
CHAOTIC_PX = 16.0
ROTATION_DEG = 30.0
REASONS = ("overlap", "offscreen", "static", "tunnelling", "speed_cap")


# ------------------------------------------------------------------------------ builders
def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


def _vec(v) -> list[float]:
    return [float(x) + 0.0 for x in v]


def make_body(bid: str, color: str, shape: dict, position, quat=IDENTITY_QUAT, *,
              dynamic: bool = True, velocity=(0.0, 0.0, 0.0), angular=(0.0, 0.0, 0.0),
              mass: float = 1.0, friction: float = 0.4, restitution: float = 0.15) -> dict:
    body: dict = {"id": bid, "category": "", "dynamic": dynamic,
                  "color_rgb": list(PALETTE_3D[color]), "shape": shape,
                  "pose": {"position_m": _vec(position), "quat": _vec(quat)}}
    if dynamic:
        body["velocity"] = {"linear_m_s": _vec(velocity), "angular_rad_s": _vec(angular)}
        body["material"] = {"mass_kg": round(float(mass), 4), "friction": round(float(friction), 6),
                            "restitution": round(float(restitution), 4)}
    else:
        body["material"] = {"friction": round(float(friction), 6),
                            "restitution": round(float(restitution), 4)}
    body["category"] = category_of_3d(body)
    return body


def sphere_shape(r: float) -> dict:
    return {"type": "sphere", "radius_m": float(r)}


def box_shape(sx: float, sy: float, sz: float) -> dict:
    return {"type": "box", "size_m": [float(sx), float(sy), float(sz)]}


def wedge_shape(length: float, height: float, width: float) -> dict:
    return {"type": "wedge", "length_m": float(length), "height_m": float(height),
            "width_m": float(width)}


def _centred_compound(parts: list[tuple[dict, list[float]]]) -> tuple[dict, np.ndarray]:
    """A compound of (primitive, offset) parts shifted so its volume centroid is the origin;
    returns the shape and the shift (old origin -> centroid)."""
    from visphy_core.spec3d import primitive_volume

    vols = np.array([primitive_volume(s) for s, _ in parts])
    offs = np.array([o for _, o in parts], dtype=np.float64)
    c = (vols[:, None] * offs).sum(axis=0) / vols.sum()
    shape = {"type": "compound", "parts": [
        {"shape": s, "offset_m": _vec(np.asarray(o) - c), "quat": list(IDENTITY_QUAT)}
        for s, o in parts]}
    return shape, c


def u_container_shape(inner: float, wall_h: float, depth: float, t: float = 0.06
                      ) -> tuple[dict, float]:
    """U container (base + two walls at ±x, open at the top); returns the shape and the height
    of its centroid above the base's underside."""
    half = inner / 2.0 + t / 2.0
    shape, c = _centred_compound([
        (box_shape(inner + 2 * t, t, depth), [0.0, t / 2.0, 0.0]),
        (box_shape(t, wall_h, depth), [-half, t + wall_h / 2.0, 0.0]),
        (box_shape(t, wall_h, depth), [half, t + wall_h / 2.0, 0.0])])
    return shape, float(c[1])


def _min_local_y(shape: dict, quat) -> float:
    """Lowest y of the shape rotated by quat (about its origin)."""
    pts = transform_points_3d(local_hull_points(shape, sphere_samples=0), list(
        [0.0, 0.0, 0.0]) + list(quat))
    low = pts[:, 1].min()
    for prim, off, _ in shape_parts(shape):  # spheres: exact lowest point
        if prim["type"] == "sphere":
            centre = transform_points_3d(off[None, :], [0.0, 0.0, 0.0] + list(quat))[0]
            low = min(low, centre[1] - prim["radius_m"])
    return float(low)


class Wedge:
    """A static ramp on a base height: slope descending towards ``d`` (+1: +x, -1: -x) with its
    toe (the slope's lowest edge) at ``toe_x``."""

    def __init__(self, length: float, height: float, width: float, toe_x: float, base_y: float,
                 d: int, z: float = 0.0):
        self.L, self.H, self.W, self.d, self.z = length, height, width, d, z
        self.cx = toe_x - d * 2.0 * length / 3.0
        self.cy = base_y + height / 3.0
        self.theta = math.atan2(height, length)
        self.normal = (d * math.sin(self.theta), math.cos(self.theta))  # outward slope normal

    def quat(self) -> list[float]:
        return list(IDENTITY_QUAT) if self.d > 0 else list(QUAT_Y_PI)

    def body(self, bid: str, color: str, friction: float = 0.4, restitution: float = 0.1) -> dict:
        return make_body(bid, color, wedge_shape(self.L, self.H, self.W),
                         [self.cx, self.cy, self.z], self.quat(), dynamic=False,
                         friction=friction, restitution=restitution)

    def slope_point(self, u: float) -> tuple[float, float]:
        """World (x, y) of the slope at u (0: top edge, 1: toe)."""
        x0, x1, y0, y1 = -self.L / 3, 2 * self.L / 3, -self.H / 3, 2 * self.H / 3
        lx, ly = x0 + u * (x1 - x0), y1 + u * (y0 - y1)
        return self.cx + self.d * lx, self.cy + ly

    def on_slope(self, u: float, r: float) -> list[float]:
        """Centre of a sphere of radius r resting on the slope at u (GAP above it)."""
        px, py = self.slope_point(u)
        return [px + (r + GAP) * self.normal[0], py + (r + GAP) * self.normal[1], self.z]

    def roll_speed(self, u: float) -> float:
        """Speed at the toe of a sphere rolling from u without slipping (cannon inertia)."""
        return math.sqrt(2 * G * (1 - u) * self.H / (1 + K_SPHERE))


def camera(rng: np.random.Generator, bodies: list[dict], fov: float = 45.0) -> dict:
    """A fixed perspective camera in front of the layout (looking along -z, slightly down),
    as close as the initial layout's x extent (plus a margin) allows."""
    lo, hi, top = math.inf, -math.inf, 0.0
    for b in bodies:
        pts = transform_points_3d(local_hull_points(b["shape"]),
                                  b["pose"]["position_m"] + b["pose"]["quat"])
        lo, hi = min(lo, pts[:, 0].min()), max(hi, pts[:, 0].max())
        top = max(top, pts[:, 1].max())
    half = max(abs(lo), abs(hi)) + 0.6
    dist = min(max(half / math.tan(math.radians(fov) / 2.0), 4.5), 9.5)
    look_y = min(max(0.35 * top, 0.5), 1.2)
    elev = math.radians(_u(rng, 12.0, 20.0))
    pos = [_u(rng, -0.3, 0.3), look_y + dist * math.sin(elev), dist * math.cos(elev)]
    return {"type": "perspective", "fov_deg": float(fov), "near": 0.1, "far": 100.0,
            "position": _vec(np.round(pos, 4)), "look_at": [0.0, round(look_y, 4), 0.0],
            "up": [0.0, 1.0, 0.0], "width": PROFILE_3D["width"], "height": PROFILE_3D["height"]}


def _contacts(bodies: list[dict]) -> dict:
    """Explicit contact values for every pair with a dynamic body (floor included): friction
    min(μa, μb) (the slipperier surface decides), restitution max(ea, eb)."""
    mats = [(b["id"], b["dynamic"], b["material"]) for b in bodies]
    mats.append((FLOOR_ID, False, FLOOR_MATERIAL))
    pairs = []
    for i, (a, dyn_a, ma) in enumerate(mats):
        for b, dyn_b, mb in mats[i + 1:]:
            if not (dyn_a or dyn_b):
                continue
            pairs.append({"a": a, "b": b,
                          "friction": round(min(ma["friction"], mb["friction"]), 6),
                          "restitution": round(max(ma["restitution"], mb["restitution"]), 4)})
    return {"default": {"friction": 0.4, "restitution": 0.1}, "pairs": pairs}


def centre_layout(bodies: list[dict], x_limit: float = 3.3) -> None:
    """Shift every body along x so the layout's x extent is centred on 0 (in place)."""
    lo, hi = math.inf, -math.inf
    for b in bodies:
        pose = b["pose"]["position_m"] + b["pose"]["quat"]
        pts = transform_points_3d(local_hull_points(b["shape"]), pose)
        lo, hi = min(lo, pts[:, 0].min()), max(hi, pts[:, 0].max())
    shift = -(lo + hi) / 2.0
    for b in bodies:
        b["pose"]["position_m"][0] = float(b["pose"]["position_m"][0] + shift)


def add_backstop(rng: np.random.Generator, bodies: list[dict], d: int,
                 name: str = "black_backstop", height: float = 0.3,
                 distance: tuple[float, float] = (0.6, 0.9)) -> None:
    """A static black plank lying across the floor beyond the layout in direction d, so what
    rolls away stops in view (in place)."""
    far = -math.inf
    for b in bodies:
        pts = transform_points_3d(local_hull_points(b["shape"]),
                                  b["pose"]["position_m"] + b["pose"]["quat"])
        far = max(far, float((d * pts[:, 0]).max()))
    bodies.append(make_body(name, "black", box_shape(0.15, height, 2.4),
                            [d * (far + _u(rng, *distance)), height / 2, 0.0], dynamic=False,
                            **_mat(rng, "static")))


def scene_3d(template_id: int, variant: int, family: str, description: str,
             bodies: list[dict], cam: dict) -> dict:
    """Wrap bodies into a `visphy-scene/1` 3D spec (ground truth still empty)."""
    p = PROFILE_3D
    return {
        "schema": SPEC_SCHEMA, "scene_id": f"{template_id:02d}_tmpl_{variant:02d}",
        "template_id": f"{template_id:02d}", "variant": int(variant),
        "seed": 0, "dim": "3d", "family": family, "description": description,
        "difficulty": {"label": "easy", "score": 0.0, "features": {}},
        "world": {
            "engine": p["engine"], "engine_version": p["engine_version"],
            "profile": PROFILE_NAME,
            "units": {"length": "m", "mass": "kg", "time": "s", "angles": "rad",
                      "up_axis": "y", "quaternion": "xyzw"},
            "gravity_m_s2": list(p["gravity_m_s2"]), "dt_s": p["dt_s"],
            "steps_per_frame": p["steps_per_frame"],
            "first_frame_after_steps": p["first_frame_after_steps"],
            "n_frames": p["n_frames"], "video_fps": p["video_fps"],
            "solver": {"type": "GSSolver", "iterations": 20, "tolerance": 1e-7},
            "broadphase": "naive",
            "contact_equation": {"stiffness": 1e7, "relaxation": 3.0},
            "friction_equation": {"stiffness": 1e7, "relaxation": 3.0},
            "damping": {"linear": 0.0, "angular": 0.01},
            "allow_sleep": False,
            "quat_normalize": {"skip": 0, "fast": False},
            "floor": {"y": 0.0, "color_rgb": list(FLOOR_RGB), "size_m": 60.0},
        },
        "camera": cam,
        "render": {
            "background_rgb": list(PALETTE_3D["white"]), "antialias": False,
            "material": "lambert", "shadows": True,
            "lighting": {
                "description": "white sky, grey floor; hemisphere light (white sky, grey "
                               "ground) plus one white directional light from above-front-right "
                               "casting shadows; flat Lambert colours",
                "hemisphere": {"sky_rgb": [255, 255, 255], "ground_rgb": [110, 110, 110],
                               "intensity": 2.0},
                "directional": {"color_rgb": [255, 255, 255], "intensity": 1.6,
                                "position": [3.0, 10.0, 6.0]},
            },
            "codec": "h264", "pix_fmt": "yuv420p",
        },
        "bodies": bodies,
        "contacts": _contacts(bodies),
        "ground_truth": {"trajectory": None, "events": [],
                         "identifiable": {"gravity": False, "initial_velocity": [],
                                          "restitution": [], "friction": [], "mass_ratio": []}},
        "digest_sha256": None,
    }


def _mat(rng: np.random.Generator, kind: str = "box") -> dict:
    """Per-body friction and restitution, in cannon-es units.

    cannon-es clamps each friction equation's *impulse per step* at μ g m_reduced (a force bound
    used as an impulse bound), and a face contact has up to four points, so a sliding box feels
    an effective Coulomb coefficient of about μ · 4 / dt = 240 μ at dt = 1/60 s (measured: a box
    on a 0.4 rad incline with μ = 0.0015 slides with μ_eff ≈ 0.35; μ = 0.02 never slides).
    Flat-faced bodies therefore get μ in [0.002, 0.004] (μ_eff ≈ 0.5-1 on a face, less on an
    edge), standing pieces that must topple [0.005, 0.008]; spheres, which
    touch at one point and mostly roll, and static scenery get ordinary values.
    """
    if kind == "sphere":
        return {"friction": _u(rng, 0.3, 0.5), "restitution": _u(rng, 0.05, 0.3)}
    if kind == "static":
        return {"friction": _u(rng, 0.3, 0.5), "restitution": _u(rng, 0.05, 0.25)}
    if kind == "grippy":  # standing pieces that must topple rather than slide
        return {"friction": _u(rng, 0.005, 0.008), "restitution": _u(rng, 0.05, 0.2)}
    return {"friction": _u(rng, 0.002, 0.004), "restitution": _u(rng, 0.05, 0.25)}


def red_ball(rng: np.random.Generator, position, r: float, velocity=(0.0, 0.0, 0.0),
             mass: float | None = None) -> dict:
    return make_body("red_ball", "red", sphere_shape(r), position, velocity=velocity,
                     mass=mass if mass is not None else _u(rng, 0.8, 2.0), **_mat(rng, "sphere"))


def _dir(rng: np.random.Generator) -> int:
    return 1 if rng.random() < 0.5 else -1


def _on_floor(shape: dict, x: float, z: float, quat=IDENTITY_QUAT) -> list[float]:
    return [x, -_min_local_y(shape, quat) + GAP, z]


def _rot_z(angle: float) -> list[float]:
    return quat_from_axis_angle([0, 0, 1], angle)


def _rot_y(angle: float) -> list[float]:
    return quat_from_axis_angle([0, 1, 0], angle)


def _random_quat(rng: np.random.Generator) -> list[float]:
    axis = rng.normal(size=3)
    return quat_from_axis_angle(axis, _u(rng, 0.0, math.pi))


# ------------------------------------------------------------------------------ templates
def _t01_ramp_to_container(rng: np.random.Generator, variant: int) -> dict:
    d = _dir(rng)
    table_h, table_l = _u(rng, 0.55, 0.8), _u(rng, 1.5, 1.8)
    table = make_body("purple_table", "purple", box_shape(table_l, table_h, 1.0),
                      [-d * table_l / 2, table_h / 2, 0.0], dynamic=False, **_mat(rng, "static"))
    ramp = Wedge(_u(rng, 0.9, 1.2), _u(rng, 0.45, 0.7), 0.7, 0.0, table_h, d)
    r, u = _u(rng, 0.14, 0.2), _u(rng, 0.05, 0.2)
    ball = red_ball(rng, ramp.on_slope(u, r), r)
    # where the ball lands (flies off the toe at the table's edge)
    v, th = ramp.roll_speed(u), ramp.theta
    x0, y0 = d * r * math.sin(th), table_h + r * math.cos(th)
    t_wall, inner, wall_h = 0.06, _u(rng, 0.8, 1.0), _u(rng, 0.28, 0.38)
    y_land = t_wall + r
    a, b_, c = 0.5 * G, v * math.sin(th), y_land - y0
    t_fly = (-b_ + math.sqrt(b_ * b_ - 4 * a * c)) / (2 * a)
    x_land = x0 + d * v * math.cos(th) * t_fly
    cx = x_land + d * _u(rng, -0.1, 0.15)
    near_outer = cx - d * (inner / 2 + t_wall)
    if d * near_outer < 0.08:
        cx += d * (0.08 - d * near_outer)
    shape, cy = u_container_shape(inner, wall_h, 0.8, t_wall)
    container = make_body("gray_container", "gray", shape, [cx, cy + GAP, 0.0],
                          mass=_u(rng, 1.5, 3.0), **_mat(rng))
    bodies = [ball, ramp.body("black_ramp", "black"), table, container]
    if variant == 2:
        rb = 0.12
        bodies.append(make_body("blue_ball", "blue", sphere_shape(rb),
                                [cx + d * (inner / 2 - rb - 0.03), t_wall + rb + 2 * GAP, 0.0],
                                mass=_u(rng, 0.3, 0.6), **_mat(rng, "sphere")))
    elif variant == 1:
        s = _u(rng, 0.25, 0.32)
        bodies.append(make_body("green_box", "green", box_shape(s, s, s),
                                _on_floor(box_shape(s, s, s), cx + d * (inner / 2 + 0.5), 0.0),
                                mass=_u(rng, 0.3, 0.8), **_mat(rng)))
    centre_layout(bodies)
    return scene_3d(1, variant, "ramp_container",
                    "a red ball rolls down a ramp on a table, flies off the edge and drops into "
                    "a gray U-shaped container", bodies, camera(rng, bodies))


def _t02_ramp_hits_box(rng: np.random.Generator, variant: int) -> dict:
    d = _dir(rng)
    ramp = Wedge(_u(rng, 1.4, 1.9), _u(rng, 0.7, 1.0), 1.0, 0.0, 0.0, d)
    r, u = _u(rng, 0.16, 0.22), _u(rng, 0.05, 0.15)
    bodies = [red_ball(rng, ramp.on_slope(u, r), r), ramp.body("black_ramp", "black")]
    x = d * _u(rng, 0.9, 1.4)
    s = _u(rng, 0.3, 0.4)
    cube = box_shape(s, s, s)
    bodies.append(make_body("green_box", "green", cube, _on_floor(cube, x, 0.0),
                            mass=_u(rng, 0.3, 0.8), **_mat(rng)))
    if variant == 1:
        s2 = _u(rng, 0.22, 0.3)
        top = box_shape(s2, s2, s2)
        bodies.append(make_body("gray_box", "gray", top, [x, s + GAP + s2 / 2 + GAP, 0.0],
                                mass=_u(rng, 0.2, 0.5), **_mat(rng)))
    elif variant == 2:
        rb = _u(rng, 0.15, 0.2)
        bodies.append(make_body("blue_ball", "blue", sphere_shape(rb),
                                [x + d * (s / 2 + rb + 0.3), rb + GAP, _u(rng, -0.15, 0.15)],
                                mass=_u(rng, 0.4, 1.0), **_mat(rng, "sphere")))
        bar = box_shape(0.12, 0.25, 2.4)
        bodies.append(make_body("black_bar", "black", bar,
                                [x + d * (s / 2 + 2 * rb + 1.0), 0.125, 0.0], dynamic=False,
                                **_mat(rng, "static")))
    if variant != 2:
        add_backstop(rng, bodies, d)
    centre_layout(bodies)
    return scene_3d(2, variant, "ramp_box",
                    "a red ball rolls down a ramp and knocks into a box on the floor",
                    bodies, camera(rng, bodies))


def _t03_plank_knockoff(rng: np.random.Generator, variant: int) -> dict:
    d = _dir(rng)
    h, lp = _u(rng, 0.7, 1.0), _u(rng, 3.0, 3.5)
    bodies = []
    for side, name in ((-1, "purple_pillar_left"), (1, "purple_pillar_right")):
        bodies.append(make_body(name, "purple", box_shape(0.3, h, 0.6),
                                [side * (lp / 2 - 0.35), h / 2, 0.0], dynamic=False,
                                **_mat(rng, "static")))
    bodies.append(make_body("black_plank", "black", box_shape(lp, 0.1, 0.7), [0.0, h + 0.05, 0.0],
                            dynamic=False, **_mat(rng, "static")))
    top = h + 0.1
    s = _u(rng, 0.26, 0.34)
    bx = d * (lp / 2 - s / 2 - _u(rng, 0.02, 0.12))
    cube = box_shape(s, s, s)
    bodies.append(make_body("green_box", "green", cube, [bx, top + s / 2 + GAP, 0.0],
                            mass=_u(rng, 0.2, 0.6), **_mat(rng)))
    if variant == 1:
        s2 = _u(rng, 0.2, 0.26)
        bodies.append(make_body("gray_box", "gray", box_shape(s2, s2, s2),
                                [bx, top + s + 2 * GAP + s2 / 2 + GAP, 0.0],
                                mass=_u(rng, 0.1, 0.4), **_mat(rng)))
    elif variant == 2:
        rb = _u(rng, 0.12, 0.16)
        bodies.append(make_body("blue_ball", "blue", sphere_shape(rb),
                                [_u(rng, -0.3, 0.3), top + rb + GAP, 0.0],
                                mass=_u(rng, 0.3, 0.8), **_mat(rng, "sphere")))
    r = _u(rng, 0.15, 0.2)
    bodies.insert(0, red_ball(rng, [-d * (lp / 2 - 0.3), top + r + GAP, 0.0], r,
                              velocity=(d * _u(rng, 3.5, 5.0), 0.0, 0.0),
                              mass=_u(rng, 1.5, 3.0)))
    add_backstop(rng, bodies, d, height=0.8, distance=(1.1, 1.4))
    return scene_3d(3, variant, "plank_knockoff",
                    "a red ball rolls along a raised plank and knocks a box off its end",
                    bodies, camera(rng, bodies))


def _t04_sphere_collision(rng: np.random.Generator, variant: int) -> dict:
    d = _dir(rng)
    r = _u(rng, 0.2, 0.26)
    tx = d * _u(rng, 0.1, 0.6)
    targets = []
    n = variant + 1
    colors = ["blue", "green", "gray"]
    rt = _u(rng, 0.18, 0.24)
    if n == 1:
        spots = [(tx, _u(rng, -0.3, 0.3))]
    elif n == 2:
        z = _u(rng, -0.2, 0.2)
        spots = [(tx, z), (tx + d * (2 * rt + _u(rng, 0.3, 0.6)), z + _u(rng, -0.2, 0.2))]
    else:
        z = _u(rng, -0.15, 0.15)
        dx = rt * math.sqrt(3) + 0.02
        spots = [(tx, z), (tx + d * dx, z - rt - 0.01), (tx + d * dx, z + rt + 0.01)]
    for i, (x, z) in enumerate(spots):
        targets.append(make_body(f"{colors[i]}_ball", colors[i], sphere_shape(rt),
                                 [x, rt + GAP, z], mass=_u(rng, 0.5, 1.5), **_mat(rng, "sphere")))
    x0, z0 = -d * _u(rng, 1.6, 2.0), _u(rng, -0.4, 0.4)
    vx = d * _u(rng, 3.5, 5.0)
    t_hit = abs(spots[0][0] - x0) / abs(vx)
    vz = (spots[0][1] + _u(rng, -0.08, 0.08) - z0) / t_hit
    bodies = [red_ball(rng, [x0, r + GAP, z0], r, velocity=(vx, 0.0, vz))] + targets
    bodies.append(make_body("black_bumper", "black", box_shape(0.15, 0.3, 3.0),
                            [d * 2.5, 0.15, 0.0], dynamic=False, **_mat(rng, "static")))
    return scene_3d(4, variant, "sphere_collision",
                    "a red ball launched along the floor collides with other balls",
                    bodies, camera(rng, bodies))


def _t05_stack_topple(rng: np.random.Generator, variant: int) -> dict:
    d = _dir(rng)
    tx = d * _u(rng, 0.6, 1.1)
    n = 4 if variant == 1 else 3
    colors = ["gray", "green", "blue", "gray"]
    bodies, y = [], 0.0
    sizes = sorted((_u(rng, 0.3, 0.42) for _ in range(n)), reverse=True)
    for i, s in enumerate(sizes):
        y += GAP
        q = _rot_y(_u(rng, -0.15, 0.15))
        bodies.append(make_body(f"{colors[i]}_box_{i}", colors[i], box_shape(s, s, s),
                                [tx + _u(rng, -0.02, 0.02), y + s / 2, _u(rng, -0.02, 0.02)], q,
                                mass=_u(rng, 0.3, 0.8), **_mat(rng)))
        y += s
    r = _u(rng, 0.17, 0.22)
    if variant == 0:  # a big fast ball rolling along the floor
        r = _u(rng, 0.26, 0.3)
        x0 = -d * _u(rng, 2.0, 2.5)
        ball = red_ball(rng, [x0, r + GAP, 0.0], r, velocity=(d * _u(rng, 5.5, 7.0), 0.0, 0.0),
                        mass=_u(rng, 2.0, 3.0))
    elif variant == 1:
        x0, y0 = -d * _u(rng, 2.2, 2.6), _u(rng, 0.4, 0.8)
        t = _u(rng, 0.5, 0.7)
        ty = y - sizes[-1] / 2
        ball = red_ball(rng, [x0, y0, 0.0], r,
                        velocity=((tx - x0) / t, (ty - y0 + 0.5 * G * t * t) / t, 0.0))
    else:
        ramp = Wedge(_u(rng, 1.2, 1.5), _u(rng, 0.6, 0.8), 0.9, tx - d * _u(rng, 0.9, 1.2), 0.0, d)
        ball = red_ball(rng, ramp.on_slope(_u(rng, 0.05, 0.15), r), r)
        bodies.append(ramp.body("black_ramp", "black"))
    add_backstop(rng, bodies, d)
    bodies.insert(0, ball)
    centre_layout(bodies)
    return scene_3d(5, variant, "stack_topple",
                    "a red ball hits a stack of boxes and topples it", bodies, camera(rng, bodies))


def _t06_seesaw(rng: np.random.Generator, variant: int) -> dict:
    d = _dir(rng)
    hf, lw = _u(rng, 0.3, 0.4), 0.4
    fulcrum = make_body("purple_fulcrum", "purple", wedge_shape(lw, hf, 0.6),
                        [d * lw / 3, hf / 3, 0.0], IDENTITY_QUAT if d > 0 else QUAT_Y_PI,
                        dynamic=False, **_mat(rng, "static"))
    lp, t = _u(rng, 2.6, 3.1), 0.08
    s_e = _u(rng, -0.15, 0.15)
    alpha = math.asin(hf / (s_e + lp / 2))
    u = np.array([d * math.cos(alpha), math.sin(alpha), 0.0])
    nrm = np.array([-d * math.sin(alpha), math.cos(alpha), 0.0])
    c = np.array([0.0, hf, 0.0]) + (t / 2 + GAP) * nrm - s_e * u
    q = _rot_z(d * alpha)
    plank = make_body("blue_plank", "blue", box_shape(lp, t, 0.5), c, q,
                      mass=_u(rng, 1.0, 1.6), **_mat(rng, "grippy"))
    sb = _u(rng, 0.24, 0.3)
    s_box = -(lp / 2 - sb / 2 - 0.08)
    box_c = c + s_box * u + (t / 2 + sb / 2 + GAP) * nrm
    bodies = [fulcrum, plank,
              make_body("green_box", "green", box_shape(sb, sb, sb), box_c, q,
                        mass=_u(rng, 0.2, 0.5), **_mat(rng, "grippy"))]
    if variant == 1:
        s2 = _u(rng, 0.18, 0.22)
        top_c = box_c + (sb / 2 + s2 / 2 + GAP) * nrm
        bodies.append(make_body("gray_box", "gray", box_shape(s2, s2, s2), top_c, q,
                                mass=_u(rng, 0.1, 0.3), **_mat(rng, "grippy")))
    r = _u(rng, 0.17, 0.22)
    s_ball = lp / 2 - _u(rng, 0.2, 0.4)
    p = c + s_ball * u
    height = _u(rng, 0.6, 1.2)
    vx = -d * _u(rng, 0.3, 0.8) if variant == 2 else 0.0
    bodies.insert(0, red_ball(rng, [p[0] - vx * 0.3, p[1] + height, 0.0], r,
                              velocity=(vx, 0.0, 0.0), mass=_u(rng, 1.5, 2.5)))
    add_backstop(rng, bodies, d, distance=(0.5, 0.7))
    add_backstop(rng, bodies, -d, name="black_backstop_far", distance=(0.5, 0.7))
    centre_layout(bodies)
    return scene_3d(6, variant, "seesaw",
                    "a heavy red ball drops on the raised end of a plank balanced on a wedge "
                    "and catapults the box on the other end", bodies, camera(rng, bodies))


def _l_shape() -> dict:
    return _centred_compound([(box_shape(0.6, 0.15, 0.3), [0.0, 0.0, 0.0]),
                              (box_shape(0.15, 0.45, 0.3), [-0.225, 0.3, 0.0])])[0]


def _t_shape() -> dict:
    return _centred_compound([(box_shape(0.7, 0.12, 0.28), [0.0, 0.5, 0.0]),
                              (box_shape(0.14, 0.44, 0.28), [0.0, 0.22, 0.0])])[0]


def _dumbbell() -> dict:
    return _centred_compound([(sphere_shape(0.15), [-0.35, 0.0, 0.0]),
                              (box_shape(0.4, 0.08, 0.08), [0.0, 0.0, 0.0]),
                              (sphere_shape(0.15), [0.35, 0.0, 0.0])])[0]


def _t07_compound_fall(rng: np.random.Generator, variant: int) -> dict:
    d = _dir(rng)
    bodies = []
    spin = lambda: tuple(_u(rng, -2.5, 2.5) for _ in range(3))  # noqa: E731
    if variant == 0:
        ramp = Wedge(_u(rng, 1.0, 1.3), _u(rng, 0.5, 0.7), 0.9, -d * 0.4, 0.0, d)
        bodies.append(ramp.body("black_ramp", "black"))
        bodies.append(make_body("green_l_shape", "green", _l_shape(),
                                [ramp.cx, _u(rng, 1.5, 2.0), _u(rng, -0.2, 0.2)],
                                _random_quat(rng), angular=spin(), mass=_u(rng, 0.5, 1.2),
                                **_mat(rng)))
        bodies.append(make_body("blue_dumbbell", "blue", _dumbbell(),
                                [d * _u(rng, 1.3, 1.7), _u(rng, 1.0, 1.6), _u(rng, -0.3, 0.3)],
                                _random_quat(rng), angular=spin(), mass=_u(rng, 0.5, 1.2),
                                **_mat(rng)))
        r = _u(rng, 0.16, 0.2)
        bodies.insert(0, red_ball(rng, [ramp.cx - d * 0.1, _u(rng, 0.9, 1.2), 0.0], r,
                                  velocity=(d * _u(rng, 0.5, 1.0), 0.0, 0.0)))
        add_backstop(rng, bodies, d)
    else:
        h, lp = _u(rng, 0.5, 0.7), _u(rng, 2.0, 2.4)
        for side, name in ((-1, "purple_pillar_left"), (1, "purple_pillar_right")):
            bodies.append(make_body(name, "purple", box_shape(0.25, h, 0.6),
                                    [side * (lp / 2 - 0.3), h / 2, 0.0], dynamic=False,
                                    **_mat(rng, "static")))
        bodies.append(make_body("black_plank", "black", box_shape(lp, 0.1, 0.7),
                                [0.0, h + 0.05, 0.0], dynamic=False, **_mat(rng, "static")))
        bodies.append(make_body("gray_t_shape", "gray", _t_shape(),
                                [d * _u(rng, 0.3, 0.6), h + _u(rng, 1.0, 1.5), 0.0],
                                _random_quat(rng), angular=spin(), mass=_u(rng, 0.5, 1.2),
                                **_mat(rng)))
        bodies.append(make_body("green_l_shape", "green", _l_shape(),
                                [-d * _u(rng, 1.8, 2.2), _u(rng, 0.8, 1.3), 0.0],
                                _random_quat(rng), angular=spin(), mass=_u(rng, 0.5, 1.2),
                                **_mat(rng)))
        r = _u(rng, 0.16, 0.2)
        bodies.insert(0, red_ball(rng, [-d * _u(rng, 0.3, 0.6), h + _u(rng, 0.7, 1.0), 0.0], r))
    centre_layout(bodies)
    return scene_3d(7, variant, "compound_fall",
                    "compound shapes and a red ball fall, bounce and tumble",
                    bodies, camera(rng, bodies))


def _t08_launch_into_container(rng: np.random.Generator, variant: int) -> dict:
    d = _dir(rng)
    inner, wall_h, t_wall = _u(rng, 0.8, 1.0), _u(rng, 0.3, 0.42), 0.06
    cx = d * _u(rng, 1.2, 1.8)
    shape, cy = u_container_shape(inner, wall_h, 0.8, t_wall)
    dynamic = variant == 1
    container = make_body("gray_container" if dynamic else "purple_container",
                          "gray" if dynamic else "purple", shape, [cx, cy + GAP, 0.0],
                          dynamic=dynamic, mass=_u(rng, 1.5, 3.0),
                          **_mat(rng, "box" if dynamic else "static"))
    r = _u(rng, 0.15, 0.2)
    x0, y0 = -d * _u(rng, 2.2, 2.6), _u(rng, 0.3, 0.8)
    tx, ty = cx + d * _u(rng, -0.15, 0.15), t_wall + r
    t = _u(rng, 0.8, 1.0)
    ball = red_ball(rng, [x0, y0, 0.0], r,
                    velocity=((tx - x0) / t, (ty - y0 + 0.5 * G * t * t) / t, 0.0))
    plank = box_shape(1.0, 0.06, 0.2)
    bodies = [ball, container,
              make_body("blue_plank", "blue", plank,
                        _on_floor(plank, cx - d * (inner / 2 + 0.75), _u(rng, -0.6, 0.6)),
                        _rot_y(_u(rng, -0.6, 0.6)), mass=_u(rng, 0.2, 0.5), **_mat(rng))]
    if dynamic:
        s = _u(rng, 0.2, 0.26)
        bodies.append(make_body("green_box", "green", box_shape(s, s, s),
                                [cx + d * (inner / 2 - s / 2 - 0.04), t_wall + s / 2 + 2 * GAP,
                                 0.0], mass=_u(rng, 0.2, 0.5), **_mat(rng)))
    if dynamic:
        add_backstop(rng, bodies, d)
    return scene_3d(8, variant, "launch_container",
                    "a red ball is thrown in an arc into a U-shaped container",
                    bodies, camera(rng, bodies))


def _t09_dominoes(rng: np.random.Generator, variant: int) -> dict:
    d = _dir(rng)
    n = 5 if variant == 0 else 6
    h, gap = _u(rng, 0.6, 0.75), _u(rng, 0.32, 0.4)
    colors = ["gray", "green", "blue"]
    x_first = -d * (n - 1) * gap / 2 + d * 0.6
    bodies = []
    for i in range(n):
        plank = box_shape(0.07, h, 0.45)
        bodies.append(make_body(f"{colors[i % 3]}_domino_{i}", colors[i % 3], plank,
                                [x_first + d * i * gap, h / 2 + GAP, _u(rng, -0.03, 0.03)],
                                mass=_u(rng, 0.2, 0.4), **_mat(rng, "grippy")))
    r = _u(rng, 0.14, 0.18)
    x0, y0 = x_first - d * _u(rng, 0.8, 1.0), _u(rng, 0.45, 0.55)
    bodies.insert(0, red_ball(rng, [x0, y0, 0.0], r,
                              velocity=(d * _u(rng, 3.0, 4.0), 0.0, 0.0)))
    centre_layout(bodies)
    return scene_3d(9, variant, "dominoes",
                    "a red ball thrown at a row of standing planks knocks them over like "
                    "dominoes", bodies, camera(rng, bodies))


def _t10_incline_slide(rng: np.random.Generator, variant: int) -> dict:
    d = _dir(rng)
    lp, t, beta = _u(rng, 2.2, 2.6), 0.08, math.radians(_u(rng, 20.0, 27.0))
    u = np.array([d * math.cos(beta), -math.sin(beta), 0.0])     # downhill
    nrm = np.array([d * math.sin(beta), math.cos(beta), 0.0])    # up, out of the plank
    c = np.array([0.0, lp / 2 * math.sin(beta) + t / 2 * math.cos(beta), 0.0])
    q = _rot_z(-d * beta)
    s_sup = -(lp / 2 - 0.25)
    sup_x = c[0] + s_sup * u[0]
    # the support's top lies just under the plank's underside at its downhill edge
    under = c - (t / 2) * nrm
    x_edge = sup_x + d * 0.2
    sup_top = under[1] + (x_edge - under[0]) * (u[1] / u[0]) - 0.003
    bodies = [make_body("black_plank", "black", box_shape(lp, t, 0.9), c, q, dynamic=False,
                        **_mat(rng, "static")),
              make_body("purple_support", "purple", box_shape(0.4, sup_top, 0.9),
                        [sup_x, sup_top / 2, 0.0], dynamic=False, **_mat(rng, "static"))]
    sb = _u(rng, 0.24, 0.3)
    box_c = c - (lp / 2 - 0.45) * u + (t / 2 + sb / 2 + GAP) * nrm + np.array([0, 0, -0.2])
    green = make_body("green_box", "green", box_shape(sb, sb, sb), box_c, q,
                      mass=_u(rng, 0.3, 0.7), **_mat(rng))
    green["material"]["friction"] = 0.0003
    r = _u(rng, 0.14, 0.18)
    ball_c = c - (lp / 2 - 0.4) * u + (t / 2 + r + GAP) * nrm + np.array([0, 0, 0.22])
    bodies.insert(0, red_ball(rng, ball_c, r))
    bodies.append(green)
    low_x = c[0] + lp / 2 * u[0]
    if variant == 0:
        rb = _u(rng, 0.16, 0.2)
        bodies.append(make_body("blue_ball", "blue", sphere_shape(rb),
                                [low_x + d * _u(rng, 0.5, 0.9), rb + GAP, _u(rng, -0.2, 0.2)],
                                mass=_u(rng, 0.4, 1.0), **_mat(rng, "sphere")))
    else:
        s = _u(rng, 0.3, 0.38)
        cube = box_shape(s, s, s)
        bodies.append(make_body("gray_box", "gray", cube,
                                _on_floor(cube, low_x + d * _u(rng, 0.6, 1.0), 0.0),
                                mass=_u(rng, 0.3, 0.8), **_mat(rng)))
    add_backstop(rng, bodies, d)
    centre_layout(bodies)
    spec = scene_3d(10, variant, "incline_slide",
                    "a box slides and a red ball rolls down an inclined plank towards an object "
                    "on the floor", bodies, camera(rng, bodies))
    for pair in spec["contacts"]["pairs"]:  # a slippery box on the plank
        if {pair["a"], pair["b"]} == {"green_box", "black_plank"}:
            pair["friction"] = 0.0003
    return spec


def _t11_bridge(rng: np.random.Generator, variant: int) -> dict:
    d = _dir(rng)
    hp, lp = _u(rng, 0.55, 0.7), _u(rng, 1.4, 1.7)
    xb = d * _u(rng, 0.6, 1.0)
    bodies = []
    for side, name in ((-1, "gray_pillar_a"), (1, "gray_pillar_b")):
        pillar = box_shape(0.22, hp, 0.4)
        bodies.append(make_body(name, "gray", pillar,
                                [xb + side * (lp / 2 - 0.2), hp / 2 + GAP, 0.0],
                                mass=_u(rng, 0.2, 0.4), **_mat(rng, "grippy")))
    plank_y = hp + 2 * GAP + 0.04 + GAP
    bodies.append(make_body("blue_plank", "blue", box_shape(lp, 0.08, 0.5), [xb, plank_y, 0.0],
                            mass=_u(rng, 0.4, 0.8), **_mat(rng)))
    s = _u(rng, 0.24, 0.3)
    bodies.append(make_body("green_box", "green", box_shape(s, s, s),
                            [xb + _u(rng, -0.2, 0.2), plank_y + 0.04 + s / 2 + GAP, 0.0],
                            mass=_u(rng, 0.2, 0.5), **_mat(rng)))
    r = _u(rng, 0.17, 0.22)
    if variant == 0:
        x0 = -d * _u(rng, 2.0, 2.4)
        ball = red_ball(rng, [x0, r + GAP, 0.0], r, velocity=(d * _u(rng, 5.5, 7.0), 0.0, 0.0),
                        mass=_u(rng, 2.0, 3.0))
    else:
        ball = red_ball(rng, [xb - d * (lp / 2 - 0.15), plank_y + _u(rng, 1.2, 1.8), 0.0], r,
                        mass=_u(rng, 3.0, 5.0))
    if variant == 0:
        add_backstop(rng, bodies, d)
    bodies.insert(0, ball)
    centre_layout(bodies)
    return scene_3d(11, variant, "bridge_collapse",
                    "a red ball hits a plank bridge on two pillars and brings it down",
                    bodies, camera(rng, bodies))


def _t12_bowling(rng: np.random.Generator, variant: int) -> dict:
    d = _dir(rng)
    x_front = d * _u(rng, 0.5, 0.8)
    spacing = _u(rng, 0.32, 0.38)
    pin_h = _u(rng, 0.5, 0.6)
    bodies = []
    k = 0
    for row in range(3):
        for j in range(row + 1):
            z = (j - row / 2) * spacing
            x = x_front + d * row * spacing * 0.9
            color = "green" if (row + j) % 2 else "gray"
            if variant == 1 and row == 2:
                rb = 0.13
                bodies.append(make_body(f"blue_ball_{k}", "blue", sphere_shape(rb),
                                        [x, rb + GAP, z], mass=_u(rng, 0.2, 0.5),
                                        **_mat(rng, "sphere")))
            else:
                pin = box_shape(0.16, pin_h, 0.16)
                bodies.append(make_body(f"{color}_pin_{k}", color, pin, [x, pin_h / 2 + GAP, z],
                                        mass=_u(rng, 0.15, 0.3), **_mat(rng, "grippy")))
            k += 1
    bodies.append(make_body("black_backstop", "black", box_shape(0.12, 0.35, 2.2),
                            [x_front + d * _u(rng, 1.3, 1.5), 0.175, 0.0], dynamic=False,
                            **_mat(rng, "static")))
    r = _u(rng, 0.2, 0.25)
    x0 = -d * _u(rng, 1.6, 2.0)
    z0 = _u(rng, -0.4, 0.4)
    vx = d * _u(rng, 5.0, 6.5)
    vz = (_u(rng, -0.1, 0.1) - z0) / (abs(x_front - x0) / abs(vx))
    bodies.insert(0, red_ball(rng, [x0, r + GAP, z0], r, velocity=(vx, 0.0, vz),
                              mass=_u(rng, 1.5, 3.0)))
    centre_layout(bodies)
    return scene_3d(12, variant, "bowling",
                    "a red ball rolls into a triangle of pins", bodies, camera(rng, bodies))


TEMPLATES_3D: list[Template] = [
    Template(1, "ramp_container", 3, "ball rolls down a ramp on a table into a U container",
             _t01_ramp_to_container),
    Template(2, "ramp_box", 3, "ball rolls down a ramp into boxes", _t02_ramp_hits_box),
    Template(3, "plank_knockoff", 3, "ball knocks a box off a raised plank", _t03_plank_knockoff),
    Template(4, "sphere_collision", 3, "ball launched into other balls", _t04_sphere_collision),
    Template(5, "stack_topple", 3, "ball topples a stack of boxes", _t05_stack_topple),
    Template(6, "seesaw", 3, "ball drops on a seesaw plank and launches a box", _t06_seesaw),
    Template(7, "compound_fall", 2, "compound shapes fall and tumble", _t07_compound_fall),
    Template(8, "launch_container", 2, "ball thrown into a U container",
             _t08_launch_into_container),
    Template(9, "dominoes", 2, "ball knocks over a row of standing planks", _t09_dominoes),
    Template(10, "incline_slide", 2, "box and ball slide/roll down an inclined plank",
             _t10_incline_slide),
    Template(11, "bridge_collapse", 2, "ball brings down a plank bridge", _t11_bridge),
    Template(12, "bowling", 2, "ball rolls into a triangle of pins", _t12_bowling),
]


# ------------------------------------------------------------------------- screening
def action_index_3d(spec: dict) -> int | None:
    """Index of the action ball: id "red_ball", else the first dynamic red sphere."""
    for i, b in enumerate(spec["bodies"]):
        if b["id"] == "red_ball":
            return i
    for i, b in enumerate(spec["bodies"]):
        if b["dynamic"] and tuple(b["color_rgb"]) == RED_RGB and b["shape"]["type"] == "sphere":
            return i
    return None


def _last_step(spec: dict, rollout) -> int:
    from visphy_plugins.physics.cannon import total_steps_3d

    return min(total_steps_3d(spec), len(rollout.step_poses) - 1)


def validity_problems_3d(spec: dict, rollout) -> list[str]:
    """Reason keys (subset of `REASONS`, in that order) why a simulated 3D candidate is unusable.

    overlap: cannon finds an interpenetration deeper than 1 mm in the initial state (pairs of
    static bodies are never tested: scenery may touch or intersect); offscreen: a body's centre
    projects outside the image (or lies behind the camera) at t = 0; static: no dynamic body
    moves more than 5 cm; tunnelling: a dynamic body's centre goes below y = -0.05 m or beyond
    |x| or |z| = 50 m; speed_cap: a body moves faster than 50 m/s between two steps.
    """
    from visphy_plugins.datasets.visphybench.detection3d import project_points

    problems = []
    if any(depth > OVERLAP_M for depth in rollout.initial_penetration_m.values()):
        problems.append("overlap")
    cam = spec["camera"]
    pix, depth = project_points(spec, rollout.step_poses[0, :, :3], return_depth=True)
    if np.any(depth <= cam.get("near", 0.1)) or np.any(
            (pix[:, 0] < 0) | (pix[:, 0] > cam["width"]) | (pix[:, 1] < 0)
            | (pix[:, 1] > cam["height"])):
        problems.append("offscreen")
    dyn = np.array([b["dynamic"] for b in spec["bodies"]], dtype=bool)
    poses = rollout.step_poses[:_last_step(spec, rollout) + 1]
    if not dyn.any() or np.linalg.norm(poses[:, dyn, :3] - poses[0, dyn, :3], axis=2).max() \
            <= MIN_MOTION_M:
        problems.append("static")
    if dyn.any():
        p = poses[:, dyn, :3]
        if np.any(p[..., 1] < spec["world"]["floor"]["y"] + FLOOR_TUNNEL_M) or np.any(
                np.abs(p[..., 0]) > REGION_M) or np.any(np.abs(p[..., 2]) > REGION_M):
            problems.append("tunnelling")
    if len(poses) > 1:
        speed = np.linalg.norm(np.diff(poses[:, :, :3], axis=0), axis=2).max() / float(
            spec["world"]["dt_s"])
        if speed > SPEED_CAP_M_S:
            problems.append("speed_cap")
    return problems


def _projected_circles(spec: dict, frame_poses: np.ndarray, radii: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Projected centres (F×B×2) and bounding-circle radii (F×B, px) of the bodies."""
    from visphy_plugins.datasets.visphybench.detection3d import camera_basis, project_points

    f, b = frame_poses.shape[:2]
    pix, depth = project_points(spec, frame_poses[:, :, :3].reshape(-1, 3), return_depth=True)
    _, _, _, f_y, _, height = camera_basis(spec)
    depth = np.maximum(depth, 1e-6).reshape(f, b)
    return pix.reshape(f, b, 2), f_y * radii[None, :] / depth * height / 2.0


def sensitivity_px_3d(spec: dict, rollout) -> float:
    """Max final-frame displacement (px) of any body's projected centre when the action ball
    starts 1 mm further along +x (one extra simulation)."""
    from visphy_plugins.physics.cannon import simulate_3d
    from visphy_plugins.datasets.visphybench.detection3d import project_points

    idx = action_index_3d(spec)
    if idx is None:
        return 0.0
    perturbed = copy.deepcopy(spec)
    perturbed["bodies"][idx]["pose"]["position_m"][0] += PERTURB_M
    other = simulate_3d(perturbed, n_steps=int(rollout.frame_steps[-1]))
    a = project_points(spec, rollout.frame_poses[-1, :, :3])
    b = project_points(spec, other.frame_poses[-1, :, :3])
    return float(np.linalg.norm(a - b, axis=1).max())


def difficulty_features_3d(spec: dict, rollout, sensitivity: bool = True) -> dict:
    """Difficulty features of a simulated 3D scene (keys shared with the 2D features).

    n_bodies, n_dynamic; n_contacts: distinct body pairs (floor excluded) that touch during the
    clip; max_rotation_deg: largest rotation of a non-spherical dynamic body from its initial
    orientation over every step, rotation_over_30deg; sensitivity_px: `sensitivity_px_3d`,
    chaotic: above 16 px; occlusion: fraction of frames in which the projected bounding circles
    (bounding sphere of each body) of two dynamic bodies overlap (static scenery such as a ramp
    always overlaps what rolls on it, so it is left out).
    """
    bodies = spec["bodies"]
    dyn = np.array([b["dynamic"] for b in bodies], dtype=bool)
    last = _last_step(spec, rollout)
    max_rot = 0.0
    for i, b in enumerate(bodies):
        if b["dynamic"] and b["shape"]["type"] != "sphere":
            q = rollout.step_poses[:last + 1, i, 3:7]
            dots = np.clip(np.abs(q @ q[0]), 0.0, 1.0)
            max_rot = max(max_rot, float(np.degrees(2.0 * np.arccos(dots)).max()))
    pairs = {k for k, st in rollout.pair_stats.items()
             if FLOOR_ID not in k.split("|") and st["steps_touching"] > 0}
    sens = sensitivity_px_3d(spec, rollout) if sensitivity else 0.0
    occlusion = 0.0
    idx = np.flatnonzero(dyn)
    if len(idx) >= 2:
        radii = np.array([bounding_radius(b["shape"]) for b in bodies])
        centres, rad = _projected_circles(spec, rollout.frame_poses, radii)
        hit = np.zeros(len(rollout.frame_poses), dtype=bool)
        for a_i, i in enumerate(idx):
            for j in idx[a_i + 1:]:
                dist = np.linalg.norm(centres[:, i] - centres[:, j], axis=1)
                hit |= dist < rad[:, i] + rad[:, j]
        occlusion = float(hit.mean())
    return {"n_bodies": len(bodies), "n_dynamic": int(dyn.sum()), "n_contacts": len(pairs),
            "rotation_over_30deg": bool(max_rot > ROTATION_DEG),
            "max_rotation_deg": round(max_rot, 3), "sensitivity_px": round(sens, 3),
            "chaotic": bool(sens > CHAOTIC_PX), "occlusion": round(occlusion, 4)}


def draw_seed_3d(template_id: int, variant: int, draw: int) -> int:
    """Seed of candidate `draw` of a slot in `generate_scene_3d` (variant 0: template_id·100 +
    draw). The benchmark builder uses its own seeds (`catalogue.scene_seed`)."""
    return template_id * 100 + variant * 10 + draw


def generate_scene_3d(template_id: int, variant: int = 0, max_draws: int = 4,
                      features: bool = True):
    """First valid candidate of a slot: (annotated spec, rollout, draws used).

    Fills ``seed``, ``ground_truth.events``, ``digest_sha256`` and the difficulty features
    (label left None: labels are relative to a whole benchmark). Raises RuntimeError with the
    rejection reasons when no draw is valid.
    """
    from visphy_plugins.physics.cannon import simulate_3d, trajectory_digest_3d

    template = next(t for t in TEMPLATES_3D if t.template_id == template_id)
    reasons: list[str] = []
    for k in range(max_draws):
        seed = draw_seed_3d(template_id, variant, k)
        spec = template.make(np.random.default_rng(seed), variant)
        spec["seed"] = seed
        validate_spec_3d(spec)
        rollout = simulate_3d(spec)
        problems = validity_problems_3d(spec, rollout)
        if problems:
            reasons.extend(problems)
            continue
        feats = difficulty_features_3d(spec, rollout) if features else {}
        spec["difficulty"] = {"label": None, "score": 0.0, "features": feats}
        spec["ground_truth"]["events"] = rollout.events
        spec["digest_sha256"] = trajectory_digest_3d(rollout)
        validate_spec_3d(spec)
        return spec, rollout, k + 1
    raise RuntimeError(f"3D template {template_id} variant {variant}: no valid candidate in "
                       f"{max_draws} draws (rejected: {reasons})")
