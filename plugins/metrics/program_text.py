"""The text layer of the program analyser (`program_params.py`): its limits and name tables,
the safe arithmetic evaluator, and the helpers that strip comments, match brackets and read
assignments, object literals and vectors out of program text. Nothing here knows an engine."""

from __future__ import annotations

import ast
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


def _brackets(src: str, start: int, end: int, quotes: str, newline_ends_quote: bool):
    """The brackets of ``src[start:end]`` outside quoted text, in order: (position, closer)
    for an opener, (position, None) for a closer (then the character itself is ``src[pos]``).
    A backslash inside quotes skips the next character; with ``newline_ends_quote`` a newline
    ends a quote too."""
    quote = None
    j = start
    while j < end:
        c = src[j]
        if quote:
            if c == "\\":
                j += 2
                continue
            if c == quote or (newline_ends_quote and c == "\n"):
                quote = None
        elif c in quotes:
            quote = c
        elif c in _OPEN:
            yield j, _OPEN[c]
        elif c in ")]}":
            yield j, None
        j += 1


def _bracket_pairs(src: str) -> dict[int, int]:
    """Matching brackets of a whole source in one pass (quotes end at a newline, so a stray
    apostrophe in text cannot hide the rest of the program; an unbalanced opener is dropped)."""
    if _MATCH_CACHE[0] is src:
        return _MATCH_CACHE[1]
    pairs: dict[int, int] = {}
    stack: list[tuple[str, int]] = []
    for j, closer in _brackets(src, 0, len(src), "'\"", True):
        if closer is not None:
            stack.append((closer, j))
            continue
        while stack and stack[-1][0] != src[j]:  # unbalanced opener: drop it
            stack.pop()
        if stack:
            pairs[stack.pop()[1]] = j
    _MATCH_CACHE[0], _MATCH_CACHE[1] = src, pairs
    return pairs


def _block(src: str, i: int) -> str | None:
    """Inner text of the bracket opening at ``src[i]`` (None when unbalanced or too long).
    Within `MAX_BLOCK` characters the scan is strict (template literals are quotes, a
    mismatched closer ends it); a longer source uses the whole source's `_bracket_pairs`."""
    if i >= len(src) or src[i] not in _OPEN:
        return None
    if len(src) > 2 * MAX_BLOCK:
        k = _bracket_pairs(src).get(i)
        return src[i + 1:k] if k is not None and k - i <= MAX_BLOCK else None
    stack = [_OPEN[src[i]]]
    for j, closer in _brackets(src, i + 1, min(len(src), i + MAX_BLOCK), "'\"`", False):
        if closer is not None:
            stack.append(closer)
        elif src[j] != stack[-1]:
            return None
        else:
            stack.pop()
            if not stack:
                return src[i + 1:j]
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
