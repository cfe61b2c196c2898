"""Building blocks of the generated 3D scenes: palette, materials, shapes (spheres, boxes,
wedges, U containers, compounds), bodies, the camera and the scene record every 3D template
(`templates_3d`) assembles. Contact values are explicit for every pair that can touch
(friction min(μa, μb), restitution max(ea, eb) of the per-body values, written out so cannon's
product rule is never used); friction is in cannon-es units (see `mat`: sliding boxes need μ of
a few 1e-3).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from visphy_core.api.scene import SPEC_SCHEMA
from visphy_core.api.spec import (
    FLOOR_ID,
    IDENTITY_QUAT,
    PROFILE_3D,
    PROFILE_NAME,
    RED_RGB,
    category_of_3d,
    local_hull_points,
    quat_from_axis_angle,
    shape_parts,
    transform_points_3d,
)

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
    "black": (0, 0, 0), "purple": (75, 74, 164), "brown": (164, 128, 96),
    "white": (255, 255, 255),
}
HEMISPHERE = {"sky_rgb": [255, 255, 255], "ground_rgb": [110, 110, 110], "intensity": 1.6}
DIRECTIONAL = {"color_rgb": [255, 255, 255], "intensity": 2.0, "position": [-3.0, 10.0, 6.0]}
#: rendered (three.js r160 Lambert, physical light units) as about grey 151, the published
#: clips' floor: linear = albedo * (I_h / pi + I_d / pi * l_y) on an upward face
FLOOR_RGB = (148, 148, 148)
FLOOR_SIZE_M = 18.0          # the published clips' square floor, centred on the origin
LAYOUT_SCALE = 1.7           # templates lay out in metres at 1/1.7 of the drawn size...
MAX_LAYOUT_WIDTH_PX = 400.0  # ...or less, so the initial layout spans at most 400 of 512 px
CONTAINER_OPACITY = 0.5
FLOOR_MATERIAL = {"friction": 0.4, "restitution": 0.1}
#: The simulator the 3D subset's specs name, at the version its clips were made with.
CANNON_VERSION = "0.20.0"
G = 9.82
GAP = 0.002          # bodies resting on something start this far above it
QUAT_Y_PI = [0.0, 1.0, 0.0, 0.0]
K_SPHERE = 2.0 / 3.0  # cannon-es sphere inertia (AABB approximation): I = 2/3 m r²

# validity thresholds (docs/benchmark.md)
# ------------------------------------------------------------------------------ builders
def uni(rng: np.random.Generator, lo: float, hi: float) -> float:
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


def centred_compound(parts: list[tuple[dict, list[float]]]) -> tuple[dict, np.ndarray]:
    """A compound of (primitive, offset) parts shifted so its volume centroid is the origin;
    returns the shape and the shift (old origin -> centroid)."""
    from visphy_core.api.spec import primitive_volume

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
    shape, c = centred_compound([
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


#: The published clips' camera: one fixed perspective camera, identical in every 3D scene, high
#: over the +x/+z corner of the floor looking down at the middle of the scene (the floor, axis
#: aligned, is seen corner-on: its far edges make a "^").
CAMERA_POSITION = (7.0, 6.2, 8.2)
CAMERA_LOOK_AT = (0.0, 1.2, 0.0)
CAMERA_FOV_DEG = 45.0
#: Templates lay their action out along +x; turned by this yaw about y, +x runs along the
#: image's horizontal (the camera's right axis), so the action is seen side-on.
LAYOUT_YAW = math.atan2(CAMERA_POSITION[0] - CAMERA_LOOK_AT[0],
                        CAMERA_POSITION[2] - CAMERA_LOOK_AT[2])


def camera(rng: np.random.Generator | None = None, bodies: list[dict] | None = None) -> dict:
    """The fixed camera of every 3D scene (the arguments are ignored; kept for callers)."""
    return {"type": "perspective", "fov_deg": CAMERA_FOV_DEG, "near": 0.1, "far": 100.0,
            "position": list(CAMERA_POSITION), "look_at": list(CAMERA_LOOK_AT),
            "up": [0.0, 1.0, 0.0], "width": PROFILE_3D["width"], "height": PROFILE_3D["height"]}


def _scale_shape(shape: dict, s: float) -> dict:
    kind = shape["type"]
    if kind == "sphere":
        return {"type": "sphere", "radius_m": float(shape["radius_m"]) * s}
    if kind == "box":
        return {"type": "box", "size_m": [float(v) * s for v in shape["size_m"]]}
    if kind == "wedge":
        return {"type": "wedge", "length_m": float(shape["length_m"]) * s,
                "height_m": float(shape["height_m"]) * s, "width_m": float(shape["width_m"]) * s}
    return {"type": "compound", "parts": [
        {"shape": _scale_shape(p["shape"], s), "offset_m": [float(v) * s for v in p["offset_m"]],
         "quat": list(p["quat"])} for p in shape["parts"]]}


def froude_scale(bodies: list[dict], s: float) -> None:
    """Scale a layout about the origin by s, keeping its story (in place): lengths x s, linear
    velocities x sqrt(s), angular velocities / sqrt(s), so every trajectory is the same curve,
    s times larger, run sqrt(s) times slower under the same gravity (masses, friction and
    restitution unchanged: cannon's friction bound mu g m scales with the forces it opposes)."""
    root = math.sqrt(s)
    for b in bodies:
        b["shape"] = _scale_shape(b["shape"], s)
        b["pose"]["position_m"] = _vec(np.asarray(b["pose"]["position_m"]) * s)
        if "velocity" in b:
            b["velocity"] = {"linear_m_s": _vec(np.asarray(b["velocity"]["linear_m_s"]) * root),
                             "angular_rad_s": _vec(
                                 np.asarray(b["velocity"]["angular_rad_s"]) / root)}


def yaw_layout(bodies: list[dict], angle: float) -> None:
    """Turn a layout about the vertical axis through the origin by ``angle`` (rad; in place):
    positions, orientations and both velocities (the story is unchanged)."""
    from visphy_core.api.spec import quat_to_matrix

    q = rot_y(angle)
    rot = quat_to_matrix(q)
    for b in bodies:
        b["pose"]["position_m"] = _vec(rot @ np.asarray(b["pose"]["position_m"]))
        b["pose"]["quat"] = _vec(_quat_mul(q, b["pose"]["quat"]))
        if "velocity" in b:
            b["velocity"] = {"linear_m_s": _vec(rot @ np.asarray(b["velocity"]["linear_m_s"])),
                             "angular_rad_s": _vec(
                                 rot @ np.asarray(b["velocity"]["angular_rad_s"]))}


def _quat_mul(a, b) -> list[float]:
    """Hamilton product a * b of (x, y, z, w) quaternions, normalised."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    q = np.array([aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
                  aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz])
    return list(q / np.linalg.norm(q))


def _image_box(bodies: list[dict], cam: dict) -> np.ndarray:
    """[x_min, y_min, x_max, y_max] (px) of the layout's projected hull points."""
    from visphy_plugins.datasets.visphybench.detection3d import project_points

    pts = np.concatenate([transform_points_3d(local_hull_points(b["shape"]),
                                              b["pose"]["position_m"] + b["pose"]["quat"])
                          for b in bodies])
    pix = project_points({"camera": cam}, pts)
    return np.concatenate([pix.min(axis=0), pix.max(axis=0)])


def frame_layout(bodies: list[dict], cam: dict, target=(256.0, 272.0)) -> None:
    """Slide the layout over the floor (x and z, in place) so its projected initial box is
    centred on ``target`` (px) in the fixed camera's image."""
    eye = np.asarray(cam["position"], dtype=np.float64)
    look = np.asarray(cam["look_at"], dtype=np.float64)
    fwd = look - eye
    fwd = np.array([fwd[0], 0.0, fwd[2]]) / math.hypot(fwd[0], fwd[2])   # away on the floor
    right = np.array([-fwd[2], 0.0, fwd[0]])                             # image right
    for _ in range(4):
        box = _image_box(bodies, cam)
        centre = (box[:2] + box[2:]) / 2.0
        err = np.asarray(target) - centre
        if np.abs(err).max() < 1.0:
            break
        # about 40 px per metre across and 20 px per metre in depth near the look-at point
        shift = right * (err[0] / 40.0) - fwd * (err[1] / 20.0)
        for b in bodies:
            b["pose"]["position_m"] = _vec(np.asarray(b["pose"]["position_m"]) + shift)


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
                 name: str = "brown_backstop", height: float = 0.3,
                 distance: tuple[float, float] = (0.6, 0.9)) -> None:
    """A static brown plank lying across the floor beyond the layout in direction d, so what
    rolls away stops in view (in place)."""
    far = -math.inf
    for b in bodies:
        pts = transform_points_3d(local_hull_points(b["shape"]),
                                  b["pose"]["position_m"] + b["pose"]["quat"])
        far = max(far, float((d * pts[:, 0]).max()))
    bodies.append(make_body(name, "brown", box_shape(0.15, height, 2.4),
                            [d * (far + uni(rng, *distance)), height / 2, 0.0], dynamic=False,
                            **mat(rng, "static")))


def scene_3d(template_id: int, variant: int, family: str, description: str,
             bodies: list[dict], cam: dict | None = None, scale: float = LAYOUT_SCALE) -> dict:
    """Wrap bodies into a `visphy-scene/1` 3D spec (ground truth still empty): the layout is
    scaled by ``scale`` (`froude_scale`) and slid over the floor so the fixed camera frames it
    (`frame_layout`), smaller where the scaled layout would be wider than
    `MAX_LAYOUT_WIDTH_PX` on screen; containers (U shapes) are drawn translucent."""
    p = PROFILE_3D
    cam = camera()
    yaw_layout(bodies, LAYOUT_YAW)
    box = _image_box(bodies, cam)             # about linear in the scale near the look-at point
    froude_scale(bodies, min(scale, MAX_LAYOUT_WIDTH_PX / max(box[2] - box[0], 1.0)))
    frame_layout(bodies, cam)
    for b in bodies:
        if "container" in b["id"]:
            b["opacity"] = CONTAINER_OPACITY
    return {
        "schema": SPEC_SCHEMA, "scene_id": f"{template_id:02d}_tmpl_{variant:02d}",
        "template_id": f"{template_id:02d}", "variant": int(variant),
        "seed": 0, "dim": "3d", "family": family, "description": description,
        "difficulty": {"label": "easy", "score": 0.0, "features": {}},
        "world": {
            "engine": "cannon-es", "engine_version": CANNON_VERSION,
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
            "floor": {"y": 0.0, "color_rgb": list(FLOOR_RGB), "size_m": FLOOR_SIZE_M},
        },
        "camera": cam,
        "render": {
            "background_rgb": list(PALETTE_3D["white"]), "antialias": True,
            "material": "lambert", "shadows": False,
            "lighting": {
                "description": "white sky, grey floor; hemisphere light (white sky, grey "
                               "ground) plus one white directional light from above, left of "
                               "the camera, without shadows: Lambert-shaded colours",
                "hemisphere": dict(HEMISPHERE),
                "directional": dict(DIRECTIONAL),
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


def mat(rng: np.random.Generator, kind: str = "box") -> dict:
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
        return {"friction": uni(rng, 0.3, 0.5), "restitution": uni(rng, 0.05, 0.3)}
    if kind == "static":
        return {"friction": uni(rng, 0.3, 0.5), "restitution": uni(rng, 0.05, 0.25)}
    if kind == "grippy":  # standing pieces that must topple rather than slide
        return {"friction": uni(rng, 0.005, 0.008), "restitution": uni(rng, 0.05, 0.2)}
    return {"friction": uni(rng, 0.002, 0.004), "restitution": uni(rng, 0.05, 0.25)}


def red_ball(rng: np.random.Generator, position, r: float, velocity=(0.0, 0.0, 0.0),
             mass: float | None = None) -> dict:
    return make_body("red_ball", "red", sphere_shape(r), position, velocity=velocity,
                     mass=mass if mass is not None else uni(rng, 0.8, 2.0), **mat(rng, "sphere"))


def lr_sign(rng: np.random.Generator) -> int:
    return 1 if rng.random() < 0.5 else -1


def on_floor(shape: dict, x: float, z: float, quat=IDENTITY_QUAT) -> list[float]:
    return [x, -_min_local_y(shape, quat) + GAP, z]


def rot_z(angle: float) -> list[float]:
    return quat_from_axis_angle([0, 0, 1], angle)


def rot_y(angle: float) -> list[float]:
    return quat_from_axis_angle([0, 1, 0], angle)


def random_quat(rng: np.random.Generator) -> list[float]:
    axis = rng.normal(size=3)
    return quat_from_axis_angle(axis, uni(rng, 0.0, math.pi))
