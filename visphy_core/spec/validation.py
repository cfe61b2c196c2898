"""What the 2D and 3D scene specifications share (`spec2d`, `spec3d`): the JSON Schema building
blocks, the validation steps (the schema's first problem as a one-line JSON path, the profile's
constants, unique and reserved ids, each body's category, the contact pairs) and the contact
table. Each dimension adds its own schema, geometry and checks on top.

A problem is a `ValueError` naming the spec and the JSON path:
``invalid <what> <scene id>: <json path>: <problem>``.
"""

from __future__ import annotations

from typing import Any, Callable, Iterable, NoReturn

import jsonschema
import numpy as np

from visphy_core.api.scene import SPEC_SCHEMA

#: Detection categories of a body (2D and 3D alike).
CATEGORIES = ("circle", "rectangle", "line", "u_shape", "triangle", "composite_shape")

# ------------------------------------------------------------------ JSON Schema building blocks
NUM = {"type": "number"}
NONNEG = {"type": "number", "minimum": 0}
POS = {"type": "number", "exclusiveMinimum": 0}
RGB = {"type": "array", "items": {"type": "integer", "minimum": 0, "maximum": 255},
       "minItems": 3, "maxItems": 3}
ID_LIST = {"type": "array", "items": {"type": "string"}}
#: ``world.engine``: the name a physics plugin registered (`visphy_core.api.physics`); whether
#: one did, for the spec's ``dim``, is checked when the spec is simulated, not here.
SIMULATOR = {"type": "string", "minLength": 1}
PAIR_LIST = {"type": "array", "items": {"type": "array", "items": {"type": "string"},
                                        "minItems": 2, "maxItems": 2}}
BODY_ID = {"type": "string", "pattern": r"^[a-z][a-z0-9_]*$"}


def obj(props: dict[str, Any], required: list[str] | None = None, extra: bool = False) -> dict:
    """A closed object schema; every property is required unless ``required`` says otherwise."""
    return {"type": "object", "properties": props,
            "required": list(props) if required is None else required,
            "additionalProperties": extra}


def shape_case(kind: str, props: dict[str, Any]) -> dict:
    """The ``if type == kind then exactly these properties`` case of a shape schema."""
    return {"if": {"properties": {"type": {"const": kind}}, "required": ["type"]},
            "then": obj({"type": {"const": kind}, **props})}


CONTACT = obj({"friction": NONNEG, "restitution": NONNEG})
CONTACT_PAIR = obj({"a": {"type": "string"}, "b": {"type": "string"}, "friction": NONNEG,
                    "restitution": NONNEG})
#: A ground-truth spec's ``contacts``: the default material and the per-pair values.
CONTACTS = obj({"default": CONTACT, "pairs": {"type": "array", "items": CONTACT_PAIR}})
#: The ``contacts`` a model's spec S may state (nothing required).
REPLY_CONTACTS = {"type": "object", "properties": {
    "default": CONTACT, "pairs": {"type": "array", "items": CONTACT_PAIR}}}
EVENT = obj({"t_s": NONNEG, "step": {"type": "integer", "minimum": 0},
             "type": {"enum": ["contact_begin"]}, "a": {"type": "string"},
             "b": {"type": "string"}, "normal_speed_m_s": NUM},
            required=["t_s", "type", "a", "b"])


def body_schema(shape: dict, pose: dict, velocity: dict, material: dict,
                **extra: dict) -> dict:
    """A body: id, category, dynamic, colour, shape and pose always; a dynamic body needs a mass
    and an initial state too (``velocity``, ``material``), a static one may omit both."""
    return {**obj({"id": BODY_ID, "category": {"enum": list(CATEGORIES)},
                   "dynamic": {"type": "boolean"}, "color_rgb": RGB, "shape": shape,
                   "pose": pose, "velocity": velocity, "material": material, **extra},
                  required=["id", "category", "dynamic", "color_rgb", "shape", "pose"]),
            "if": {"properties": {"dynamic": {"const": True}}},
            "then": {"required": ["velocity", "material"]}}


def reply_schema(dim: str, world: dict, body: dict) -> dict:
    """JSON Schema of the scene specification S a model writes: the ground truth's schema for
    bodies and contacts, with only what a model can infer from the frames required (no scene
    id, difficulty, solver or ground-truth sections)."""
    return {"$schema": "https://json-schema.org/draft/2020-12/schema",
            "title": f"visphy scene specification S written by a model ({dim.upper()})",
            "type": "object",
            "properties": {"schema": {"const": SPEC_SCHEMA}, "dim": {"const": dim},
                           "world": world,
                           "bodies": {"type": "array", "items": body, "minItems": 1},
                           "contacts": REPLY_CONTACTS},
            "required": ["world", "bodies"]}


def ground_truth_schema(identifiable_open: bool = False) -> dict:
    """A spec's ``ground_truth`` section; ``identifiable_open``: its ``identifiable`` keys are
    all optional and others are allowed (the 3D spec)."""
    identifiable = {"gravity": {"type": "boolean"}, "initial_velocity": ID_LIST,
                    "restitution": PAIR_LIST, "friction": PAIR_LIST, "mass_ratio": PAIR_LIST}
    return obj({"trajectory": {"type": ["string", "null"]},
                "events": {"type": "array", "items": EVENT},
                "identifiable": (obj(identifiable, required=[], extra=True)
                                 if identifiable_open else obj(identifiable))},
               required=["trajectory", "events", "identifiable"])


# ------------------------------------------------------------------------------ validation
def json_path(parts: Iterable[Any]) -> str:
    """``$.a[0].b`` of a path given as keys and indices."""
    out = "$"
    for p in parts:
        out += f"[{p}]" if isinstance(p, int) else f".{p}"
    return out


def fail(spec: Any, what: str, path: str, message: str) -> NoReturn:
    """Raise the one-line problem of ``spec`` (``what``: e.g. ``"scene spec"``) at ``path``."""
    sid = spec.get("scene_id", "<no scene_id>") if isinstance(spec, dict) else "<not an object>"
    raise ValueError(f"invalid {what} {sid}: {path}: {message}")


def check_schema(validator: jsonschema.protocols.Validator, spec: Any, what: str,
                 clean: Callable[[str], str] = str) -> None:
    """The first problem the JSON Schema finds, at its concrete path: a missing field, an
    unknown field, or the validator's message (passed through ``clean``)."""
    errors = list(validator.iter_errors(spec))
    if not errors:
        return
    err = jsonschema.exceptions.best_match(errors)
    while err.context:  # descend into if/then/allOf to the concrete failure
        err = jsonschema.exceptions.best_match(err.context)
    parts = list(err.absolute_path)
    if err.validator == "required" and isinstance(err.instance, dict):
        missing = [r for r in err.validator_value if r not in err.instance]
        parts.append(missing[0] if missing else "?")
        fail(spec, what, json_path(parts), "required field is missing")
    if err.validator == "additionalProperties" and isinstance(err.instance, dict):
        allowed = set(err.schema.get("properties", {}))
        unknown = sorted(k for k in err.instance if k not in allowed)
        parts.append(unknown[0] if unknown else "?")
        fail(spec, what, json_path(parts), "unknown field")
    fail(spec, what, json_path(parts), clean(err.message))


def check_profile(spec: dict, what: str, profile: str,
                  checks: Iterable[tuple[str, Any, Any]]) -> None:
    """Each (JSON path, value, the profile's value) must match: strings exactly, numbers and
    vectors to 1e-12."""
    for where, value, want in checks:
        same = value == want if isinstance(want, str) else np.allclose(
            value, want, rtol=1e-12, atol=1e-12)
        if not same:
            fail(spec, what, where, f"profile {profile!r} requires {want}")


def check_bodies(spec: dict, what: str, reserved: Iterable[str],
                 category_of: Callable[[dict], str],
                 check_body: Callable[[int, dict], None] | None = None) -> set[str]:
    """Every body: an id neither repeated nor ``reserved``, then ``check_body(index, body)``
    (the dimension's own checks), then a category its geometry agrees with. Returns the ids."""
    reserved = set(reserved)
    seen: set[str] = set()
    for i, body in enumerate(spec["bodies"]):
        if body["id"] in seen or body["id"] in reserved:
            fail(spec, what, f"$.bodies[{i}].id", f"duplicate or reserved id {body['id']!r}")
        seen.add(body["id"])
        if check_body is not None:
            check_body(i, body)
        if body["category"] != category_of(body):
            fail(spec, what, f"$.bodies[{i}].category",
                 f"{body['category']!r} but the geometry says {category_of(body)!r}")
    return seen


def check_contact_pairs(spec: dict, what: str, known: set[str]) -> None:
    """Every contact pair names two different ``known`` bodies, and no pair is repeated."""
    pairs: set[frozenset[str]] = set()
    for k, pair in enumerate(spec["contacts"]["pairs"]):
        for side in ("a", "b"):
            if pair[side] not in known:
                fail(spec, what, f"$.contacts.pairs[{k}].{side}",
                     f"unknown body id {pair[side]!r}")
        key = frozenset((pair["a"], pair["b"]))
        if key in pairs or len(key) < 2:
            fail(spec, what, f"$.contacts.pairs[{k}]",
                 "pair repeated or a body paired with itself")
        pairs.add(key)


def contact_table(spec: dict) -> tuple[dict[str, float], dict[frozenset[str], dict[str, float]]]:
    """Default contact material and the explicit per-pair values, keyed by unordered id pair."""
    contacts = spec["contacts"]
    pairs = {frozenset((p["a"], p["b"])): {"friction": float(p["friction"]),
                                           "restitution": float(p["restitution"])}
             for p in contacts["pairs"]}
    return {k: float(v) for k, v in contacts["default"].items()}, pairs
