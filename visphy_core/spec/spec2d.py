"""Scene specification `visphy-scene/1` for generated 2D scenes: JSON Schema, validation, geometry.

The spec is the single source of ground truth for a generated scene: the simulator, the rasteriser,
the detection context and any engine that re-renders the scene all read the same file, so the
conventions below are fixed here once:

* lengths are pixels, origin bottom-left, y up; angles radians, counter-clockwise;
  simulator metres = pixels / `world.units.px_per_m`;
* a body's pose is the position of its local origin; shapes are given in local pixel coordinates:
  circle `{radius_px}`, box `{length_px, thickness_px}` (centred, length along local x),
  polygon `{vertices_px}` (convex, counter-clockwise), compound `{parts_px}` (convex CCW parts);
* PHYRE walls are static boxes just outside the canvas, named `wall_bottom|left|right|top`, so
  contact pairs may name them.

`validate_spec` adds the checks JSON Schema cannot express (unique ids, convexity, constants of
the PHYRE profile, category consistency) and reports the first problem on one line with its path;
the steps and schema parts it shares with the 3D spec are in `visphy_core.spec.validation`.
"""

from __future__ import annotations

import math
from typing import Any

import jsonschema
import numpy as np

from visphy_core.api.scene import SPEC_SCHEMA
from visphy_core.spec.validation import CATEGORIES as CATEGORIES  # 2D callers' name
from visphy_core.spec.validation import (
    CONTACTS,
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

#: Constants of PHYRE's world; a spec with profile "phyre" must use them.
PHYRE_PROFILE: dict[str, Any] = {
    "px_per_m": 6.0,
    "canvas_px": [512, 512],
    "gravity_m_s2": [0.0, -9.8],
    "dt_s": 1.0 / 60.0,
    "velocity_iterations": 15,
    "position_iterations": 20,
    "steps_per_frame": 60,
    "first_frame_after_steps": 1,
    "density_kg_m2": 0.25,
    "friction": 0.5,
    "restitution": 0.2,
    "bar_thickness_px": 512 / 50,
}
WALL_IDS = ("wall_bottom", "wall_left", "wall_right", "wall_top")
#: The usual polygon limit of 2D rigid-body simulators: a convex part has at most this many
#: vertices.
MAX_POLYGON_VERTICES = 8

_VEC2 = {"type": "array", "items": NUM, "minItems": 2, "maxItems": 2}
_POLY = {"type": "array", "items": _VEC2, "minItems": 3, "maxItems": MAX_POLYGON_VERTICES}

_MATERIAL = obj({"density_kg_m2": POS, "friction": NONNEG, "restitution": NONNEG})
_SHAPE = {
    "type": "object",
    "required": ["type"],
    "properties": {"type": {"enum": ["circle", "box", "polygon", "compound"]}},
    "allOf": [
        shape_case("circle", {"radius_px": POS}),
        shape_case("box", {"length_px": POS, "thickness_px": POS}),
        shape_case("polygon", {"vertices_px": _POLY}),
        shape_case("compound", {"parts_px": {"type": "array", "items": _POLY, "minItems": 1}}),
    ],
}
_BODY = body_schema(_SHAPE, obj({"x_px": NUM, "y_px": NUM, "angle_rad": NUM}),
                    obj({"vx_px_s": NUM, "vy_px_s": NUM, "omega_rad_s": NUM}), _MATERIAL)

#: JSON Schema (draft 2020-12) of `visphy-scene/1` for 2D scenes.
SPEC_JSON_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "visphy scene specification (2D)",
    **obj(
        {
            "schema": {"const": SPEC_SCHEMA},
            # generated ids (`vpb3-s0-2d-t001-v00`); builds before version 3 used task-style ids
            "scene_id": {"type": "string",
                         "pattern": r"^(vpb\d+-s\d+-2d-t\d{3}-v\d{2}|task\d{5}_\d{3})$"},
            "template_id": {"type": "string", "pattern": r"^\d{5}$"},
            "variant": {"type": "integer", "minimum": 0},
            "seed": {"type": "integer", "minimum": 0},
            "dim": {"const": "2d"},
            "family": {"type": "string"},
            "description": {"type": "string"},
            "difficulty": obj({"label": {"enum": ["easy", "medium", "hard"]}, "score": NUM,
                                "features": {"type": "object"}}),
            "world": obj(
                {
                    "engine": SIMULATOR,
                    "engine_version": {"type": "string"},
                    "profile": {"type": "string"},
                    "units": obj({"px_per_m": POS,
                                   "canvas_px": {"type": "array", "minItems": 2, "maxItems": 2,
                                                 "items": {"type": "integer", "minimum": 2}},
                                   "origin": {"const": "bottom-left"}, "y_up": {"const": True},
                                   "angles": {"const": "rad_ccw"}}),
                    "gravity_m_s2": _VEC2,
                    "dt_s": POS,
                    "solver": obj({"velocity_iterations": {"type": "integer", "minimum": 1},
                                    "position_iterations": {"type": "integer", "minimum": 1}}),
                    "steps_per_frame": {"type": "integer", "minimum": 1},
                    "first_frame_after_steps": {"type": "integer", "minimum": 0},
                    "n_frames": {"type": "integer", "minimum": 1},
                    "video_fps": POS,
                    "walls": obj({"thickness_px": POS,
                                   "sides": {"type": "array", "items": {"enum": ["bottom", "left",
                                             "right", "top"]}, "uniqueItems": True}}),
                    "damping": obj({"linear": NONNEG, "angular": NONNEG}),
                    "allow_sleep": {"type": "boolean"},
                },
                required=["engine", "profile", "units", "gravity_m_s2", "dt_s", "solver",
                          "steps_per_frame", "first_frame_after_steps", "n_frames", "video_fps",
                          "walls", "damping"],
            ),
            "render": obj({"background_rgb": RGB, "antialias": {"const": False},
                            "codec": {"type": "string"}, "pix_fmt": {"type": "string"}},
                           required=["background_rgb", "antialias"]),
            "bodies": {"type": "array", "items": _BODY, "minItems": 1},
            "contacts": CONTACTS,
            "ground_truth": ground_truth_schema(),
            "digest_sha256": {"type": ["string", "null"]},
        },
        required=["schema", "scene_id", "template_id", "variant", "seed", "dim", "difficulty",
                  "world", "render", "bodies", "contacts", "ground_truth"],
    ),
}

_VALIDATOR = jsonschema.Draft202012Validator(SPEC_JSON_SCHEMA)


# ----------------------------------------------------------------------------------- geometry
def local_polygons(shape: dict) -> list[np.ndarray]:
    """Convex CCW parts (k×2 float64, local px) of a non-circle shape; circles have none."""
    kind = shape["type"]
    if kind == "box":
        hx, hy = shape["length_px"] / 2.0, shape["thickness_px"] / 2.0
        return [np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]], dtype=np.float64)]
    if kind == "polygon":
        return [np.asarray(shape["vertices_px"], dtype=np.float64)]
    if kind == "compound":
        return [np.asarray(p, dtype=np.float64) for p in shape["parts_px"]]
    return []


def transform_points(points: np.ndarray, pose: tuple[float, float, float]) -> np.ndarray:
    """Rotate local points CCW by the pose angle, then translate (world px, y up)."""
    x, y, a = pose
    c, s = math.cos(a), math.sin(a)
    pts = np.asarray(points, dtype=np.float64)
    return np.stack([x + c * pts[:, 0] - s * pts[:, 1], y + s * pts[:, 0] + c * pts[:, 1]], axis=1)


def polygon_area_centroid(poly: np.ndarray) -> tuple[float, float, float]:
    """Signed area (positive for CCW) and centroid of a simple polygon (shoelace formula)."""
    x, y = poly[:, 0], poly[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    area = cross.sum() / 2.0
    if area == 0:
        return 0.0, float(x.mean()), float(y.mean())
    return float(area), float(((x + xn) * cross).sum() / (6 * area)), float(
        ((y + yn) * cross).sum() / (6 * area))


def shape_area_centroid(shape: dict) -> tuple[float, float, float]:
    """Area and local centroid of a shape; compound parts are assumed not to overlap."""
    if shape["type"] == "circle":
        return math.pi * shape["radius_px"] ** 2, 0.0, 0.0
    parts = [polygon_area_centroid(p) for p in local_polygons(shape)]
    total = sum(a for a, _, _ in parts)
    return (total, sum(a * cx for a, cx, _ in parts) / total,
            sum(a * cy for a, _, cy in parts) / total)


def _convex_ccw_problem(poly: np.ndarray) -> str | None:
    """Why a vertex list is not a strictly convex CCW polygon, or None when it is."""
    edges = np.roll(poly, -1, axis=0) - poly
    nxt = np.roll(edges, -1, axis=0)
    cross = edges[:, 0] * nxt[:, 1] - edges[:, 1] * nxt[:, 0]
    if polygon_area_centroid(poly)[0] <= 1e-9:
        return "vertices must be counter-clockwise with positive area"
    if np.any(cross <= 1e-12):
        return "polygon must be strictly convex"
    return None


# ------------------------------------------------------------------------------- categories
def category_of(body: dict) -> str:
    """Detection category of a body, derived from its geometry alone.

    Rule: circle -> "circle"; a box (or a rectangular 4-gon) is a "line" when
    length / thickness >= 4 (PHYRE bars are W/50 thick) and a "rectangle" otherwise; a 3-vertex
    polygon is a "triangle"; a compound of exactly three parts is a "u_shape" (PHYRE jar: base plus
    two walls); any other polygon or compound (e.g. standing sticks, an X of two bars) is a
    "composite_shape".
    """
    shape = body["shape"]
    kind = shape["type"]
    if kind == "circle":
        return "circle"
    if kind == "box":
        long, short = max(shape["length_px"], shape["thickness_px"]), min(
            shape["length_px"], shape["thickness_px"])
        return "line" if long / short >= 4.0 else "rectangle"
    if kind == "polygon":
        poly = np.asarray(shape["vertices_px"], dtype=np.float64)
        if len(poly) == 3:
            return "triangle"
        if len(poly) == 4:
            e = np.roll(poly, -1, axis=0) - poly
            dots = np.abs((e * np.roll(e, -1, axis=0)).sum(axis=1))
            lens = np.hypot(e[:, 0], e[:, 1])
            if np.all(dots <= 1e-6 * lens * np.roll(lens, -1)):
                return "line" if lens.max() / lens.min() >= 4.0 else "rectangle"
        return "composite_shape"
    return "u_shape" if len(shape["parts_px"]) == 3 else "composite_shape"


# ------------------------------------------------------------------------------- validation
_WHAT = "scene spec"


def validate_spec(spec: dict) -> None:
    """Raise ValueError("invalid scene spec <id>: <json path>: <problem>") for the first problem."""
    check_schema(_VALIDATOR, spec, _WHAT)
    world = spec["world"]
    if world["profile"] == "phyre":
        units, solver = world["units"], world["solver"]
        check_profile(spec, _WHAT, "phyre", [
            (f"$.world.{where}", value, PHYRE_PROFILE[key]) for where, value, key in (
                ("units.px_per_m", units["px_per_m"], "px_per_m"),
                ("units.canvas_px", units["canvas_px"], "canvas_px"),
                ("gravity_m_s2", world["gravity_m_s2"], "gravity_m_s2"),
                ("dt_s", world["dt_s"], "dt_s"),
                ("solver.velocity_iterations", solver["velocity_iterations"],
                 "velocity_iterations"),
                ("solver.position_iterations", solver["position_iterations"],
                 "position_iterations"),
                ("steps_per_frame", world["steps_per_frame"], "steps_per_frame"),
                ("first_frame_after_steps", world["first_frame_after_steps"],
                 "first_frame_after_steps"))])
    w, h = world["units"]["canvas_px"]
    if w % 2 or h % 2:
        fail(spec, _WHAT, "$.world.units.canvas_px", "H.264 needs even canvas dimensions")

    def convex_parts(i: int, body: dict) -> None:
        key = "parts_px" if body["shape"]["type"] == "compound" else "vertices_px"
        for j, poly in enumerate(local_polygons(body["shape"])):
            problem = _convex_ccw_problem(poly)
            if problem:
                where = f"$.bodies[{i}].shape.{key}" + (f"[{j}]" if key == "parts_px" else "")
                fail(spec, _WHAT, where, problem)

    ids = check_bodies(spec, _WHAT, WALL_IDS, category_of, convex_parts)
    check_contact_pairs(spec, _WHAT, ids | set(WALL_IDS))


#: JSON Schema of the scene specification S a model writes for a 2D scene
#: (`visphy_core.spec.validation.reply_schema`).
REPLY_SCHEMA_2D: dict[str, Any] = reply_schema(
    "2d", {"type": "object",
           "properties": {"gravity_m_s2": _VEC2,
                          "units": {"type": "object", "properties": {"px_per_m": POS}}},
           "required": ["gravity_m_s2"]}, _BODY)
