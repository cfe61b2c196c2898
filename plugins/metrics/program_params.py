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
# size: one static analyser: each language's parameter patterns share tables and change together

from __future__ import annotations

import ast
import bisect
import itertools
import math
import re
import tokenize
from io import StringIO
from typing import Any

MAX_SOURCE = 400_000      # characters of a program that are analysed
MAX_BLOCK = 4_000         # longest (...) / {...} block read
MAX_ABS = 1e9             # a number beyond this is not a physical parameter
MAX_ITEMS = 5_000         # assignments / blocks read per program (bounds the work)
SI_GRAVITY = (1.0, 50.0)  # a gravity magnitude in this range is read as m/s²
MATTER_GRAVITY_SCALE = 0.001

_ID = r"[A-Za-z_$][\w$]*"
_REST_KEYS = ("restitution", "elasticity", "bounce", "bounciness", "cor",
              "coefficientofrestitution", "coeffrestitution", "restitutioncoefficient")
_FRIC_KEYS = ("friction", "mu", "frictioncoefficient", "coefficientoffriction",
              "frictioncoeff", "kineticfriction", "dynamicfriction", "muk")
_GRAV_NAMES = ("g", "grav", "gravity", "gravityacc", "gravityaccel", "gravityacceleration",
               "gacc", "gaccel", "accelgravity", "accelerationgravity", "gravitystrength")
_SCALE_NAMES = ("pxperm", "pxpermeter", "pxpermetre", "pixelspermeter", "pixelspermetre",
                "pixelpermeter", "pixelpermetre", "ppm", "scalepxperm", "metertopx",
                "metretopx", "metertopixel", "metertopixels", "m2px", "mtopx", "pxm",
                "worldscalepxperm")
_INV_SCALE_NAMES = ("mperpx", "meterperpixel", "meterperpx", "meterspermpixel",
                    "meterspixel", "meterperpixels", "meterspperpixel", "meterspertpixel",
                    "meterspertpx", "meterspx", "px2m", "pxtom", "pixeltometer", "pxtometer",
                    "meterperpixel", "metersperpixel", "metresperpixel")


# ------------------------------------------------------------------------------ numbers
class _Eval(ast.NodeVisitor):
    def __init__(self, names: dict[str, float]):
        self.names = names

    def visit_Expression(self, node):
        return self.visit(node.body)

    def visit_Constant(self, node):
        if isinstance(node.value, bool) or not isinstance(node.value, (int, float)):
            raise ValueError("not a number")
        return float(node.value)

    def visit_Name(self, node):
        if node.id in ("pi", "PI"):
            return math.pi
        if node.id in self.names:
            return self.names[node.id]
        raise ValueError("unknown name")

    def visit_UnaryOp(self, node):
        v = self.visit(node.operand)
        if isinstance(node.op, ast.USub):
            return -v
        if isinstance(node.op, ast.UAdd):
            return v
        raise ValueError("operator")

    def visit_BinOp(self, node):
        a, b = self.visit(node.left), self.visit(node.right)
        op = node.op
        if isinstance(op, ast.Add):
            return a + b
        if isinstance(op, ast.Sub):
            return a - b
        if isinstance(op, ast.Mult):
            return a * b
        if isinstance(op, ast.Div):
            return a / b
        if isinstance(op, ast.Pow):
            if abs(b) > 8 or abs(a) > 1e6:
                raise ValueError("power too large")
            return a ** b
        raise ValueError("operator")

    def visit_Call(self, node):
        if isinstance(node.func, ast.Name) and node.func.id in ("sqrt", "abs") \
                and len(node.args) == 1 and not node.keywords:
            v = self.visit(node.args[0])
            return math.sqrt(v) if node.func.id == "sqrt" else abs(v)
        raise ValueError("call")

    def generic_visit(self, node):
        raise ValueError(f"not allowed: {type(node).__name__}")


_JS_MATH = re.compile(r"\b(?:Math|math|np|numpy)\.(PI|pi|sqrt|abs)\b")


def eval_number(expr: str, names: dict[str, float] | None = None) -> float | None:
    """The value of a constant arithmetic expression, or None (never raises, never runs code)."""
    if not isinstance(expr, str):
        return None
    text = expr.strip().rstrip(";").strip()
    if not text or len(text) > 200:
        return None
    text = _JS_MATH.sub(lambda m: m.group(1), text)
    text = re.sub(r"(?<=\d)[fF]\b", "", text)  # 9.8f
    try:
        value = _Eval(names or {}).visit(ast.parse(text, mode="eval"))
    except (SyntaxError, ValueError, TypeError, ZeroDivisionError, OverflowError,
            RecursionError, MemoryError, AttributeError):
        return None
    if isinstance(value, complex) or not math.isfinite(value) or abs(value) > MAX_ABS:
        return None
    return float(value)


# ------------------------------------------------------------------------------ text helpers
def _strip_comments(src: str, python: bool) -> str:
    if python:
        try:
            out, last = [], (1, 0)
            lines = src.splitlines(keepends=True)
            for tok in tokenize.generate_tokens(StringIO(src).readline):
                if tok.type == tokenize.COMMENT:
                    (sr, sc), (er, ec) = tok.start, tok.end
                    out.append(_slice(lines, last, (sr, sc)))
                    last = (er, ec)
            out.append(_slice(lines, last, (len(lines) + 1, 0)))
            return "".join(out)
        except (tokenize.TokenError, IndentationError, SyntaxError, ValueError):
            return re.sub(r"(?m)^\s*#[^\n]*", "", src)
    src = re.sub(r"/\*.*?\*/", " ", src, flags=re.S)
    src = re.sub(r"<!--.*?-->", " ", src, flags=re.S)
    return re.sub(r"(?<![:\\'\"/])//[^\n]*", "", src)


def _slice(lines: list[str], start: tuple[int, int], end: tuple[int, int]) -> str:
    (sr, sc), (er, ec) = start, end
    if sr == er:
        return lines[sr - 1][sc:ec] if sr - 1 < len(lines) else ""
    parts = [lines[sr - 1][sc:]] if sr - 1 < len(lines) else []
    parts.extend(lines[sr:er - 1])
    if er - 1 < len(lines):
        parts.append(lines[er - 1][:ec])
    return "".join(parts)


_OPEN = {"(": ")", "[": "]", "{": "}"}


def _finditer(pattern: str, src: str, flags: int = 0):
    """``re.finditer``, at most `MAX_ITEMS` matches."""
    return itertools.islice(re.finditer(pattern, src, flags), MAX_ITEMS)


_MATCH_CACHE: list[Any] = [None, None]  # [source, {open index: close index}]


def _bracket_pairs(src: str) -> dict[int, int]:
    """Matching brackets of a whole source in one pass (quotes end at a newline, so a stray
    apostrophe in text cannot hide the rest of the program)."""
    if _MATCH_CACHE[0] is src:
        return _MATCH_CACHE[1]
    pairs: dict[int, int] = {}
    stack: list[tuple[str, int]] = []
    quote = None
    j, n = 0, len(src)
    while j < n:
        c = src[j]
        if quote:
            if c == "\\":
                j += 2
                continue
            if c == quote or c == "\n":
                quote = None
        elif c in "'\"":
            quote = c
        elif c in _OPEN:
            stack.append((_OPEN[c], j))
        elif c in ")]}":
            while stack and stack[-1][0] != c:  # unbalanced opener: drop it
                stack.pop()
            if stack:
                _, k = stack.pop()
                pairs[k] = j
        j += 1
    _MATCH_CACHE[0], _MATCH_CACHE[1] = src, pairs
    return pairs


def _block(src: str, i: int) -> str | None:
    """Inner text of the bracket opening at ``src[i]`` (None when unbalanced or too long)."""
    if i >= len(src) or src[i] not in _OPEN:
        return None
    if len(src) > 2 * MAX_BLOCK:
        k = _bracket_pairs(src).get(i)
        return src[i + 1:k] if k is not None and k - i <= MAX_BLOCK else None
    stack, quote = [_OPEN[src[i]]], None
    end = min(len(src), i + MAX_BLOCK)
    j = i + 1
    while j < end:
        c = src[j]
        if quote:
            if c == "\\":
                j += 2
                continue
            if c == quote:
                quote = None
        elif c in "'\"`":
            quote = c
        elif c in _OPEN:
            stack.append(_OPEN[c])
        elif c in ")]}":
            if c != stack[-1]:
                return None
            stack.pop()
            if not stack:
                return src[i + 1:j]
        j += 1
    return None


def _split_top(text: str) -> list[str]:
    parts, depth, quote, cur = [], 0, None, []
    for c in text:
        if quote:
            cur.append(c)
            if c == quote:
                quote = None
            continue
        if c in "'\"`":
            quote = c
        elif c in "([{":
            depth += 1
        elif c in ")]}":
            depth -= 1
        elif c == "," and depth == 0:
            parts.append("".join(cur))
            cur = []
            continue
        cur.append(c)
    parts.append("".join(cur))
    return [p.strip() for p in parts if p.strip()]


def _norm(name: str) -> str:
    return re.sub(r"[^a-z0-9]", "", name.lower())


def _vector(text: str | None, names: dict[str, float]) -> list[float] | None:
    """Numbers of a vector expression: ``(a, b)``, ``[a, b]``, ``new Vec3(a, b, c)``,
    ``createVector(a, b)``, ``Vector((a, b, c))``, ``np.array([a, b])``, ``{x: a, y: b}``."""
    if text is None:
        return None
    t = text.strip().rstrip(";").strip()
    m = re.match(r"^(?:new\s+)?[\w$.]*\s*\(", t)
    if m:
        inner = _block(t, m.end() - 1)
        if inner is None:
            return None
        inner = inner.strip()
        if inner[:1] in "([":  # Vector((a, b, c)), np.array([a, b])
            inner = _block(inner, 0) or ""
        elif inner[:1] == "{":
            return _xyz(_block(inner, 0), names)
        t = inner
    elif t[:1] in "([":
        t = _block(t, 0) or ""
    elif t[:1] == "{":
        return _xyz(_block(t, 0), names)
    parts = _split_top(t)
    if not 1 <= len(parts) <= 3:
        return None
    vals = [eval_number(p, names) for p in parts]
    return None if any(v is None for v in vals) else vals


def _xyz(block: str | None, names: dict[str, float]) -> list[float] | None:
    if block is None:
        return None
    props = _props(block, names)
    vals = [props.get(k) for k in ("x", "y", "z") if k in props]
    if not vals or any(not isinstance(v, float) for v in vals):
        return None
    return vals


def _props(block: str, names: dict[str, float]) -> dict[str, Any]:
    """``key: expr`` / ``key=expr`` entries at the top level of a block (values evaluated when
    they are numbers; strings kept for ids; the raw text under ``'<key>#'``). Top-level
    ``{...}`` arguments (option objects) are read too."""
    out: dict[str, Any] = {}
    for part in _split_top(block):
        if part.startswith("{"):
            inner = _block(part, 0)
            if inner is not None:
                for k, v in _props(inner, names).items():
                    out.setdefault(k, v)
            continue
        m = re.match(r"^['\"]?(" + _ID + r")['\"]?\s*(?::|=(?!=))\s*(.+)$", part, flags=re.S)
        if not m:
            continue
        key, expr = m.group(1), m.group(2).strip()
        out.setdefault(key + "#", expr)
        s = re.match(r"^['\"`]([^'\"`]{1,80})['\"`]$", expr)
        if s:
            out.setdefault(key, s.group(1))
            continue
        v = eval_number(expr, names)
        if v is not None:
            out.setdefault(key, v)
    return out


def _assignments(src: str) -> list[tuple[int, str, str, int]]:
    """(position, name, expression text, where the expression starts) of every ``name = expr``
    (not ``obj.name``, not ``==``/``+=``/``=>``), the text cut at ``;``, ``,`` or the end of
    the line."""
    out = []
    for m in _finditer(r"(?<![\w$.])(" + _ID + r")\s*=(?![=>])[ \t]*([^;,\n]{1,200})", src):
        out.append((m.start(), m.group(1), m.group(2), m.start(2)))
        if len(out) >= MAX_ITEMS:
            break
    return out


def _py_assignments(src: str) -> list[tuple[int, str, str, int]] | None:
    """Python assignments from the syntax tree (tuple unpacking paired up, ``x += 1`` left
    out); None when the source does not parse."""
    try:
        tree = ast.parse(src)
    except (SyntaxError, ValueError, RecursionError, MemoryError, OverflowError):
        return None
    lines = src.splitlines(keepends=True)
    starts, acc = [], 0
    for line in lines:
        starts.append(acc)
        acc += len(line)

    def offset(lineno: int, col: int) -> int:
        if not 1 <= lineno <= len(lines):
            return 0
        line = lines[lineno - 1]
        return starts[lineno - 1] + len(line.encode("utf-8")[:col].decode("utf-8", "ignore"))

    out = []
    try:
        for node in ast.walk(tree):
            if isinstance(node, ast.Assign):
                targets, value = node.targets, node.value
            elif isinstance(node, ast.AnnAssign) and node.value is not None:
                targets, value = [node.target], node.value
            else:
                continue
            for t in targets:
                pairs = []
                if isinstance(t, ast.Name):
                    pairs = [(t, value)]
                elif isinstance(t, (ast.Tuple, ast.List)) and isinstance(
                        value, (ast.Tuple, ast.List)) and len(t.elts) == len(value.elts):
                    pairs = [(n, v) for n, v in zip(t.elts, value.elts) if isinstance(n, ast.Name)]
                for n, v in pairs:
                    start = offset(v.lineno, v.col_offset)
                    end = offset(v.end_lineno or v.lineno, v.end_col_offset or 0)
                    out.append((offset(n.lineno, n.col_offset), n.id,
                                src[start:min(end, start + 200)], start))
                    if len(out) >= MAX_ITEMS:
                        raise ValueError("too many assignments")
    except (RecursionError, MemoryError, ValueError):
        pass
    out.sort()
    return out


def _constants(assigns: list[tuple[int, str, str, int]]) -> dict[str, float]:
    names: dict[str, float] = {}
    for _, name, expr, _start in assigns:
        if name in names:
            continue
        v = eval_number(expr, names)
        if v is not None:
            names[name] = v
    return names


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


def _classify_key(key: str) -> str | None:
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


def _split_name(name: str) -> tuple[str, str] | None:
    """``ball_mass`` / ``BALL_RESTITUTION`` / ``ballMass`` / ``mass_ball`` -> (body hint, key)."""
    words = [w.lower() for w in re.findall(r"[A-Z]?[a-z]+|[A-Z]+(?![a-z])|\d+", name)]
    if len(words) < 2:
        return None
    for n in (2, 1):  # key words at the end (ball_mass) or the start (mass_ball)
        if len(words) > n:
            tail = "".join(words[-n:])
            kind = _classify_key(tail) or ("velocity" if tail in ("vx", "vy", "vz") else None)
            if kind:
                return "_".join(words[:-n]), tail
            head = "".join(words[:n])
            kind = _classify_key(head)
            if kind:
                return "_".join(words[n:]), head
    return None


class _Bodies:
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
    bodies = _Bodies()
    default: dict[str, dict[str, Any]] = {}
    pairs: list[dict[str, Any]] = []

    # ---------------------------------------------------------------- scale constants
    px_per_m = None
    for _, name, _expr, _start in assigns:
        n = _norm(name)
        v = names.get(name)
        if v is None or v <= 0:
            continue
        if n in _SCALE_NAMES:
            px_per_m = v
            break
        if n in _INV_SCALE_NAMES:
            px_per_m = 1.0 / v
            break

    gravity = _gravity(src, engine, names, assigns)

    # ---------------------------------------------------------------- aliases and names
    # Blender: `obj = bpy.context.active_object` then `obj.name = "red_ball"`: later
    # statements on `obj` refer to "red_ball" (until renamed); `rb = obj.rigid_body` aliases.
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

    # ---------------------------------------------------------------- materials (cannon)
    materials: dict[str, dict[str, Any]] = {}
    for m in _finditer(r"(?<![\w$.])(" + _ID + r")\s*=(?!=)\s*new\s+(?:[\w$]+\.)?Material\s*\(",
                         src):
        inner = _block(src, m.end() - 1) or ""
        props = _props(inner, names)
        label = None
        s = re.match(r"^\s*['\"]([^'\"]{1,80})['\"]", inner)
        if s:
            label = s.group(1)
        materials[m.group(1)] = {"label": label or props.get("name"),
                                 "friction": props.get("friction"),
                                 "restitution": props.get("restitution"), "bodies": []}

    # ---------------------------------------------------------------- body blocks
    block_re = re.compile(r"(?<![\w$])((?:this|self)\.)?(" + _ID + r")\s*=(?![=>])\s*"
                          r"(?:new\s+)?([\w$.]*)\s*([({])")
    matter_default: list[str] = []  # matter bodies with neither density nor mass option
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
        _body_props(bodies, name, props, names, f"{ctor or 'object'} options")
        mat = props.get("material#")
        if isinstance(mat, str) and mat.strip() in materials:
            materials[mat.strip()]["bodies"].append(name)
        if ctor.split(".")[-1] in ("circle", "rectangle") and "Bodies" in ctor:
            parts = _split_top(inner)
            nums = [eval_number(p, names) for p in parts[2:4]]
            if ctor.endswith("circle") and nums[:1] and nums[0]:
                bodies.set(name, "area", math.pi * nums[0] ** 2, "Bodies.circle radius")
            elif ctor.endswith("rectangle") and len(nums) == 2 and all(nums):
                bodies.set(name, "area", abs(nums[0] * nums[1]), "Bodies.rectangle size")
            if "density" not in props and "mass" not in props:
                matter_default.append(name)

    # objects named inside arrays / calls: {id: 'red_ball', mass: 2} or make('red_ball', mass=2)
    for m in _finditer(r"\{\s*['\"]?(?:id|name|label)['\"]?\s*:\s*['\"]([^'\"]{1,80})['\"]", src):
        inner = _block(src, m.start())
        if inner is not None:
            _body_props(bodies, m.group(1), _props(inner, names), names, "object literal")
    for m in _finditer(r"(?<![\w$.])[\w$.]+\s*\(\s*['\"]([A-Za-z][\w\- ]{0,79})['\"]\s*,", src):
        inner = _block(src, src.index("(", m.start()))
        if inner is not None:
            _body_props(bodies, m.group(1), _props(inner, names), names, "call arguments")

    # ---------------------------------------------------------------- property assignments
    prop_re = re.compile(r"(?<![\w$.])(" + _ID + r")((?:\.[A-Za-z_$][\w$]*)*)\.("
                         r"mass|density|restitution|friction|elasticity|bounce|bounciness)"
                         r"\s*=(?!=)\s*([^;\n]{1,200})")
    for m in itertools.islice(prop_re.finditer(src), MAX_ITEMS):
        base, chain, key, expr = m.group(1), m.group(2), m.group(3), m.group(4)
        kind = _classify_key(key)
        v = eval_number(_first_expr(expr), names)
        if v is None or kind is None:
            continue
        if "defaultContactMaterial" in chain or base == "defaultContactMaterial":
            default.setdefault(kind, {"value": v, "pattern": f"defaultContactMaterial.{key}"})
        elif base in materials and not chain:
            if materials[base].get(kind) is None:
                materials[base][kind] = v
        else:
            name = resolve(base, m.start())
            pattern = f"{base}{chain}.{key} ="
            bodies.set(name, kind, v, pattern)
    for m in _finditer(r"(?<![\w$.])(" + _ID + r")\.material\s*=(?!=)\s*(" + _ID + r")", src):
        if m.group(2) in materials:
            materials[m.group(2)]["bodies"].append(resolve(m.group(1), m.start()))

    # Matter helpers: Body.setMass(b, m), Body.setDensity(b, d)
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
        _body_props(bodies, name, props, names, "createFixture")
        if len(parts) >= 2 and "density" not in props:
            bodies.set(name, "density", eval_number(parts[1], names), "createFixture density")
        bodies.set(name, "area", _shape_area(parts[0] if parts else None, names),
                   "createFixture shape")

    for name in matter_default:  # matter's default density, unless set later
        if not {"density", "mass"} & set(bodies.data.get(name, {})):
            bodies.set(name, "density", 0.001, "matter default density")

    # ---------------------------------------------------------------- velocities
    for m in _finditer(r"(?<![\w$.])(" + _ID + r")\.velocity\.set\s*\(", src):
        vec = _vector(_block(src, m.end() - 1), names)
        bodies.set(resolve(m.group(1), m.start()), "velocity", vec, "velocity.set(...)")
    for m in _finditer(r"(?<![\w$.])(" + _ID + r")\.(?:velocity|linear_velocity|"
                         r"linearVelocity)\s*=(?!=)\s*", src):
        vec = _vector(_expr_at(src, m.end()), names)
        bodies.set(resolve(m.group(1), m.start()), "velocity", vec, "velocity =")
    for m in _finditer(r"(?<![\w$.])(" + _ID + r")\.[sS]et[Ll]inear[Vv]elocity\s*\(", src):
        inner = _block(src, m.end() - 1)
        vec = _vector(inner, names) if inner is not None else None
        bodies.set(resolve(m.group(1), m.start()), "velocity", vec, "setLinearVelocity")
    for m in _finditer(r"\bBody\.setVelocity\s*\(\s*(" + _ID + r")\s*,\s*", src):
        vec = _vector(_expr_at(src, m.end()), names)
        bodies.set(m.group(1), "velocity", vec, "Body.setVelocity (px/step)",
                   unit="matter_step")
    comp: dict[str, dict[str, float]] = {}
    for m in _finditer(r"(?<![\w$.])(" + _ID + r")\.(?:velocity|vel|v)\.([xyz])\s*=(?!=)\s*"
                         r"([^;\n]{1,100})", src):
        v = eval_number(_first_expr(m.group(3)), names)
        if v is not None:
            comp.setdefault(resolve(m.group(1), m.start()), {}).setdefault(m.group(2), v)
    for m in _finditer(r"(?<![\w$.])(" + _ID + r")\.(vx|vy|vz)0?\s*=(?!=)\s*([^;\n]{1,100})",
                         src):
        v = eval_number(_first_expr(m.group(3)), names)
        if v is not None:
            comp.setdefault(resolve(m.group(1), m.start()), {}).setdefault(m.group(2)[1], v)
    for name, c in comp.items():
        bodies.set(name, "velocity", [c.get(k, 0.0) for k in "xyz" if k in c] or None,
                   "velocity components")

    # ---------------------------------------------------------------- prefixed constants
    free: dict[str, float] = {}
    free_vec = None
    for _pos, name, expr, start in assigns:
        v = names.get(name)
        n = _norm(name)
        if v is not None:
            kind = _classify_key(name)
            if kind in ("restitution", "friction") and kind not in default:
                default[kind] = {"value": v, "pattern": f"{name} = ..."}
                continue
            if n in ("vx", "vy", "vz", "vx0", "vy0", "vz0", "velx", "vely", "velz"):
                free.setdefault(n.replace("vel", "v")[:2], v)
                continue
            if n in ("v0", "speed", "initialspeed", "speed0", "initialvelocity", "u0"):
                free.setdefault("speed", abs(v))
                continue
            split = _split_name(name)
            if split:
                hint, key = split
                kind = _classify_key(key)
                if kind in ("mass", "density", "restitution", "friction"):
                    bodies.set(hint, kind, v, f"{name} = ...")
                elif key in ("vx", "vy", "vz"):
                    d = bodies.data.setdefault(hint, {})
                    d.setdefault("_comp", {})[key[1]] = v
        elif n in ("vel", "velocity", "v", "v0", "initialvelocity", "vel0") and free_vec is None:
            free_vec = _vector(_expr_at(src, start), names)
        else:
            split = _split_name(name)
            if split and split[1] in ("velocity", "vel") or (
                    n.endswith(("velocity", "vel")) and len(n) > 5):
                hint = re.sub(r"(?i)[_]?(velocity|vel)0?$", "", name)
                vec = _vector(_expr_at(src, start), names)
                bodies.set(hint, "velocity", vec, f"{name} = ...")
    for name, d in list(bodies.data.items()):
        c = d.pop("_comp", None)
        if c and "velocity" not in d:
            d["velocity"] = {"value": [c.get(k, 0.0) for k in "xyz" if k in c],
                             "pattern": "prefixed vx/vy constants"}
        if not d:
            del bodies.data[name]
    free_velocity = None
    if free_vec is not None:
        free_velocity = {"value": float(math.sqrt(sum(x * x for x in free_vec))),
                         "pattern": "velocity vector constant"}
    elif any(k in free for k in ("vx", "vy", "vz")):
        free_velocity = {"value": float(math.sqrt(sum(free.get(k, 0.0) ** 2
                                                      for k in ("vx", "vy", "vz")))),
                         "pattern": "vx/vy constants"}
    elif "speed" in free:
        free_velocity = {"value": free["speed"], "pattern": "speed constant"}

    # ---------------------------------------------------------------- contact materials
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
            mat = materials.get(p)
            hints = list(mat["bodies"]) if mat else []
            if not hints:
                hints = [h for h in (mat.get("label") if mat else None, p) if h]
            sides.append(list(dict.fromkeys(hints))[:64])
        if len(sides) == 2:
            pairs.append({"a": sides[0], "b": sides[1], "friction": fr, "restitution": re_,
                          "pattern": "ContactMaterial(a, b, {...})"})
    for name, mat in materials.items():  # per-material coefficients -> the bodies using them
        for k in ("friction", "restitution"):
            if isinstance(mat.get(k), float):
                for b in mat["bodies"]:
                    bodies.set(b, k, mat[k], f"Material {name}.{k}")

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


def _first_expr(expr: str) -> str:
    return _split_top(expr)[0] if _split_top(expr) else expr


def _expr_at(src: str, i: int) -> str:
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


def _body_props(bodies: _Bodies, name: Any, props: dict[str, Any], names: dict[str, float],
                where: str) -> None:
    if not isinstance(name, str) or not name:
        return
    for key, value in props.items():
        if key.endswith("#") or not isinstance(value, float):
            continue
        kind = _classify_key(key)
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
            v = eval_number(_first_expr(m.group(2)), names)
            if v is not None:
                comps.setdefault(m.group(1), v)
        if comps:
            found = ([comps[k] for k in sorted(comps)], "gravity.x/y/z =")
    if found is None:  # Python tuples / vectors: scene.gravity = (0, 0, -9.81)
        m = re.search(r"\bgravity\s*=(?![=>])\s*", src)
        if m:
            vec = _vector(_expr_at(src, m.end()), names)
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
