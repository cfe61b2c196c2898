"""Static analysis of a model's program: the physical parameters it sets, read without running it.

`analyse_program(source, language)` reads a program (HTML/JS or Python) with regular expressions
and a small, safe arithmetic evaluator (numbers, + - * / **, parentheses, ``Math.PI``/``pi``,
``sqrt`` and constants the program defines earlier, nothing else is ever evaluated) and returns
what it found, each value with the pattern it came from:

* ``engine``: ``cannon`` (cannon / cannon-es), ``matter`` (matter-js), ``planck`` (planck.js,
  box2d-style JS: ``box2d``), ``bpy`` (Blender), ``pymunk``, else ``plain`` (hand-written
  integrators in p5 / SVG / Manim / plain Python);
* ``gravity``: the magnitude the program sets, its raw unit class and the pattern: cannon
  ``world.gravity.set(x, y, z)``, ``new CANNON.World({gravity: new CANNON.Vec3(...)})``,
  ``world.gravity.y = ...``; planck / box2d ``World(Vec2(...))``; matter
  ``engine.gravity.y = ...`` / ``Engine.create({gravity: {y}})`` (with ``gravity.scale``);
  Python ``scene.gravity = (x, y, z)`` (Blender), ``space.gravity = (x, y)`` (pymunk); a scalar
  constant named ``g``, ``G``, ``gravity``, ``GRAVITY``, ``grav``, ``gravity_accel``… (``const
  g = 9.8``, ``GRAVITY = 9.81``); ``gravity = createVector(0, g)``;
* ``length_unit``: ``m`` when the program works in SI (its gravity lies in [1, 50], or it is
  planck / box2d / Blender without a gravity statement), ``px`` when its gravity is larger (pixel
  units; matter-js is always pixels), else None (a per-frame integrator, no gravity: lengths
  not interpretable);
* ``px_per_m``: a scale constant the program declares (``PX_PER_M``, ``pixelsPerMeter``,
  ``PPM``, ``SCALE_PX_PER_M``, ``METER_TO_PX``…; ``M_PER_PX``/``metersPerPixel`` inverted);
* ``bodies``: per body name (the variable, or the ``id``/``name``/``label`` string it is given,
  or Blender's ``obj.name = "..."``): ``mass``, ``density`` with the ``area`` of its shape (matter
  ``Bodies.circle/rectangle``, planck ``createFixture(Circle(r) | Box(hx, hy), {density})``),
  ``restitution`` (also ``elasticity``, ``bounce``, ``bounciness``), ``friction`` and the initial
  ``velocity``: cannon ``b.velocity.set(...)``, ``velocity: new Vec3(...)`` options,
  ``b.velocity.x = ...``; matter ``Body.setVelocity(b, {x, y})`` (pixels per 1/60 s step);
  planck / box2d ``b.setLinearVelocity(Vec2(...))``; object literals and constructor options
  (``{mass: 2, restitution: 0.8, vx: 3}``, ``Ball(mass=2, restitution=0.8)``), property
  assignments (``ball.mass = 2``, ``obj.rigid_body.friction = 0.5`` also through an alias
  ``rb = obj.rigid_body``, ``shape.elasticity = 0.9``), prefixed constants (``ball_mass = 2``,
  ``ball_vx = 3``, ``BALL_RESTITUTION = 0.6``);
* ``pairs``: cannon ``ContactMaterial(matA, matB, {friction, restitution})`` with the bodies
  using each material (``material: matA`` or ``b.material = matA``; else the material's own
  name);
* ``default``: scene-wide coefficients: ``world.defaultContactMaterial.friction = ...`` (or a
  default ContactMaterial), and unprefixed constants ``restitution``, ``bounce``, ``COR``,
  ``elasticity``, ``friction``, ``mu``…;
* ``free_velocity``: a velocity with no body prefix (``vx = 3; vy = 0``, ``vel =
  createVector(2, 0)``, ``v0 = 4``), used when the scene has a single moving body.

Limits: values computed at run time (loops, functions of parameters, random numbers, values read
from JSON payloads) are not followed; a body is recognised only through its name (matching is
done by `match_name` against the ground truth's ids, colours and shape words); engine defaults
a program does not state (cannon's 0.3 friction, matter's 0.1…) are never assumed. Anything not
understood is simply absent, never an exception.
"""

from __future__ import annotations

import math
import re
from typing import Any

from visphy_plugins.metrics import program_patterns as patterns
from visphy_plugins.metrics.program_patterns import expr_at, first_expr
from visphy_plugins.metrics.program_text import (
    _GRAV_NAMES,
    MATTER_GRAVITY_SCALE,
    MAX_SOURCE,
    SI_GRAVITY,
    _assignments,
    _block,
    _constants,
    _finditer,
    _norm,
    _props,
    _py_assignments,
    _strip_comments,
    _vector,
    eval_number,
)

__all__ = ["MIXING", "analyse_program", "detect_engine", "eval_number", "match_name",
           "name_tokens"]


def analyse_program(source: Any, language: str | None = None) -> dict[str, Any]:
    """What the program sets (see the module docstring); an empty analysis for anything that is
    not program text."""
    empty = {"engine": None, "gravity": None, "length_unit": None, "px_per_m": None,
             "bodies": {}, "pairs": [], "default": {}, "free_velocity": None}
    if not isinstance(source, str) or not source.strip():
        return empty
    try:
        return _analyse(source[:MAX_SOURCE], language)
    except (RecursionError, MemoryError, ValueError, TypeError, IndexError, KeyError):
        return empty



def _analyse(raw: str, language: str | None) -> dict[str, Any]:
    python = (language or "").lower() in ("python", "py") or (
        language is None and bool(re.search(r"^\s*(?:import|from)\s+\w+", raw, re.M))
        and "<script" not in raw)
    src = _strip_comments(raw, python)
    engine = detect_engine(src, python)
    assigns = (_py_assignments(src) if python else None) or _assignments(src)
    names = _constants(assigns)
    bodies = patterns.Bodies()
    default: dict[str, dict[str, Any]] = {}

    px_per_m = patterns.scale_constant(assigns, names)
    gravity = _gravity(src, engine, names, assigns)
    resolve = patterns.name_resolver(src)
    materials = patterns.materials(src, names)
    matter_default = patterns.body_blocks(src, names, bodies, materials, resolve)
    patterns.named_objects(src, names, bodies)
    patterns.property_assignments(src, names, bodies, materials, default, resolve)
    patterns.mass_helpers(src, names, bodies, resolve, matter_default)
    patterns.velocities(src, names, bodies, resolve)
    free_velocity = patterns.prefixed_constants(src, assigns, names, bodies, default)
    pairs = patterns.contact_materials(src, names, bodies, materials, default)

    length_unit = None
    if gravity is not None:
        length_unit = gravity["unit"] if gravity["unit"] in ("m", "px") else None
    elif engine in ("planck", "box2d", "bpy"):
        length_unit = "m"
    elif engine == "matter":
        length_unit = "px"
    for d in bodies.data.values():
        if d.get("velocity") is not None:
            d["velocity"].setdefault("unit", "len")
    return {"engine": engine, "gravity": gravity, "length_unit": length_unit,
            "px_per_m": px_per_m, "bodies": bodies.data, "pairs": pairs, "default": default,
            "free_velocity": free_velocity, "mixing": MIXING.get(engine)}



# ------------------------------------------------------------------------------ analysis
def detect_engine(src: str, python: bool) -> str:
    if python:
        if re.search(r"\bimport\s+bpy\b|\bbpy\.", src):
            return "bpy"
        if re.search(r"\bpymunk\b", src):
            return "pymunk"
        if re.search(r"\b(?:Box2D|b2World)\b", src):
            return "box2d"
        return "plain"
    if re.search(r"\bplanck\b", src):
        return "planck"
    if re.search(r"\bb2World\b|\bBox2D\b|box2d", src):
        return "box2d"
    if re.search(r"\bMatter\b|matter-js|\bEngine\.create\s*\(", src):
        return "matter"
    if re.search(r"\bCANNON\b|cannon-es|cannon\.js|cannon@|\bContactMaterial\b", src):
        return "cannon"
    return "plain"


#: How each program engine combines two bodies' coefficients into a contact's (None: no engine,
#: the caller applies the ground truth engine's rule).
MIXING = {
    "cannon": {"friction": "product", "restitution": "product"},
    "matter": {"friction": "min", "restitution": "max"},
    "planck": {"friction": "sqrt", "restitution": "max"},
    "box2d": {"friction": "sqrt", "restitution": "max"},
    "bpy": {"friction": "product", "restitution": "product"},    # Bullet
    "pymunk": {"friction": "product", "restitution": "product"},
}



def _gravity(src: str, engine: str, names: dict[str, float],
             assigns: list[tuple[int, str, str, int]]) -> dict[str, Any] | None:
    """The program's gravity: {raw (magnitude in program units), unit, pattern, vector}."""
    found: tuple[list[float], str] | None = None
    m = re.search(r"\bgravity\.set\s*\(", src)
    if m:
        vec = _vector(_block(src, m.end() - 1), names)
        if vec:
            found = (vec, "gravity.set(x, y, z)")
    if found is None:
        m = re.search(r"\b(?:World|b2World)\s*\(\s*(?:\{\s*gravity\s*:\s*)?(?:new\s+)?"
                      r"(?:[\w$]+\.)?(?:b2)?Vec[23]\s*\(", src)
        if m:
            vec = _vector(_block(src, m.end() - 1), names)
            if vec:
                found = (vec, "World(gravity Vec)")
    if found is None:
        m = re.search(r"\bgravity\s*[:=](?![=>])\s*(?:new\s+)?(?:[\w$]+\.)?(?:b2)?Vec[23]\s*\(",
                      src)
        if m:
            vec = _vector(_block(src, m.end() - 1), names)
            if vec:
                found = (vec, "gravity: Vec(...)")
    scale = MATTER_GRAVITY_SCALE
    if engine == "matter":
        s = re.search(r"\bgravity\.scale\s*=(?!=)\s*([^;\n]{1,60})", src)
        s = eval_number(s.group(1), names) if s else None
        if s is None:
            s2 = re.search(r"\bgravity\s*:\s*\{([^{}]{0,200})\}", src)
            if s2 and isinstance(_props(s2.group(1), names).get("scale"), float):
                s = _props(s2.group(1), names)["scale"]
        if s is not None:
            scale = s
    if found is None:
        m = re.search(r"\bgravity\s*:\s*\{([^{}]{0,200})\}", src)
        if m:
            props = _props(m.group(1), names)
            vec = [props[k] for k in ("x", "y", "z") if isinstance(props.get(k), float)]
            if vec:
                found = (vec, "gravity: {x, y}")
    if found is None:
        comps: dict[str, float] = {}
        for m in _finditer(r"\bgravity\.([xyz])\s*=(?!=)\s*([^;\n]{1,100})", src):
            v = eval_number(first_expr(m.group(2)), names)
            if v is not None:
                comps.setdefault(m.group(1), v)
        if comps:
            found = ([comps[k] for k in sorted(comps)], "gravity.x/y/z =")
    if found is None:  # Python tuples / vectors: scene.gravity = (0, 0, -9.81)
        m = re.search(r"\bgravity\s*=(?![=>])\s*", src)
        if m:
            vec = _vector(expr_at(src, m.end()), names)
            if vec and len(vec) >= 2:
                found = (vec, "gravity = (x, y[, z])")
    if found is None:
        for _, name, _expr, _start in assigns:
            if _norm(name) in _GRAV_NAMES and name in names:
                found = ([names[name]], f"{name} = ...")
                break
    if found is None:
        m = re.search(r"(?<![\w$])['\"]?(?:gravity|GRAVITY|g)['\"]?\s*:\s*([-+\d.][^,;}\n]{0,60})",
                      src)
        if m:
            v = eval_number(m.group(1), names)
            if v is not None:
                found = ([v], "gravity: value")
    if found is None:
        return None
    vec, pattern = found
    raw = float(math.sqrt(sum(x * x for x in vec)))
    if not math.isfinite(raw):
        return None
    if engine == "matter" and not pattern.startswith(("gravity.set", "World(")):
        # matter adds gravity·scale px per ms² (velocity in px per step): g·scale·1e6 px/s²
        px = raw * scale * 1e6
        return {"raw": raw, "value": px, "unit": "px", "pattern": pattern + " (matter)",
                "vector": vec}
    if SI_GRAVITY[0] <= raw <= SI_GRAVITY[1]:
        unit = "m"
    elif raw > SI_GRAVITY[1]:
        unit = "px"
    elif raw == 0.0:
        unit = "zero"
    else:
        unit = "unknown"
    return {"raw": raw, "value": raw, "unit": unit, "pattern": pattern, "vector": vec}


# ------------------------------------------------------------------------------ name matching
_STOP = {"body", "bodies", "mesh", "mat", "material", "obj", "object", "rb", "rigid", "shape",
         "fixture", "geo", "geom", "geometry", "phys", "physics", "cm", "the", "my", "def",
         "sprite", "node", "el", "elem", "element", "svg", "circle", "rect", "group", "data",
         "state", "props", "cfg", "config", "s", "ent", "entity"}
_SYN = {"sphere": "ball", "disc": "ball", "disk": "ball", "cube": "box", "block": "box",
        "crate": "box", "square": "box", "ground": "floor", "plane": "floor", "grey": "gray",
        "container": "jar", "cup": "jar", "basket": "jar", "stick": "sticks", "rod": "bar",
        "beam": "bar", "platform": "bar", "ledge": "bar", "shelf": "bar", "board": "plank"}


def name_tokens(name: str) -> tuple[str, ...]:
    words = re.findall(r"[A-Z]?[a-z]+|[A-Z]+(?![a-z])|\d+", name or "")
    out = []
    for w in words:
        w = w.lower()
        w = _SYN.get(w, w)
        if w in _STOP:
            continue
        out.append(w)
    return tuple(out)


def match_name(name: Any, entities: dict[str, tuple[str, ...]]) -> str | None:
    """The ground-truth id a program name refers to (entities: id -> its tokens), or None when
    no id or several equally good ids fit. Exact token match first, then the unique id whose
    tokens contain all the name's tokens."""
    if not isinstance(name, str) or not name:
        return None
    if name in entities:
        return name
    toks = name_tokens(name)
    if not toks:
        return None
    exact = [e for e, t in entities.items() if t == toks]
    if len(exact) == 1:
        return exact[0]
    if exact:
        return None
    tset = set(toks)
    sup = [e for e, t in entities.items() if tset <= set(t)]
    if len(sup) == 1:
        return sup[0]
    if len(sup) > 1:  # "box" with green_box and green_box_2: the one without a number suffix
        plain = [e for e in sup if not any(x.isdigit() for x in entities[e])]
        return plain[0] if len(plain) == 1 and not any(x.isdigit() for x in toks) else None
    sub = [e for e, t in entities.items() if t and set(t) <= tset]
    if len(sub) == 1:
        return sub[0]
    return None
