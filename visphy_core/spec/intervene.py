"""Interventions: a scene spec with named physical parameters changed, and what the change did.

"Would the red ball still land in the jar on the Moon?" A benchmark scene (or a model's scene
specification S) is data, so a counterfactual is an edit of that data followed by the same
simulation the ground truth comes from. This module owns the edit and the comparison; the
command (`visphy_core.cli.intervene`) simulates both specs and renders them with the engine's
trusted reference program (the path the spec track and the variance normalisation use).

An assignment is ``PARAM=VALUE`` (every body, or the world) or ``PARAM.OBJECT=VALUE`` (one
body, named by its id; ``"red ball"`` and ``Red-Ball`` mean ``red_ball``). VALUE is a number, a
comma-separated vector, or ``xF``: F times the current value (``gravity=x2``). Parameters, in
SI units whatever the scene's own units (a 2D spec stores pixels; the conversion uses its
``px_per_m``):

====================  =========  ==============================================================
parameter             unit       what it sets
====================  =========  ==============================================================
gravity               m/s²       a number: the vertical (y, up) component; a vector: all of it
friction              –          contact friction (≥ 0): the default and every pair; with
                                 ``.OBJECT``, every contact of that body (walls, floor included)
restitution           –          contact restitution (≥ 0), as friction
mass                  kg         a dynamic body's mass (> 0; 2D: its density over its area)
velocity              m/s        a dynamic body's initial linear velocity (a vector, y up)
angular_velocity      rad/s      its initial angular velocity (2D: a number, CCW; 3D: a vector)
====================  =========  ==============================================================

Contacts use the spec's explicit contact table (`validation.contact_table`): a body-level change
writes an explicit pair for each partner the body has, starting from the pair's current values,
so nothing depends on a material-mixing rule. Every value is checked against the range the
spec's JSON Schema gives the field, and the edited spec is validated as a whole (its profile
becomes ``intervention``: a benchmark profile pins gravity). Errors are one line naming the valid
parameters or objects (`UserError`).
"""

from __future__ import annotations

import copy
import math
import re
from dataclasses import dataclass, field
from typing import Any

import jsonschema
import numpy as np

from visphy_core.infra.errors import UserError
from visphy_core.spec.spec2d import shape_area_centroid
from visphy_core.spec.spec3d import FLOOR_ID, body_mass
from visphy_core.spec.validation import NONNEG, NUM, POS
from visphy_core.spec.spec_track import MAX_SPEED

PROFILE = "intervention"


@dataclass(frozen=True)
class Parameter:
    """One parameter a user may set: its unit, where it applies and the schema range of a
    value (a JSON Schema fragment of `visphy_core.spec.spec2d`)."""

    name: str
    unit: str
    scope: str            # "world", "contact" or "dynamic" (a dynamic body's state)
    schema: dict
    help: str


PARAMETERS: dict[str, Parameter] = {p.name: p for p in (
    Parameter("gravity", "m/s²", "world", NUM, "number (vertical) or vector"),
    Parameter("friction", "", "contact", NONNEG, "contact friction ≥ 0"),
    Parameter("restitution", "", "contact", NONNEG, "contact restitution ≥ 0"),
    Parameter("mass", "kg", "dynamic", POS, "mass > 0"),
    Parameter("velocity", "m/s", "dynamic", NUM, "initial velocity vector"),
    Parameter("angular_velocity", "rad/s", "dynamic", NUM, "initial angular velocity"),
)}


@dataclass(frozen=True)
class Assignment:
    """One ``--set``: ``parameter[.object]=value`` as the user wrote it."""

    text: str
    parameter: str
    obj: str | None
    factor: float | None          # ``xF``: scale the current value
    values: tuple[float, ...]     # a number or a vector (empty for a factor)


@dataclass
class Change:
    """What one assignment changed: the values before and after, one per spec field touched
    (``fields``: JSON paths), in the parameter's SI unit."""

    parameter: str
    object: str | None
    unit: str
    assignment: str
    fields: list[str] = field(default_factory=list)
    old: list[Any] = field(default_factory=list)
    new: list[Any] = field(default_factory=list)

    def to_json(self) -> dict:
        def one(values: list[Any]) -> Any:
            distinct = {repr(v) for v in values}
            return values[0] if len(distinct) == 1 else dict(zip(self.fields, values))

        return {"parameter": self.parameter, "object": self.object, "unit": self.unit,
                "set": self.assignment, "old": one(self.old), "new": one(self.new),
                "fields": self.fields}

    def describe(self) -> str:
        def fmt(values: list[Any]) -> str:
            shown = sorted({_fmt(v) for v in values})
            return shown[0] if len(shown) == 1 else "{" + ", ".join(shown) + "}"

        where = f"{self.parameter}.{self.object}" if self.object else self.parameter
        unit = f" {self.unit}" if self.unit else ""
        return f"{where}: {fmt(self.old)} → {fmt(self.new)}{unit}"


def _fmt(value: Any) -> str:
    if isinstance(value, (list, tuple)):
        return "(" + ", ".join(_fmt(v) for v in value) + ")"
    return f"{float(value) + 0.0:.4g}"  # + 0.0: never "-0"


# ------------------------------------------------------------------------------------ parsing
_NAME = re.compile(r"^(?P<param>[A-Za-z_]+)(?:\.(?P<obj>.+))?$")


def object_key(name: str) -> str:
    """``"Red ball"`` → ``red_ball``: how a user may name a body."""
    return re.sub(r"[\s\-]+", "_", name.strip()).lower()


def parse_assignment(text: str) -> Assignment:
    """Parse ``PARAM[.OBJECT]=VALUE`` (`UserError` naming the valid parameters)."""
    name, sep, value = text.partition("=")
    match = _NAME.match(name.strip())
    if not sep or not match or not value.strip():
        raise UserError(f"--set {text!r}: write PARAM=VALUE or PARAM.OBJECT=VALUE, e.g. "
                        f"gravity=-20, friction.red_ball=0.1; parameters: {', '.join(PARAMETERS)}")
    param = match.group("param").lower()
    if param not in PARAMETERS:
        raise UserError(f"--set {text!r}: unknown parameter {param!r}; valid parameters: "
                        f"{', '.join(PARAMETERS)}")
    obj = object_key(match.group("obj")) if match.group("obj") else None
    if obj is not None and PARAMETERS[param].scope == "world":
        raise UserError(f"--set {text!r}: {param} belongs to the world, not to a body; write "
                        f"{param}=VALUE")
    value = value.strip()
    try:
        if value[:1] in ("x", "X", "*"):
            factor = float(value[1:])
            if not math.isfinite(factor):
                raise ValueError
            return Assignment(text, param, obj, factor, ())
        values = tuple(float(v) for v in value.split(","))
    except ValueError:
        raise UserError(f"--set {text!r}: {value!r} is not a number, a comma-separated vector or "
                        "xF (F times the current value)") from None
    if not all(math.isfinite(v) for v in values):
        raise UserError(f"--set {text!r}: values must be finite")
    return Assignment(text, param, obj, None, values)


# ----------------------------------------------------------------------------------- applying
def _check_range(assignment: Assignment, value: float) -> None:
    schema = PARAMETERS[assignment.parameter].schema
    try:
        jsonschema.validate(value, schema)
    except jsonschema.ValidationError:
        bound = (f"≥ {schema['minimum']:g}" if "minimum" in schema
                 else f"> {schema['exclusiveMinimum']:g}")
        raise UserError(f"--set {assignment.text!r}: {assignment.parameter} must be {bound} "
                        f"(the scene spec's range), got {value:g}") from None


class _Editor:
    """Applies assignments to a deep copy of one spec, recording a `Change` per assignment."""

    def __init__(self, spec: dict):
        self.spec = copy.deepcopy(spec)
        self.dim = spec["dim"]
        self.ppm = float(spec["world"].get("units", {}).get("px_per_m", 1.0)) \
            if self.dim == "2d" else 1.0
        self.bodies = {b["id"]: b for b in self.spec["bodies"]}
        self.partners_extra = ([f"wall_{s}" for s in spec["world"]["walls"]["sides"]]
                               if self.dim == "2d" else [FLOOR_ID])

    # -- values
    def new_value(self, a: Assignment, old: Any, size: int | None = None) -> Any:
        """The assigned value for a field whose current value is ``old``; ``size`` is the
        vector length the field needs (None: a number)."""
        if a.factor is not None:
            new = [v * a.factor for v in old] if size else old * a.factor
        elif size is None:
            if len(a.values) != 1:
                raise UserError(f"--set {a.text!r}: {a.parameter} takes one number")
            new = a.values[0]
        else:
            if len(a.values) != size:
                axes = "vx,vy" if size == 2 else "x,y,z"
                raise UserError(f"--set {a.text!r}: {a.parameter} takes {size} components "
                                f"({axes}) in a {self.dim.upper()} scene")
            new = list(a.values)
        for v in (new if isinstance(new, list) else [new]):
            _check_range(a, v)
        return new

    # -- targets
    def targets(self, a: Assignment) -> list[str]:
        """Body ids the assignment applies to (every eligible body when it names none)."""
        scope = PARAMETERS[a.parameter].scope
        eligible = [b["id"] for b in self.spec["bodies"] if scope != "dynamic" or b["dynamic"]]
        if a.obj is None:
            return eligible
        known = list(self.bodies) + (self.partners_extra if scope == "contact" else [])
        if a.obj not in known:
            raise UserError(f"--set {a.text!r}: unknown object {a.obj!r}; objects of scene "
                            f"{self.spec.get('scene_id')}: {', '.join(known)}")
        if a.obj not in eligible and a.obj in self.bodies:
            raise UserError(f"--set {a.text!r}: {a.obj!r} is static; {a.parameter} applies to "
                            f"dynamic bodies: {', '.join(eligible) or 'none'}")
        return [a.obj]

    def apply(self, a: Assignment) -> Change:
        param = PARAMETERS[a.parameter]
        change = Change(a.parameter, a.obj, param.unit, a.text)
        if param.scope == "world":
            self._gravity(a, change)
        elif param.scope == "contact":
            self._contact(a, change)
        else:
            for bid in self.targets(a):
                getattr(self, f"_{a.parameter}")(a, self.bodies[bid], change)
        return change

    def _record(self, change: Change, where: str, old: Any, new: Any) -> None:
        change.fields.append(where)
        change.old.append(old)
        change.new.append(new)

    def _gravity(self, a: Assignment, change: Change) -> None:
        world = self.spec["world"]
        old = [float(v) for v in world["gravity_m_s2"]]
        if a.factor is None and len(a.values) == 1:
            new = list(old)
            new[1] = self.new_value(a, old[1])
        else:
            new = self.new_value(a, old, size=len(old))
        world["gravity_m_s2"] = new
        self._record(change, "$.world.gravity_m_s2", old, new)

    def _contact(self, a: Assignment, change: Change) -> None:
        key = a.parameter
        contacts = self.spec["contacts"]
        if a.obj is None:
            default = contacts["default"]
            new = self.new_value(a, float(default[key]))
            self._record(change, f"$.contacts.default.{key}", float(default[key]), new)
            default[key] = new
            for i, pair in enumerate(contacts["pairs"]):
                new = self.new_value(a, float(pair[key]))
                self._record(change, f"$.contacts.pairs[{i}].{key}", float(pair[key]), new)
                pair[key] = new
            for body in self.spec["bodies"]:
                if "material" in body:
                    body["material"][key] = self.new_value(a, float(body["material"][key]))
            return
        (obj,) = self.targets(a)
        index = {frozenset((p["a"], p["b"])): p for p in contacts["pairs"]}
        for partner in [b for b in list(self.bodies) + self.partners_extra if b != obj]:
            pair = index.get(frozenset((obj, partner)))
            if pair is None:
                pair = {"a": obj, "b": partner, **{k: float(v) for k, v in
                                                   contacts["default"].items()}}
                contacts["pairs"].append(pair)
            new = self.new_value(a, float(pair[key]))
            self._record(change, f"$.contacts.pairs[{obj}|{partner}].{key}", float(pair[key]),
                         new)
            pair[key] = new
        body = self.bodies.get(obj)
        if body is not None and "material" in body:
            body["material"][key] = self.new_value(a, float(body["material"][key]))

    def _mass(self, a: Assignment, body: dict, change: Change) -> None:
        mat = body["material"]
        if self.dim == "2d":
            area_m2 = shape_area_centroid(body["shape"])[0] / self.ppm ** 2
            old = float(mat["density_kg_m2"]) * area_m2
            new = self.new_value(a, old)
            mat["density_kg_m2"] = new / area_m2
        else:
            old = body_mass(body)
            new = self.new_value(a, old)
            mat.pop("density_kg_m3", None)
            mat["mass_kg"] = new
        self._record(change, f"$.bodies[{body['id']}].mass", old, new)

    def _velocity(self, a: Assignment, body: dict, change: Change) -> None:
        vel = body["velocity"]
        if self.dim == "2d":
            old = [vel["vx_px_s"] / self.ppm, vel["vy_px_s"] / self.ppm]
            new = self.new_value(a, old, size=2)
            vel["vx_px_s"], vel["vy_px_s"] = new[0] * self.ppm, new[1] * self.ppm
        else:
            old = [float(v) for v in vel["linear_m_s"]]
            new = self.new_value(a, old, size=3)
            vel["linear_m_s"] = new
        if float(np.linalg.norm(new)) > MAX_SPEED:
            raise UserError(f"--set {a.text!r}: a speed above {MAX_SPEED:g} m/s is not physics")
        self._record(change, f"$.bodies[{body['id']}].velocity", old, new)

    def _angular_velocity(self, a: Assignment, body: dict, change: Change) -> None:
        vel = body["velocity"]
        if self.dim == "2d":
            old = float(vel["omega_rad_s"])
            new = self.new_value(a, old)
            vel["omega_rad_s"] = new
        else:
            old = [float(v) for v in vel["angular_rad_s"]]
            new = self.new_value(a, old, size=3)
            vel["angular_rad_s"] = new
        self._record(change, f"$.bodies[{body['id']}].angular_velocity", old, new)


def intervened_spec(spec: dict, assignments: list[str]) -> tuple[dict, list[Change]]:
    """``spec`` (a full, valid scene spec) with ``assignments`` applied in order, validated,
    and the changes made (`UserError` for a bad assignment or an edited spec that is invalid)."""
    if not assignments:
        raise UserError("name at least one change: --set PARAM=VALUE (parameters: "
                        f"{', '.join(PARAMETERS)})")
    editor = _Editor(spec)
    changes = [editor.apply(parse_assignment(text)) for text in assignments]
    out = editor.spec
    out["world"]["profile"] = PROFILE
    try:
        if out["dim"] == "2d":
            from visphy_core.spec.spec2d import validate_spec

            validate_spec(out)
        else:
            from visphy_core.spec.spec3d import validate_spec_3d

            validate_spec_3d(out)
    except (ValueError, KeyError) as exc:
        raise UserError(f"the intervened spec is not valid: {str(exc).splitlines()[0]}") from None
    return out, changes


# --------------------------------------------------------------------------------- comparing
def _first_contacts(events: list[dict], body: str) -> tuple[dict | None, int]:
    mine = [e for e in events if body in (e["a"], e["b"])]
    if not mine:
        return None, 0
    e = mine[0]
    return {"t_s": float(e["t_s"]), "with": e["b"] if e["a"] == body else e["a"]}, len(mine)


def compare_rollouts(spec: dict, original, intervened) -> dict:
    """Per dynamic body, how the intervention moved it: final positions, the final and the
    largest displacement over the clip's frames (px in 2D, m in 3D) and its first contact
    (time, partner) and number of contact begins in each rollout."""
    dim = spec["dim"]
    unit, width = ("px", 2) if dim == "2d" else ("m", 3)
    ids_o, ids_i = list(original.body_ids), list(intervened.body_ids)
    out: dict[str, Any] = {"unit": unit, "bodies": {}}
    for body in (b for b in spec["bodies"] if b["dynamic"]):
        po = np.asarray(original.frame_poses)[:, ids_o.index(body["id"]), :width]
        pi = np.asarray(intervened.frame_poses)[:, ids_i.index(body["id"]), :width]
        moved = np.linalg.norm(po - pi, axis=1)
        first_o, n_o = _first_contacts(list(getattr(original, "events", []) or []), body["id"])
        first_i, n_i = _first_contacts(list(getattr(intervened, "events", []) or []), body["id"])
        out["bodies"][body["id"]] = {
            "final_original": [round(float(v), 6) for v in po[-1]],
            "final_intervened": [round(float(v), 6) for v in pi[-1]],
            "final_moved": round(float(moved[-1]), 6), "max_moved": round(float(moved.max()), 6),
            "first_contact_original": first_o, "first_contact_intervened": first_i,
            "contact_begins_original": n_o, "contact_begins_intervened": n_i}
    return out


def effect_lines(effects: dict) -> list[str]:
    """The comparison as text, one line per dynamic body (most moved first)."""
    unit = effects["unit"]
    digits = 1 if unit == "px" else 3
    lines = []
    for bid, e in sorted(effects["bodies"].items(), key=lambda kv: -kv[1]["max_moved"]):
        fo = ", ".join(f"{v:.{digits}f}" for v in e["final_original"])
        fi = ", ".join(f"{v:.{digits}f}" for v in e["final_intervened"])
        line = (f"{bid}: final position ({fo}) → ({fi}) {unit}, moved "
                f"{e['final_moved']:.{digits}f} {unit} (at most {e['max_moved']:.{digits}f})")
        co, ci = e["first_contact_original"], e["first_contact_intervened"]
        if co or ci:
            def when(c: dict | None) -> str:
                return "none" if c is None else f"{c['t_s']:.2f} s ({c['with']})"

            line += f"; first contact {when(co)} → {when(ci)}"
        lines.append(line)
    return lines
