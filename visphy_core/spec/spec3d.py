"""Scene specification `visphy-scene/1` with ``dim: "3d"``: JSON Schema, validation, geometry.

The 3D spec has the same top-level keys as the 2D one (`visphy_core/spec/spec2d.py`) plus a
``camera``; it is the single source of ground truth for a generated 3D scene (the simulator's
rollout, the engines' replays, the detection context). Conventions, fixed here once:

* SI units: metres, kilograms, seconds, radians; right-handed world, **y up**, the floor is the
  plane y = ``world.floor.y`` (a static body with the reserved id ``floor``);
* a pose is ``{position_m: [x, y, z], quat: [x, y, z, w]}`` (unit quaternion, body -> world);
  poses in trajectories are 7-vectors ``(x, y, z, qx, qy, qz, qw)``;
* the body origin is its centre of mass (rigid-body simulators rotate bodies about their origin), so
  templates place compound parts around their common centroid;
* shapes (local frame): ``sphere {radius_m}``; ``box {size_m: [sx, sy, sz]}`` (full extents,
  centred); ``wedge {length_m, height_m, width_m}``: a right-triangle prism whose triangle lies in
  the x-y plane with legs ``length_m`` along +x and ``height_m`` along +y meeting at the right
  angle (low, high-side corner at -x), extruded over ``width_m`` along z and centred on the
  triangle's centroid, so the slope descends towards +x; ``compound {parts: [{shape: box|sphere,
  offset_m, quat}]}``;
* simulators mix two bodies' materials by rules of their own; every pair that can touch gets an
  explicit contact material (``contacts.pairs``, falling back to ``contacts.default``), so the
  ground truth never depends on a mixing rule. Per-body ``material.friction/restitution`` are the
  template's per-body values the pair values were derived from (documentation only).
* drawing only (no effect on the physics): a body's optional ``opacity`` (0-1, default 1: a
  translucent body, e.g. a U container), ``render.antialias`` (multisampled edges) and
  ``render.shadows`` (shadow-mapped shadows of the directional light).

`validate_spec_3d` adds the checks JSON Schema cannot express (unique ids, unit quaternions,
profile constants, category consistency, one of mass/density) and reports the first problem on
one line naming the scene and the JSON path; the steps and schema parts it shares with the 2D
spec are in `visphy_core.spec.validation`.
"""

from __future__ import annotations

import math
from typing import Any

import jsonschema
import numpy as np

from visphy_core.api.scene import SPEC_SCHEMA
from visphy_core.spec.validation import (
    CONTACTS,
    ID_LIST,
    NONNEG,
    NUM,
    POS,
    RGB,
    SIMULATOR,
    body_schema,
    check_bodies,
    check_contact_pairs,
    check_profile,
    check_schema,
    fail,
    ground_truth_schema,
    obj,
    reply_schema,
    shape_case,
)

#: Constants of the generated 3D subset: a spec with profile "visphybench-3d" must
#: use them.
PROFILE_3D: dict[str, Any] = {
    "gravity_m_s2": [0.0, -9.82, 0.0],
    "dt_s": 1.0 / 60.0,
    "steps_per_frame": 4,
    "first_frame_after_steps": 0,
    "n_frames": 75,
    "video_fps": 15,
    "width": 512,
    "height": 512,
}
PROFILE_NAME = "visphybench-3d"
FLOOR_ID = "floor"
RED_RGB = (243, 79, 70)
#: Long thin boxes (longest / shortest side >= this) are "line" (planks), others "rectangle".
LINE_ASPECT = 4.0

_VEC3 = {"type": "array", "items": NUM, "minItems": 3, "maxItems": 3}
_POS3 = {"type": "array", "items": POS, "minItems": 3, "maxItems": 3}
_QUAT = {"type": "array", "items": NUM, "minItems": 4, "maxItems": 4}


_PRIMITIVE_CASES = [
    shape_case("sphere", {"radius_m": POS}),
    shape_case("box", {"size_m": _POS3}),
    shape_case("wedge", {"length_m": POS, "height_m": POS, "width_m": POS}),
]
_PART_SHAPE = {"type": "object", "required": ["type"],
               "properties": {"type": {"enum": ["sphere", "box"]}}, "allOf": _PRIMITIVE_CASES}
_PART = obj({"shape": _PART_SHAPE, "offset_m": _VEC3, "quat": _QUAT})
_SHAPE = {
    "type": "object",
    "required": ["type"],
    "properties": {"type": {"enum": ["sphere", "box", "wedge", "compound"]}},
    "allOf": _PRIMITIVE_CASES + [
        shape_case("compound", {"parts": {"type": "array", "items": _PART, "minItems": 1}})],
}
_MATERIAL = obj({"mass_kg": POS, "density_kg_m3": POS, "friction": NONNEG,
                  "restitution": NONNEG}, required=["friction", "restitution"])
_BODY = body_schema(_SHAPE, obj({"position_m": _VEC3, "quat": _QUAT}),
                    obj({"linear_m_s": _VEC3, "angular_rad_s": _VEC3}), _MATERIAL,
                    opacity={"type": "number", "exclusiveMinimum": 0, "maximum": 1})
_SPOOK = obj({"stiffness": POS, "relaxation": POS})

#: JSON Schema (draft 2020-12) of `visphy-scene/1` for 3D scenes.
SCHEMA_3D: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "visphy scene specification (3D)",
    **obj(
        {
            "schema": {"const": SPEC_SCHEMA},
            "scene_id": {"type": "string",  # vpb3-s0-3d-t001-v00; before version 3: NN_tmpl_NN
                         "pattern": r"^(vpb\d+-s\d+-3d-t\d{3}-v\d{2}|\d{2}_tmpl_\d{2})$"},
            "template_id": {"type": "string", "pattern": r"^\d{2}$"},
            "variant": {"type": "integer", "minimum": 0},
            "seed": {"type": "integer", "minimum": 0},
            "dim": {"const": "3d"},
            "family": {"type": "string"},
            "description": {"type": "string"},
            "splits": ID_LIST,
            "difficulty": obj({"label": {"enum": ["easy", "medium", "hard", None]},
                                "score": NUM, "features": {"type": "object"}}),
            "world": obj(
                {
                    "engine": SIMULATOR,
                    "engine_version": {"type": "string"},
                    "profile": {"type": "string"},
                    "units": obj({"length": {"const": "m"}, "mass": {"const": "kg"},
                                   "time": {"const": "s"}, "angles": {"const": "rad"},
                                   "up_axis": {"const": "y"},
                                   "quaternion": {"const": "xyzw"}}),
                    "gravity_m_s2": _VEC3,
                    "dt_s": POS,
                    "steps_per_frame": {"type": "integer", "minimum": 1},
                    "first_frame_after_steps": {"type": "integer", "minimum": 0},
                    "n_frames": {"type": "integer", "minimum": 1},
                    "video_fps": POS,
                    "solver": obj({"type": {"const": "GSSolver"},
                                    "iterations": {"type": "integer", "minimum": 1},
                                    "tolerance": NONNEG}),
                    "broadphase": {"const": "naive"},
                    "contact_equation": _SPOOK,
                    "friction_equation": _SPOOK,
                    "damping": obj({"linear": {"type": "number", "minimum": 0, "maximum": 1},
                                     "angular": {"type": "number", "minimum": 0, "maximum": 1}}),
                    "allow_sleep": {"const": False},
                    "quat_normalize": obj({"skip": {"type": "integer", "minimum": 0},
                                            "fast": {"type": "boolean"}}),
                    "floor": obj({"y": NUM, "color_rgb": RGB, "size_m": POS},
                                  required=["y", "color_rgb"]),
                },
                required=["engine", "engine_version", "profile", "units", "gravity_m_s2",
                          "dt_s", "steps_per_frame", "first_frame_after_steps", "n_frames",
                          "video_fps", "solver", "contact_equation", "friction_equation",
                          "damping", "allow_sleep", "floor"],
            ),
            "camera": obj(
                {"type": {"const": "perspective"},
                 "fov_deg": {"type": "number", "exclusiveMinimum": 0, "exclusiveMaximum": 180},
                 "near": POS, "far": POS, "position": _VEC3, "look_at": _VEC3,
                 "up": _VEC3, "width": {"type": "integer", "minimum": 2},
                 "height": {"type": "integer", "minimum": 2}},
                required=["type", "fov_deg", "position", "look_at", "width", "height"]),
            "render": obj(
                {"background_rgb": RGB, "antialias": {"type": "boolean"},
                 "material": {"enum": ["lambert"]},
                 "shadows": {"type": "boolean"},
                 "lighting": obj(
                     {"description": {"type": "string"},
                      "hemisphere": obj({"sky_rgb": RGB, "ground_rgb": RGB,
                                          "intensity": NONNEG}),
                      "directional": obj({"color_rgb": RGB, "intensity": NONNEG,
                                           "position": _VEC3})},
                     required=["hemisphere", "directional"]),
                 "codec": {"type": "string"}, "pix_fmt": {"type": "string"}},
                required=["background_rgb", "antialias", "lighting"]),
            "bodies": {"type": "array", "items": _BODY, "minItems": 1},
            "contacts": CONTACTS,
            "ground_truth": ground_truth_schema(identifiable_open=True),
            "digest_sha256": {"type": ["string", "null"]},
        },
        required=["schema", "scene_id", "template_id", "variant", "seed", "dim", "difficulty",
                  "world", "camera", "render", "bodies", "contacts", "ground_truth"],
    ),
}

_VALIDATOR = jsonschema.Draft202012Validator(SCHEMA_3D)


# ------------------------------------------------------------------------------ quaternions
def quat_to_matrix(q) -> np.ndarray:
    """3×3 rotation matrix of a unit quaternion (x, y, z, w); body -> world."""
    x, y, z, w = (float(v) for v in q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def quat_from_axis_angle(axis, angle_rad: float) -> list[float]:
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    s = math.sin(angle_rad / 2.0)
    return [float(a[0] * s), float(a[1] * s), float(a[2] * s), math.cos(angle_rad / 2.0)]


def quat_multiply(q1, q2) -> list[float]:
    """Hamilton product q1 * q2 (apply q2 first, then q1), both (x, y, z, w)."""
    x1, y1, z1, w1 = q1
    x2, y2, z2, w2 = q2
    return [w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2]


def quat_angle_deg(q1, q2) -> float:
    """Rotation angle (degrees, 0..180) between two orientations."""
    d = abs(float(np.dot(np.asarray(q1, dtype=np.float64), np.asarray(q2, dtype=np.float64))))
    return math.degrees(2.0 * math.acos(min(1.0, d)))


IDENTITY_QUAT = [0.0, 0.0, 0.0, 1.0]


# --------------------------------------------------------------------------------- geometry
#: Faces of the wedge's 6 vertices (`wedge_vertices`), counter-clockwise seen from outside
#: (outward normals by the right-hand rule, as convex-polyhedron shapes expect): front, back,
#: bottom, vertical back face, slope.
WEDGE_FACES: list[list[int]] = [[3, 4, 5], [0, 2, 1], [0, 1, 4, 3], [0, 3, 5, 2], [1, 2, 5, 4]]


def wedge_vertices(length_m: float, height_m: float, width_m: float) -> np.ndarray:
    """The wedge's 6 local vertices (centroid at the origin): back face z = -w/2 (0..2) then
    front face z = +w/2 (3..5), each as right-angle corner, toe (+x), top (+y)."""
    x0, x1 = -length_m / 3.0, 2.0 * length_m / 3.0
    y0, y1 = -height_m / 3.0, 2.0 * height_m / 3.0
    hw = width_m / 2.0
    return np.array([[x0, y0, -hw], [x1, y0, -hw], [x0, y1, -hw],
                     [x0, y0, hw], [x1, y0, hw], [x0, y1, hw]], dtype=np.float64)


def box_corners(size_m) -> np.ndarray:
    hx, hy, hz = (float(s) / 2.0 for s in size_m)
    return np.array([[sx * hx, sy * hy, sz * hz] for sx in (-1, 1) for sy in (-1, 1)
                     for sz in (-1, 1)], dtype=np.float64)


def transform_points_3d(points, pose7) -> np.ndarray:
    """Local points (k×3) to world by a pose (x, y, z, qx, qy, qz, qw)."""
    p = np.asarray(pose7, dtype=np.float64)
    return np.asarray(points, dtype=np.float64) @ quat_to_matrix(p[3:7]).T + p[:3]


def shape_parts(shape: dict) -> list[tuple[dict, np.ndarray, list[float]]]:
    """(primitive shape, offset, quat) of every part; a primitive is its own single part."""
    if shape["type"] == "compound":
        return [(p["shape"], np.asarray(p["offset_m"], dtype=np.float64), list(p["quat"]))
                for p in shape["parts"]]
    return [(shape, np.zeros(3), list(IDENTITY_QUAT))]


def primitive_volume(shape: dict) -> float:
    kind = shape["type"]
    if kind == "sphere":
        return 4.0 / 3.0 * math.pi * shape["radius_m"] ** 3
    if kind == "box":
        sx, sy, sz = shape["size_m"]
        return float(sx * sy * sz)
    if kind == "wedge":
        return 0.5 * shape["length_m"] * shape["height_m"] * shape["width_m"]
    raise ValueError(f"not a primitive shape: {kind}")


def shape_volume(shape: dict) -> float:
    """Volume in m³; compound parts are assumed not to overlap."""
    return sum(primitive_volume(s) for s, _, _ in shape_parts(shape))


def body_mass(body: dict) -> float:
    """Mass in kg (``mass_kg``, else density × volume); 0 for static bodies."""
    if not body["dynamic"]:
        return 0.0
    mat = body["material"]
    if "mass_kg" in mat:
        return float(mat["mass_kg"])
    return float(mat["density_kg_m3"]) * shape_volume(body["shape"])


def local_hull_points(shape: dict, sphere_samples: int = 0) -> np.ndarray:
    """Local points whose convex hull bounds the shape: box corners, wedge vertices and, for
    spheres, the centre ± r on each axis (or `sphere_samples` points on a Fibonacci sphere)."""
    pts = []
    for prim, offset, quat in shape_parts(shape):
        rot = quat_to_matrix(quat)
        kind = prim["type"]
        if kind == "box":
            local = box_corners(prim["size_m"])
        elif kind == "wedge":
            local = wedge_vertices(prim["length_m"], prim["height_m"], prim["width_m"])
        else:
            r = prim["radius_m"]
            if sphere_samples:
                i = np.arange(sphere_samples) + 0.5
                phi = np.arccos(1 - 2 * i / sphere_samples)
                theta = math.pi * (1 + 5 ** 0.5) * i
                local = r * np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi),
                                      np.cos(phi)], axis=1)
            else:
                local = r * np.vstack([np.eye(3), -np.eye(3)])
        pts.append(local @ rot.T + offset)
    return np.concatenate(pts)


def bounding_radius(shape: dict) -> float:
    """Radius of the smallest origin-centred sphere containing the shape."""
    r = 0.0
    for prim, offset, quat in shape_parts(shape):
        if prim["type"] == "sphere":
            r = max(r, float(np.linalg.norm(offset)) + prim["radius_m"])
        else:
            pts = local_hull_points({"type": "compound", "parts": [
                {"shape": prim, "offset_m": list(offset), "quat": quat}]})
            r = max(r, float(np.linalg.norm(pts, axis=1).max()))
    return r


def pose7(body: dict) -> np.ndarray:
    """The spec's initial pose of a body as (x, y, z, qx, qy, qz, qw)."""
    return np.array(list(body["pose"]["position_m"]) + list(body["pose"]["quat"]),
                    dtype=np.float64)


# ------------------------------------------------------------------------------- categories
def category_of_3d(body: dict) -> str:
    """Detection category of a body, from its geometry alone.

    sphere -> "circle"; box -> "line" when longest / shortest side >= 4 (a plank), else
    "rectangle"; wedge -> "triangle"; a compound of exactly three boxes -> "u_shape" (a
    container: base plus two walls); any other compound -> "composite_shape".
    """
    shape = body["shape"]
    kind = shape["type"]
    if kind == "sphere":
        return "circle"
    if kind == "box":
        size = sorted(float(s) for s in shape["size_m"])
        return "line" if size[2] / size[0] >= LINE_ASPECT else "rectangle"
    if kind == "wedge":
        return "triangle"
    parts = shape["parts"]
    if len(parts) == 3 and all(p["shape"]["type"] == "box" for p in parts):
        return "u_shape"
    return "composite_shape"


# ------------------------------------------------------------------------------- validation
_WHAT = "3D scene spec"


def _one_line(message: str) -> str:
    return message.replace("\n", " ")[:300]


def _unit_quat(spec: dict, q, where: str) -> None:
    n = math.sqrt(sum(float(v) ** 2 for v in q))
    if abs(n - 1.0) > 1e-6:
        fail(spec, _WHAT, where, f"quaternion must have unit norm (has {n:.6g})")


def _check_body(spec: dict, i: int, body: dict) -> None:
    """Unit quaternions, and a dynamic body's mass given exactly once."""
    where = f"$.bodies[{i}]"
    _unit_quat(spec, body["pose"]["quat"], f"{where}.pose.quat")
    if body["shape"]["type"] == "compound":
        for j, part in enumerate(body["shape"]["parts"]):
            _unit_quat(spec, part["quat"], f"{where}.shape.parts[{j}].quat")
    if body["dynamic"]:
        mat = body["material"]
        if ("mass_kg" in mat) == ("density_kg_m3" in mat):
            fail(spec, _WHAT, f"{where}.material", "give exactly one of mass_kg and density_kg_m3")


def _check_camera(spec: dict, cam: dict) -> None:
    if cam["width"] % 2 or cam["height"] % 2:
        fail(spec, _WHAT, "$.camera.width", "H.264 needs even image dimensions")
    view = np.asarray(cam["look_at"], dtype=np.float64) - np.asarray(cam["position"], float)
    up = np.asarray(cam.get("up", [0.0, 1.0, 0.0]), dtype=np.float64)
    if np.linalg.norm(view) < 1e-9 or np.linalg.norm(np.cross(view, up)) < 1e-9 * np.linalg.norm(
            view) * max(np.linalg.norm(up), 1e-300):
        fail(spec, _WHAT, "$.camera.look_at",
             "the view direction must be non-zero and not along up")
    if cam.get("near", 0.1) >= cam.get("far", 100.0):
        fail(spec, _WHAT, "$.camera.near", "near must be smaller than far")


def validate_spec_3d(spec: dict) -> None:
    """Raise ValueError("invalid 3D scene spec <id>: <json path>: <problem>") for the first
    problem (one line)."""
    check_schema(_VALIDATOR, spec, _WHAT, _one_line)
    world, cam = spec["world"], spec["camera"]
    if world["profile"] == PROFILE_NAME:
        check_profile(spec, _WHAT, PROFILE_NAME, [
            (f"$.{where}", value, PROFILE_3D[key]) for where, value, key in (
                ("world.gravity_m_s2", world["gravity_m_s2"], "gravity_m_s2"),
                ("world.dt_s", world["dt_s"], "dt_s"),
                ("world.steps_per_frame", world["steps_per_frame"], "steps_per_frame"),
                ("world.first_frame_after_steps", world["first_frame_after_steps"],
                 "first_frame_after_steps"),
                ("world.n_frames", world["n_frames"], "n_frames"),
                ("world.video_fps", world["video_fps"], "video_fps"),
                ("camera.width", cam["width"], "width"),
                ("camera.height", cam["height"], "height"))])
    _check_camera(spec, cam)
    ids = check_bodies(spec, _WHAT, (FLOOR_ID,), category_of_3d,
                       lambda i, body: _check_body(spec, i, body))
    check_contact_pairs(spec, _WHAT, ids | {FLOOR_ID})


#: JSON Schema of the scene specification S a model writes for a 3D scene
#: (`visphy_core.spec.validation.reply_schema`).
REPLY_SCHEMA_3D: dict[str, Any] = reply_schema(
    "3d", {"type": "object", "properties": {"gravity_m_s2": _VEC3},
           "required": ["gravity_m_s2"]}, _BODY)
