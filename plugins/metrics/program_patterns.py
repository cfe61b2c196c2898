"""The pattern readers of the program analyser (`program_params.py`): each reads one family of
statements (materials, body options, property assignments, velocities, prefixed constants,
contact materials) into the per-body record `Bodies`. `program_params._analyse` runs them in
order; the order matters, since the first value a body gets for a key is kept."""

from __future__ import annotations

import bisect
import itertools
import math
import re
from collections.abc import Callable
from typing import Any

from visphy_plugins.metrics.program_text import (
    _FRIC_KEYS,
    _ID,
    _INV_SCALE_NAMES,
    _REST_KEYS,
    _SCALE_NAMES,
    MAX_ITEMS,
    _block,
    _finditer,
    _norm,
    _props,
    _split_top,
    _vector,
    eval_number,
)


def classify_key(key: str) -> str | None:
    k = _norm(key)
    if k in ("mass",):
        return "mass"
    if k in ("density",):
        return "density"
    if k in _REST_KEYS:
        return "restitution"
    if k in _FRIC_KEYS:
        return "friction"
    return None


def split_name(name: str) -> tuple[str, str] | None:
    """``ball_mass`` / ``BALL_RESTITUTION`` / ``ballMass`` / ``mass_ball`` -> (body hint, key)."""
    words = [w.lower() for w in re.findall(r"[A-Z]?[a-z]+|[A-Z]+(?![a-z])|\d+", name)]
    if len(words) < 2:
        return None
    for n in (2, 1):  # key words at the end (ball_mass) or the start (mass_ball)
        if len(words) > n:
            tail = "".join(words[-n:])
            kind = classify_key(tail) or ("velocity" if tail in ("vx", "vy", "vz") else None)
            if kind:
                return "_".join(words[:-n]), tail
            head = "".join(words[:n])
            kind = classify_key(head)
            if kind:
                return "_".join(words[n:]), head
    return None


class Bodies:
    def __init__(self):
        self.data: dict[str, dict[str, Any]] = {}

    def set(self, name: str, key: str, value: Any, pattern: str, **extra: Any) -> None:
        if not name or value is None:
            return
        d = self.data.setdefault(name, {})
        if key not in d:
            d[key] = {"value": value, "pattern": pattern, **extra}


def _shape_area(text: str | None, names: dict[str, float]) -> float | None:
    if not text:
        return None
    m = re.search(r"\bCircle\s*\(([^()]*)\)", text)
    if m:
        parts = _split_top(m.group(1))
        r = eval_number(parts[-1], names) if parts else None
        return math.pi * r * r if r else None
    m = re.search(r"\bBox\s*\(([^()]*)\)", text)
    if m:
        parts = _split_top(m.group(1))
        if len(parts) >= 2:
            hx, hy = eval_number(parts[0], names), eval_number(parts[1], names)
            if hx and hy:
                return 4.0 * abs(hx * hy)
    return None




def first_expr(expr: str) -> str:
    return _split_top(expr)[0] if _split_top(expr) else expr


def expr_at(src: str, i: int) -> str:
    """The expression starting at ``src[i]``: a bracketed block with its constructor, or the text
    up to ``;``/newline."""
    m = re.match(r"\s*(?:new\s+)?[\w$.]*\s*([(\[{])", src[i:i + 200])
    if m:
        start = i + m.start(1)
        inner = _block(src, start)
        if inner is not None:
            return src[i:start + len(inner) + 2]
    m = re.match(r"[^;\n]{1,200}", src[i:])
    return m.group(0) if m else ""


def body_props(bodies: Bodies, name: Any, props: dict[str, Any], names: dict[str, float],
                where: str) -> None:
    if not isinstance(name, str) or not name:
        return
    for key, value in props.items():
        if key.endswith("#") or not isinstance(value, float):
            continue
        kind = classify_key(key)
        if kind:
            bodies.set(name, kind, value, f"{key} in {where}")
    comps = {k[1]: props[k] for k in ("vx", "vy", "vz") if isinstance(props.get(k), float)}
    if comps:
        bodies.set(name, "velocity", [comps.get(k, 0.0) for k in "xyz" if k in comps],
                   f"vx/vy in {where}")
    for key in ("velocity", "vel", "v", "linearVelocity", "linear_velocity", "v0"):
        raw = props.get(key + "#")
        if isinstance(raw, str):
            vec = _vector(raw, names)
            if vec is None and isinstance(props.get(key), float):
                vec = [props[key]]
            bodies.set(name, "velocity", vec, f"{key} in {where}")



# --------------------------------------------------------------------------------- scale constants
def scale_constant(assigns: list[tuple[int, str, str, int]],
                   names: dict[str, float]) -> float | None:
    """A pixels-per-metre constant the program declares (a metres-per-pixel one inverted)."""
    for _, name, _expr, _start in assigns:
        n = _norm(name)
        v = names.get(name)
        if v is None or v <= 0:
            continue
        if n in _SCALE_NAMES:
            return v
        if n in _INV_SCALE_NAMES:
            return 1.0 / v
    return None


# ------------------------------------------------------------------------------- aliases and names
def name_resolver(src: str) -> Callable[[str, int], str]:
    """``resolve(var, pos)``: the body name a variable stands for at ``pos``.

    Blender: ``obj = bpy.context.active_object`` then ``obj.name = "red_ball"``: later
    statements on ``obj`` refer to "red_ball" (until renamed); ``rb = obj.rigid_body`` aliases."""
    events: list[tuple[int, str, str, str]] = []
    for m in _finditer(r"(?<![\w$.])(" + _ID + r")\.name\s*=(?!=)\s*['\"]([^'\"]{1,80})['\"]",
                         src):
        events.append((m.start(), "rename", m.group(1), m.group(2)))
    for m in _finditer(r"(?<![\w$.])(" + _ID + r")\s*=(?!=)\s*(" + _ID + r")\.rigid_body\b"
                         r"(?!\s*\.)", src):
        events.append((m.start(), "alias", m.group(1), m.group(2)))
    for m in _finditer(r"(?<![\w$.])(" + _ID + r")\s*=(?!=)\s*(?:bpy\.context\.(?:active_)?"
                         r"object|bpy\.data\.objects\.new\s*\(\s*['\"]([^'\"]{1,80})['\"])", src):
        events.append((m.start(), "rebind", m.group(1), m.group(2) or ""))
    events.sort()

    # per variable, the positions where its alias / its name changes (resolved in O(log n))
    alias_ev: dict[str, tuple[list[int], list[str | None]]] = {}
    name_ev: dict[str, tuple[list[int], list[str]]] = {}

    def latest(ev: dict, var: str, pos: int) -> Any:
        if var not in ev:
            return None
        ps, vs = ev[var]
        i = bisect.bisect_right(ps, pos)
        return vs[i - 1] if i else None

    def push(ev: dict, var: str, pos: int, value: Any) -> None:
        ps, vs = ev.setdefault(var, ([], []))
        ps.append(pos)
        vs.append(value)

    for p, kind, a, b in events:
        if kind == "alias":
            push(alias_ev, a, p, b)
        elif kind == "rebind":
            push(alias_ev, a, p, None)
            push(name_ev, a, p, b)
        else:
            push(name_ev, latest(alias_ev, a, p) or a, p, b)

    def resolve(var: str, pos: int) -> str:
        base = latest(alias_ev, var, pos) or var
        return latest(name_ev, base, pos) or base

    return resolve


# ------------------------------------------------------------------------------ materials (cannon)
def materials(src: str, names: dict[str, float]) -> dict[str, dict[str, Any]]:
    """Each ``new Material(...)`` variable: its label, coefficients and (later) its bodies."""
    found: dict[str, dict[str, Any]] = {}
    for m in _finditer(r"(?<![\w$.])(" + _ID + r")\s*=(?!=)\s*new\s+(?:[\w$]+\.)?Material\s*\(",
                         src):
        inner = _block(src, m.end() - 1) or ""
        props = _props(inner, names)
        label = None
        s = re.match(r"^\s*['\"]([^'\"]{1,80})['\"]", inner)
        if s:
            label = s.group(1)
        found[m.group(1)] = {"label": label or props.get("name"),
                             "friction": props.get("friction"),
                             "restitution": props.get("restitution"), "bodies": []}
    return found


# ------------------------------------------------------------------------------------- body blocks
def body_blocks(src: str, names: dict[str, float], bodies: Bodies,
                mats: dict[str, dict[str, Any]], resolve: Callable[[str, int], str]) -> list[str]:
    """Constructor options and object literals bound to a variable; returns the matter bodies
    with neither a density nor a mass option."""
    block_re = re.compile(r"(?<![\w$])((?:this|self)\.)?(" + _ID + r")\s*=(?![=>])\s*"
                          r"(?:new\s+)?([\w$.]*)\s*([({])")
    matter_default: list[str] = []
    for m in itertools.islice(block_re.finditer(src), MAX_ITEMS):
        var, ctor = m.group(2), m.group(3)
        if ctor.split(".")[-1] in ("Material", "ContactMaterial", "World", "Vec3", "Vec2",
                                   "Vector", "createVector", "Color", "Engine", "Quaternion"):
            continue
        inner = _block(src, m.end() - 1)
        if inner is None:
            continue
        props = _props(inner, names)
        name = props.get("id") or props.get("name") or props.get("label")
        name = name if isinstance(name, str) else resolve(var, m.start())
        body_props(bodies, name, props, names, f"{ctor or 'object'} options")
        mat = props.get("material#")
        if isinstance(mat, str) and mat.strip() in mats:
            mats[mat.strip()]["bodies"].append(name)
        if ctor.split(".")[-1] in ("circle", "rectangle") and "Bodies" in ctor:
            parts = _split_top(inner)
            nums = [eval_number(p, names) for p in parts[2:4]]
            if ctor.endswith("circle") and nums[:1] and nums[0]:
                bodies.set(name, "area", math.pi * nums[0] ** 2, "Bodies.circle radius")
            elif ctor.endswith("rectangle") and len(nums) == 2 and all(nums):
                bodies.set(name, "area", abs(nums[0] * nums[1]), "Bodies.rectangle size")
            if "density" not in props and "mass" not in props:
                matter_default.append(name)
    return matter_default


def named_objects(src: str, names: dict[str, float], bodies: Bodies) -> None:
    """Objects named inside arrays / calls: ``{id: 'red_ball', mass: 2}`` or
    ``make('red_ball', mass=2)``."""
    for m in _finditer(r"\{\s*['\"]?(?:id|name|label)['\"]?\s*:\s*['\"]([^'\"]{1,80})['\"]", src):
        inner = _block(src, m.start())
        if inner is not None:
            body_props(bodies, m.group(1), _props(inner, names), names, "object literal")
    for m in _finditer(r"(?<![\w$.])[\w$.]+\s*\(\s*['\"]([A-Za-z][\w\- ]{0,79})['\"]\s*,", src):
        inner = _block(src, src.index("(", m.start()))
        if inner is not None:
            body_props(bodies, m.group(1), _props(inner, names), names, "call arguments")


# ---------------------------------------------------------------------------- property assignments
def property_assignments(src: str, names: dict[str, float], bodies: Bodies,
                         mats: dict[str, dict[str, Any]], default: dict[str, dict[str, Any]],
                         resolve: Callable[[str, int], str]) -> None:
    """``ball.mass = 2``, ``world.defaultContactMaterial.friction = ...``, ``b.material = m``."""
    prop_re = re.compile(r"(?<![\w$.])(" + _ID + r")((?:\.[A-Za-z_$][\w$]*)*)\.("
                         r"mass|density|restitution|friction|elasticity|bounce|bounciness)"
                         r"\s*=(?!=)\s*([^;\n]{1,200})")
    for m in itertools.islice(prop_re.finditer(src), MAX_ITEMS):
        base, chain, key, expr = m.group(1), m.group(2), m.group(3), m.group(4)
        kind = classify_key(key)
        v = eval_number(first_expr(expr), names)
        if v is None or kind is None:
            continue
        if "defaultContactMaterial" in chain or base == "defaultContactMaterial":
            default.setdefault(kind, {"value": v, "pattern": f"defaultContactMaterial.{key}"})
        elif base in mats and not chain:
            if mats[base].get(kind) is None:
                mats[base][kind] = v
        else:
            name = resolve(base, m.start())
            pattern = f"{base}{chain}.{key} ="
            bodies.set(name, kind, v, pattern)
    for m in _finditer(r"(?<![\w$.])(" + _ID + r")\.material\s*=(?!=)\s*(" + _ID + r")", src):
        if m.group(2) in mats:
            mats[m.group(2)]["bodies"].append(resolve(m.group(1), m.start()))


def mass_helpers(src: str, names: dict[str, float], bodies: Bodies,
                 resolve: Callable[[str, int], str], matter_default: list[str]) -> None:
    """Matter's ``Body.setMass/setDensity`` and default density; planck's ``createFixture``."""
    for m in _finditer(r"\bBody\.set(Mass|Density)\s*\(\s*(" + _ID + r")\s*,\s*([^)]{1,100})\)",
                         src):
        v = eval_number(m.group(3), names)
        bodies.set(m.group(2), m.group(1).lower(), v, f"Body.set{m.group(1)}")

    # planck: b.createFixture(Circle(r) | Box(hx, hy), {density, friction, restitution} | d)
    for m in _finditer(r"(?<![\w$.])(" + _ID + r")\.create[Ff]ixture\s*\(", src):
        inner = _block(src, m.end() - 1)
        if inner is None:
            continue
        parts = _split_top(inner)
        name = resolve(m.group(1), m.start())
        props = _props(inner, names)
        body_props(bodies, name, props, names, "createFixture")
        if len(parts) >= 2 and "density" not in props:
            bodies.set(name, "density", eval_number(parts[1], names), "createFixture density")
        bodies.set(name, "area", _shape_area(parts[0] if parts else None, names),
                   "createFixture shape")

    for name in matter_default:  # matter's default density, unless set later
        if not {"density", "mass"} & set(bodies.data.get(name, {})):
            bodies.set(name, "density", 0.001, "matter default density")


# -------------------------------------------------------------------------------------- velocities
def velocities(src: str, names: dict[str, float], bodies: Bodies,
               resolve: Callable[[str, int], str]) -> None:
    """Each body's initial velocity, in every form the engines take it."""
    for m in _finditer(r"(?<![\w$.])(" + _ID + r")\.velocity\.set\s*\(", src):
        vec = _vector(_block(src, m.end() - 1), names)
        bodies.set(resolve(m.group(1), m.start()), "velocity", vec, "velocity.set(...)")
    for m in _finditer(r"(?<![\w$.])(" + _ID + r")\.(?:velocity|linear_velocity|"
                         r"linearVelocity)\s*=(?!=)\s*", src):
        vec = _vector(expr_at(src, m.end()), names)
        bodies.set(resolve(m.group(1), m.start()), "velocity", vec, "velocity =")
    for m in _finditer(r"(?<![\w$.])(" + _ID + r")\.[sS]et[Ll]inear[Vv]elocity\s*\(", src):
        inner = _block(src, m.end() - 1)
        vec = _vector(inner, names) if inner is not None else None
        bodies.set(resolve(m.group(1), m.start()), "velocity", vec, "setLinearVelocity")
    for m in _finditer(r"\bBody\.setVelocity\s*\(\s*(" + _ID + r")\s*,\s*", src):
        vec = _vector(expr_at(src, m.end()), names)
        bodies.set(m.group(1), "velocity", vec, "Body.setVelocity (px/step)",
                   unit="matter_step")
    comp: dict[str, dict[str, float]] = {}
    for m in _finditer(r"(?<![\w$.])(" + _ID + r")\.(?:velocity|vel|v)\.([xyz])\s*=(?!=)\s*"
                         r"([^;\n]{1,100})", src):
        v = eval_number(first_expr(m.group(3)), names)
        if v is not None:
            comp.setdefault(resolve(m.group(1), m.start()), {}).setdefault(m.group(2), v)
    for m in _finditer(r"(?<![\w$.])(" + _ID + r")\.(vx|vy|vz)0?\s*=(?!=)\s*([^;\n]{1,100})",
                         src):
        v = eval_number(first_expr(m.group(3)), names)
        if v is not None:
            comp.setdefault(resolve(m.group(1), m.start()), {}).setdefault(m.group(2)[1], v)
    for name, c in comp.items():
        bodies.set(name, "velocity", [c.get(k, 0.0) for k in "xyz" if k in c] or None,
                   "velocity components")


# ------------------------------------------------------------------------------ prefixed constants
def prefixed_constants(src: str, assigns: list[tuple[int, str, str, int]],
                       names: dict[str, float], bodies: Bodies,
                       default: dict[str, dict[str, Any]]) -> dict[str, Any] | None:
    """``ball_mass = 2``, ``BALL_RESTITUTION = 0.6``, unprefixed ``friction = 0.3`` (scene-wide);
    returns the free velocity (``vx = 3; vy = 0``, ``vel = createVector(2, 0)``, ``v0 = 4``)."""
    free: dict[str, float] = {}
    free_vec = None
    for _pos, name, expr, start in assigns:
        v = names.get(name)
        n = _norm(name)
        if v is not None:
            kind = classify_key(name)
            if kind in ("restitution", "friction") and kind not in default:
                default[kind] = {"value": v, "pattern": f"{name} = ..."}
                continue
            if n in ("vx", "vy", "vz", "vx0", "vy0", "vz0", "velx", "vely", "velz"):
                free.setdefault(n.replace("vel", "v")[:2], v)
                continue
            if n in ("v0", "speed", "initialspeed", "speed0", "initialvelocity", "u0"):
                free.setdefault("speed", abs(v))
                continue
            split = split_name(name)
            if split:
                hint, key = split
                kind = classify_key(key)
                if kind in ("mass", "density", "restitution", "friction"):
                    bodies.set(hint, kind, v, f"{name} = ...")
                elif key in ("vx", "vy", "vz"):
                    d = bodies.data.setdefault(hint, {})
                    d.setdefault("_comp", {})[key[1]] = v
        elif n in ("vel", "velocity", "v", "v0", "initialvelocity", "vel0") and free_vec is None:
            free_vec = _vector(expr_at(src, start), names)
        else:
            split = split_name(name)
            if split and split[1] in ("velocity", "vel") or (
                    n.endswith(("velocity", "vel")) and len(n) > 5):
                hint = re.sub(r"(?i)[_]?(velocity|vel)0?$", "", name)
                vec = _vector(expr_at(src, start), names)
                bodies.set(hint, "velocity", vec, f"{name} = ...")
    for name, d in list(bodies.data.items()):
        c = d.pop("_comp", None)
        if c and "velocity" not in d:
            d["velocity"] = {"value": [c.get(k, 0.0) for k in "xyz" if k in c],
                             "pattern": "prefixed vx/vy constants"}
        if not d:
            del bodies.data[name]
    if free_vec is not None:
        return {"value": float(math.sqrt(sum(x * x for x in free_vec))),
                "pattern": "velocity vector constant"}
    if any(k in free for k in ("vx", "vy", "vz")):
        return {"value": float(math.sqrt(sum(free.get(k, 0.0) ** 2
                                             for k in ("vx", "vy", "vz")))),
                "pattern": "vx/vy constants"}
    if "speed" in free:
        return {"value": free["speed"], "pattern": "speed constant"}
    return None


# ------------------------------------------------------------------------------- contact materials
def contact_materials(src: str, names: dict[str, float], bodies: Bodies,
                      mats: dict[str, dict[str, Any]],
                      default: dict[str, dict[str, Any]]) -> list[dict[str, Any]]:
    """cannon ``ContactMaterial(a, b, {...})`` pairs (a default one fills ``default``), then each
    material's own coefficients given to the bodies using it."""
    pairs: list[dict[str, Any]] = []
    for m in _finditer(r"\bnew\s+(?:[\w$]+\.)?ContactMaterial\s*\(", src):
        inner = _block(src, m.end() - 1)
        if inner is None:
            continue
        is_default = re.search(r"\.defaultContactMaterial\s*=\s*$",
                               src[max(0, m.start() - 100):m.start()]) is not None
        parts = _split_top(inner)
        props = {}
        if len(parts) >= 3 and parts[2].startswith("{"):
            props = _props(_block(parts[2], 0) or "", names)
        fr, re_ = props.get("friction"), props.get("restitution")
        fr = fr if isinstance(fr, float) else None
        re_ = re_ if isinstance(re_, float) else None
        if fr is None and re_ is None:
            continue
        if is_default:
            for k, v in (("friction", fr), ("restitution", re_)):
                if v is not None:
                    default.setdefault(k, {"value": v, "pattern": "defaultContactMaterial"})
            continue
        sides = []
        for p in parts[:2]:
            p = p.strip()
            mat = mats.get(p)
            hints = list(mat["bodies"]) if mat else []
            if not hints:
                hints = [h for h in (mat.get("label") if mat else None, p) if h]
            sides.append(list(dict.fromkeys(hints))[:64])
        if len(sides) == 2:
            pairs.append({"a": sides[0], "b": sides[1], "friction": fr, "restitution": re_,
                          "pattern": "ContactMaterial(a, b, {...})"})
    for name, mat in mats.items():  # per-material coefficients -> the bodies using them
        for k in ("friction", "restitution"):
            if isinstance(mat.get(k), float):
                for b in mat["bodies"]:
                    bodies.set(b, k, mat[k], f"Material {name}.{k}")
    return pairs
