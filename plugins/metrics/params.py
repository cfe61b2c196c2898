"""Parameter recovery (docs/metrics.md): how far the physical parameters a model states are from
the ground truth's, scored only where the clip reveals them.

Five scene metrics (family ``physics``, lower is better, ``needs`` spec and program):

=========================  ==================================================================
``param_gravity_err``      |‖g_model‖ − ‖g_gt‖| in m/s²
``param_restitution_err``  mean over the revealed contact pairs of |e_model − e_gt|
``param_friction_err``     mean over the revealed contact pairs of |μ_model − μ_gt|
``param_mass_ratio_err``   mean over the revealed pairs of |ln(m_a/m_b)_model − ln(m_a/m_b)_gt|
                           (nats: 0.69 = a ratio off by a factor 2; scale-free, so a model that
                           gets the ratio right with other absolute masses is not penalised)
``param_speed_err``        mean over the revealed moving bodies of |‖v0‖_model − ‖v0‖_gt| in m/s
=========================  ==================================================================

What is scored: the ground truth's ``ground_truth.identifiable`` (written by the generator,
`visphy_plugins.datasets.visphybench.identifiable`): ``gravity`` (bool), ``initial_velocity``
(body ids), ``restitution``, ``friction`` and ``mass_ratio`` (id pairs). A parameter the clip
does not reveal is NaN (recorded as None, status ``not_revealed``); a revealed one for which the
model's reply gives no usable value is NaN too (status ``not_determinable``); a pair parameter
is the mean over the items the model determines (the breakdown counts how many).

Ground-truth values: ‖world.gravity_m_s2‖; a pair's effective coefficient is the explicit
``contacts.pairs`` entry, else ``contacts.default`` (both simulators apply exactly that: Box2D's
PreSolve in 2D, one cannon-es ContactMaterial per pair in 3D); mass ``material.mass_kg``, else
density × area (2D: density_kg_m2 × area_px / px_per_m²; 3D: density_kg_m3 × volume); speed
‖velocity.linear_m_s‖ (3D) or ‖(vx_px_s, vy_px_s)‖ / world.units.px_per_m (2D).

The model's values come from its scene specification S when S states them, else from a static
analysis of its program (`plugins/metrics/program_params.py`):

* bodies are matched to the ground truth by id, then by one min-cost assignment over the
  object tracks' tint-tolerant colour cost (a paler, tinted or shaded ``color_rgb`` matches,
  another hue does not), the category and the initial position; the floor / walls are
  ``floor`` (3D) and ``wall_bottom|left|right|top`` (2D), also recognised as ``ground``,
  ``plane``, ``bottom_wall``…; program bodies are matched by name (variable, id/name/label
  string, Blender ``obj.name``) against the ids' words (colour + shape, with synonyms);
* a pair coefficient from S: the S ``contacts.pairs`` entry for the two matched bodies, else S's
  ``contacts.default``, else the bodies' own ``material`` values combined by the mixing rule of
  the engine that simulated the ground truth (2D Box2D: friction √(μa·μb), restitution
  max(ea, eb); 3D cannon-es: μa·μb and ea·eb); when only one side states a value (walls and
  the floor carry no material) that value is used;
* from a program: a cannon ``ContactMaterial`` between the two bodies' materials, else the
  bodies' own coefficients combined by the program's engine (cannon and Blender/Bullet:
  product; matter-js: friction min, restitution max; planck/box2d: √ and max; a hand-written
  integrator: the ground truth engine's rule), else the program's scene-wide value
  (``defaultContactMaterial``, ``const restitution = 0.7``…);
* gravity from S ``world.gravity_m_s2`` (m/s² at face value, 2D or 3D vector or a number);
  from a program, a magnitude in [1, 50] is read as m/s² at face value; a larger one is in
  pixels: divided by the program's own px-per-metre constant when it declares one, else (2D
  only) by the ground truth's px_per_m · T², T = simulated seconds per video second
  (steps_per_frame · dt · video_fps: 5 for the PHYRE clips, 1 in 3D), i.e. the physical gravity
  the animation implies on the clip's pixel grid and clock; anything else (per-frame
  integrators, 3D programs in pixels, matter-js without a scale in 3D) is not determinable;
* speed from S: 3D ‖linear_m_s‖; 2D ‖(vx_px_s, vy_px_s)‖ / px_per_m with S's own px_per_m when
  S states one (the model's belief in metres, consistent with its gravity in m/s²), else the
  ground truth's (the breakdown also records the pixel error); from a program: in the program's
  length unit per second (m/s when its gravity is in m/s²; pixels converted as gravity, with T
  instead of T²; matter-js velocities are pixels per 1/60 s step);
* masses from S (kg: mass_kg or density × the S shape's area/volume) or, for both bodies of a
  pair together, from the program (``mass``, or density × shape area: any consistent unit, only
  the ratio counts).

Nothing here raises on a hostile reply: a value that is not a finite number in a plausible range
(coefficients in [0, 1000], |g| ≤ 10⁴ m/s², speed ≤ 10⁴ m/s, mass in (0, 10¹²]) is not
determinable.

The per-scene breakdown (model value, ground truth value, source, error for each item) is
stored in ``inp.extra["param_recovery"]`` by the first of these metrics that runs on a scene, and
`parameter_recovery(gt_spec, spec, program, language)` computes it directly (the scorer caches
metric values, so a cached scene does not run `compute`). `gt_parameter_table(specs)` gives the
dataset's mean ground-truth values beside the paper's (g 9.82, e 0.15, μ 0.40, mass 1.25 kg,
speed 2.59 m/s).
"""
# size: parameter recovery: each parameter's visibility rule and error beside the others

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Iterable

import numpy as np
from scipy.optimize import linear_sum_assignment

from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.metrics import LOWER, SCENE, Metric, MetricInput
from visphy_plugins.metrics.association import COLOUR_GATE, colour_cost, colour_features
from visphy_plugins.metrics.program_params import analyse_program, match_name, name_tokens

PARAMS = ("gravity", "restitution", "friction", "mass_ratio", "speed")
UNITS = {"gravity": "m/s^2", "restitution": "1", "friction": "1", "mass_ratio": "nats",
         "speed": "m/s"}
EXTRA_KEY = "param_recovery"
CATEGORY_COST = 0.5            # S body matching: categories differ
POSITION_SCALE = (64.0, 0.5)   # S body matching: px (2D), m (3D)...
POSITION_CAP = 1.5             # ...capped: a body placed elsewhere is still found by colour
MAX_COEF, MAX_G, MAX_SPEED, MAX_MASS = 1e3, 1e4, 1e4, 1e12

#: docs/metrics.md: the paper's ground-truth means and GPT-5's mean absolute errors.
PAPER_GT_MEANS = {"gravity": 9.82, "restitution": 0.15, "friction": 0.40, "mass": 1.25,
                  "speed": 2.59}
PAPER_GPT5_MAE = {"restitution": 0.17, "friction": 0.10, "mass": 0.15, "speed": 2.07}

_WALLS_2D = {"wall_bottom": ("wall_bottom", "bottom_wall", "floor", "ground", "bottom"),
             "wall_left": ("wall_left", "left_wall", "left"),
             "wall_right": ("wall_right", "right_wall", "right"),
             "wall_top": ("wall_top", "top_wall", "ceiling", "top")}
_FLOOR_3D = {"floor": ("floor", "ground", "plane", "ground_plane", "floor_plane")}


# ------------------------------------------------------------------------------ numbers
def _num(x: Any, limit: float = float("inf")) -> float | None:
    """A finite float no larger than ``limit`` in magnitude, else None."""
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        return None
    try:
        v = float(x)
    except (OverflowError, ValueError):
        return None
    return v if math.isfinite(v) and abs(v) <= limit else None


def _coef(x: Any) -> float | None:
    v = _num(x, MAX_COEF)
    return v if v is not None and v >= 0 else None


def _vec_norm(v: Any, limit: float) -> float | None:
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        n = _num(v, limit)
        return abs(n) if n is not None else None
    if not isinstance(v, (list, tuple)) or not 1 <= len(v) <= 3:
        return None
    vals = [_num(x, limit) for x in v]
    if any(x is None for x in vals):
        return None
    n = math.sqrt(sum(x * x for x in vals))
    return n if n <= limit else None


def _get(d: Any, *path: str) -> Any:
    for k in path:
        if not isinstance(d, dict):
            return None
        d = d.get(k)
    return d


def _mix(a: float | None, b: float | None, rule: str) -> float | None:
    if a is None:
        return b
    if b is None:
        return a
    if rule == "sqrt":
        return math.sqrt(a * b)
    if rule == "max":
        return max(a, b)
    if rule == "min":
        return min(a, b)
    return a * b


#: Mixing rule of the engine that simulated the ground truth (used for S without contacts).
GT_MIXING = {"2d": {"friction": "sqrt", "restitution": "max"},      # Box2D b2MixFriction/...
             "3d": {"friction": "product", "restitution": "product"}}  # cannon-es materials


# ------------------------------------------------------------------------------ geometry
def _area_2d(shape: Any) -> float | None:
    """Area (px²) of a 2D spec shape, None when the shape is not well formed."""
    if not isinstance(shape, dict):
        return None
    kind = shape.get("type")
    if kind == "circle":
        r = _num(shape.get("radius_px"), 1e6)
        return math.pi * r * r if r and r > 0 else None
    if kind == "box":
        a, b = _num(shape.get("length_px"), 1e6), _num(shape.get("thickness_px"), 1e6)
        return abs(a * b) if a and b else None
    polys = []
    if kind == "polygon":
        polys = [shape.get("vertices_px")]
    elif kind == "compound" and isinstance(shape.get("parts_px"), list):
        polys = shape["parts_px"][:64]
    total = 0.0
    for poly in polys:
        if not isinstance(poly, list) or not 3 <= len(poly) <= 64:
            return None
        pts = []
        for p in poly:
            if not isinstance(p, (list, tuple)) or len(p) != 2:
                return None
            x, y = _num(p[0], 1e6), _num(p[1], 1e6)
            if x is None or y is None:
                return None
            pts.append((x, y))
        total += abs(sum(pts[i][0] * pts[i - 1][1] - pts[i - 1][0] * pts[i][1]
                         for i in range(len(pts)))) / 2.0
    return total if total > 0 else None


def _volume_3d(shape: Any, depth: int = 0) -> float | None:
    if not isinstance(shape, dict) or depth > 2:
        return None
    kind = shape.get("type")
    if kind == "sphere":
        r = _num(shape.get("radius_m"), 1e6)
        return 4.0 / 3.0 * math.pi * r ** 3 if r and r > 0 else None
    if kind == "box":
        s = shape.get("size_m")
        if not isinstance(s, list) or len(s) != 3:
            return None
        vals = [_num(x, 1e6) for x in s]
        return abs(vals[0] * vals[1] * vals[2]) if all(vals) else None
    if kind == "wedge":
        vals = [_num(shape.get(k), 1e6) for k in ("length_m", "height_m", "width_m")]
        return abs(0.5 * vals[0] * vals[1] * vals[2]) if all(vals) else None
    if kind == "compound" and isinstance(shape.get("parts"), list):
        vols = [_volume_3d(_get(p, "shape"), depth + 1) for p in shape["parts"][:64]]
        return sum(vols) if vols and all(vols) else None
    return None


def _body_mass(body: Any, dim: str, ppm: float | None) -> float | None:
    """Mass in kg of a spec body (ground truth or S), None when not determinable."""
    if not isinstance(body, dict) or body.get("dynamic") is False:
        return None
    mat = body.get("material")
    if not isinstance(mat, dict):
        return None
    m = _num(mat.get("mass_kg"), MAX_MASS)
    if m is not None:
        return m if m > 0 else None
    if dim == "3d":
        d, vol = _num(mat.get("density_kg_m3"), MAX_MASS), _volume_3d(body.get("shape"))
        m = d * vol if d is not None and vol else None
    else:
        d, area = _num(mat.get("density_kg_m2"), MAX_MASS), _area_2d(body.get("shape"))
        m = d * area / (ppm * ppm) if d is not None and area and ppm else None
    return m if m is not None and 0 < m <= MAX_MASS else None


def _body_speed(body: Any, dim: str, ppm: float | None) -> tuple[float | None, float | None]:
    """(speed in m/s, speed in px/s for 2D) of a spec body's initial velocity."""
    v = _get(body, "velocity")
    if not isinstance(v, dict):
        return None, None
    if dim == "3d":
        return _vec_norm(v.get("linear_m_s"), MAX_SPEED), None
    vx, vy = _num(v.get("vx_px_s"), MAX_SPEED * 1e4), _num(v.get("vy_px_s"), MAX_SPEED * 1e4)
    if vx is None or vy is None:
        return None, None
    px = math.hypot(vx, vy)
    if not ppm:
        return None, px
    s = px / ppm
    return (s if s <= MAX_SPEED else None), px


def _ppm(spec: Any) -> float | None:
    v = _num(_get(spec, "world", "units", "px_per_m"), 1e6)
    return v if v is not None and v > 0 else None


def _time_scale(spec: Any) -> float:
    """Simulated seconds per second of video (2D PHYRE clips: 5; 3D: 1)."""
    w = _get(spec, "world") or {}
    spf, dt, fps = _num(w.get("steps_per_frame")), _num(w.get("dt_s")), _num(w.get("video_fps"))
    if spf and dt and fps and spf > 0 and dt > 0 and fps > 0:
        return spf * dt * fps
    return 1.0


# ------------------------------------------------------------------------------ ground truth
def _gt_pair(spec: dict, a: str, b: str, key: str) -> float | None:
    contacts = spec.get("contacts") if isinstance(spec.get("contacts"), dict) else {}
    pairs = contacts.get("pairs") if isinstance(contacts.get("pairs"), list) else []
    for p in pairs:
        if isinstance(p, dict) and {p.get("a"), p.get("b")} == {a, b}:
            return _coef(p.get(key))
    return _coef(_get(contacts, "default", key))


def _gt_bodies(spec: dict) -> dict[str, dict]:
    out: dict[str, dict] = {}
    bodies = spec.get("bodies")
    for b in bodies[:4096] if isinstance(bodies, list) else []:
        if isinstance(b, dict) and isinstance(b.get("id"), str):
            out.setdefault(b["id"], b)
    return out


def _pairs(x: Any) -> list[tuple[str, str]]:
    out = []
    for p in x if isinstance(x, list) else []:
        if isinstance(p, (list, tuple)) and len(p) == 2 and all(isinstance(s, str) for s in p):
            out.append((p[0], p[1]))
    return out


def _env(dim: str) -> dict[str, tuple[str, ...]]:
    return _FLOOR_3D if dim == "3d" else _WALLS_2D


# ------------------------------------------------------------------------------ S matching
def _color(x: Any) -> tuple[float, float, float] | None:
    if not isinstance(x, (list, tuple)) or len(x) != 3:
        return None
    vals = [_num(v, 1e4) for v in x]
    return None if any(v is None for v in vals) else tuple(vals)  # type: ignore[return-value]


def _position(body: Any, dim: str) -> tuple[float, ...] | None:
    pose = _get(body, "pose")
    if dim == "3d":
        p = _get(pose, "position_m")
        if isinstance(p, list) and len(p) == 3:
            vals = [_num(v, 1e9) for v in p]
            return None if any(v is None for v in vals) else tuple(vals)
        return None
    x, y = _num(_get(pose, "x_px"), 1e9), _num(_get(pose, "y_px"), 1e9)
    return None if x is None or y is None else (x, y)


def match_spec_bodies(gt: dict, spec: Any, dim: str) -> dict[str, dict]:
    """Ground-truth id -> the S body it corresponds to: same id first; the others by one
    min-cost assignment over the tint-tolerant colour cost of the object tracks
    (`plugins/metrics/association.py`: a paler, tinted or shaded version of the colour is close,
    another hue is not; pairs beyond `COLOUR_GATE` never match), plus `CATEGORY_COST` when the
    categories differ and the distance of the initial positions over `POSITION_SCALE` (capped
    at `POSITION_CAP`)."""
    if not isinstance(spec, dict) or not isinstance(spec.get("bodies"), list):
        return {}
    model = [b for b in spec["bodies"][:256] if isinstance(b, dict)]
    gt_bodies = _gt_bodies(gt)
    out: dict[str, dict] = {}
    used: set[int] = set()
    for gid in gt_bodies:
        for i, b in enumerate(model):
            if i not in used and b.get("id") == gid:
                out[gid] = b
                used.add(i)
                break
    rows = [(gid, _color(gb.get("color_rgb"))) for gid, gb in gt_bodies.items() if gid not in out]
    rows = [(gid, c) for gid, c in rows if c is not None]
    cols = [(i, _color(b.get("color_rgb"))) for i, b in enumerate(model) if i not in used]
    cols = [(i, c) for i, c in cols if c is not None]
    if not rows or not cols:
        return out
    colour = colour_cost(colour_features(np.clip([c for _, c in rows], 0, 255)),
                         colour_features(np.clip([c for _, c in cols], 0, 255)))
    cost = np.where(colour <= COLOUR_GATE, colour ** 2, np.inf)
    scale = POSITION_SCALE[dim == "3d"]
    for r, (gid, _) in enumerate(rows):
        gb = gt_bodies[gid]
        gp = _position(gb, dim)
        for c, (i, _) in enumerate(cols):
            mp = _position(model[i], dim)
            if gb.get("category") != model[i].get("category"):
                cost[r, c] += CATEGORY_COST
            if gp is not None and mp is not None and len(gp) == len(mp):
                cost[r, c] += min(math.dist(gp, mp) / scale, POSITION_CAP) ** 2
    finite = np.where(np.isfinite(cost), cost, 1e9)
    for r, c in zip(*linear_sum_assignment(finite)):
        if np.isfinite(cost[r, c]):
            out[rows[r][0]] = model[cols[c][0]]
    return out


# ------------------------------------------------------------------------------ the recovery
class _Ctx:
    def __init__(self, gt: dict, spec: Any, program: Any, language: Any):
        self.gt = gt
        self.dim = "3d" if gt.get("dim") == "3d" else "2d"
        self.spec = spec if isinstance(spec, dict) else None
        self.gt_ppm = _ppm(gt) if self.dim == "2d" else None
        self.model_ppm = _ppm(self.spec) if self.dim == "2d" else None
        self.ts = _time_scale(gt)
        self.gt_bodies = _gt_bodies(gt)
        self.matched = match_spec_bodies(gt, self.spec, self.dim)
        self.prog = analyse_program(program, language if isinstance(language, str) else None)
        ents = {gid: name_tokens(gid) for gid in self.gt_bodies}
        for eid in _env(self.dim):
            ents[eid] = name_tokens(eid)
        self.entities = ents
        self._match_memo: dict[str, str | None] = {}
        self._pairs_memo: list[tuple[set, set, dict]] | None = None
        self.prog_bodies: dict[str, dict] = {}
        self.prog_names: dict[str, list[str]] = {}
        for pname, data in (self.prog.get("bodies") or {}).items():
            gid = self._prog_match(pname)
            if gid is None:
                continue
            self.prog_names.setdefault(gid, []).append(pname)
            merged = self.prog_bodies.setdefault(gid, {})
            for k, v in data.items():
                merged.setdefault(k, v)

    def _prog_match(self, name: Any) -> str | None:
        if not isinstance(name, str):
            return None
        if name not in self._match_memo:
            gid = None
            for eid, syn in _env(self.dim).items():
                if name.lower() in syn:
                    gid = eid
            self._match_memo[name] = gid or match_name(name, self.entities)
        return self._match_memo[name]

    def prog_pairs(self) -> list[tuple[set, set, dict]]:
        """The program's explicit pairs with each side mapped to ground-truth ids (once)."""
        if self._pairs_memo is None:
            self._pairs_memo = []
            for p in self.prog.get("pairs") or []:
                sa = {self._prog_match(h) for h in set(p.get("a") or [])} - {None}
                sb = {self._prog_match(h) for h in set(p.get("b") or [])} - {None}
                if sa and sb:
                    self._pairs_memo.append((sa, sb, p))
        return self._pairs_memo

    # names S uses for a ground-truth entity (its matched body, or the floor's/walls' names)
    def model_names(self, gid: str) -> set[str]:
        if gid in self.matched:
            mid = self.matched[gid].get("id")
            return {mid} if isinstance(mid, str) else set()
        env = _env(self.dim)
        return set(env.get(gid, ()))

    # ---------------------------------------------------------------- program conversions
    def prog_length(self, value: float, unit: str, power: int) -> tuple[float | None, str]:
        """A program length-based value (power 1: speed, 2: acceleration) in SI."""
        if unit == "matter_step":
            value, unit = value / (1.0 / 60.0), "px"
        lu = self.prog.get("length_unit") if unit == "len" else unit
        if lu == "m":
            return value, "program (m)"
        if lu == "px":
            own = _num(self.prog.get("px_per_m"))
            if own and own > 0:
                return value / own, "program (px / program px_per_m)"
            if self.dim == "2d" and self.gt_ppm:
                return value / (self.gt_ppm * self.ts ** power), \
                    f"program (px / gt px_per_m / T^{power})"
        return None, "program (units not interpretable)"


def _item(model: float | None, gt: float | None, source: str | None, **kw) -> dict:
    err = abs(model - gt) if model is not None and gt is not None else None
    return {"model": model, "gt": gt, "source": source if model is not None else None,
            "err": err, **kw}


def _summary(items: list[dict], revealed: bool, param: str) -> dict:
    scored = [it for it in items if it["err"] is not None]
    out: dict[str, Any] = {"unit": UNITS[param], "n_revealed": len(items),
                           "n_scored": len(scored), "items": items}
    if not revealed:
        out.update(status="not_revealed", err=None, model=None, gt=None, source=None)
    elif not scored:
        out.update(status="not_determinable", err=None, model=None, gt=None, source=None)
    else:
        sources = sorted({str(it["source"]).split(":")[0].split(" ")[0] for it in scored})
        out.update(status="scored", err=sum(it["err"] for it in scored) / len(scored),
                   model=sum(it["model"] for it in scored) / len(scored),
                   gt=sum(it["gt"] for it in scored) / len(scored),
                   source=sources[0] if len(sources) == 1 else "mixed")
    return out


def _gravity(c: _Ctx, ident: dict) -> dict:
    revealed = ident.get("gravity") is True
    gt = _vec_norm(_get(c.gt, "world", "gravity_m_s2"), MAX_G)
    model, source = None, None
    if c.spec is not None:
        model = _vec_norm(_get(c.spec, "world", "gravity_m_s2"), MAX_G)
        source = "spec" if model is not None else None
    if model is None:
        g = c.prog.get("gravity")
        if g:
            if g.get("unit") == "zero":
                model, source = 0.0, f"program: {g['pattern']}"
            elif g.get("unit") in ("m", "px"):
                model, how = c.prog_length(g["value"], g["unit"], 2)
                source = f"program: {g['pattern']} -> {how}"
                if model is not None and model > MAX_G:
                    model = None
    items = [_item(model, gt, source, item="world")] if revealed else []
    return _summary(items, revealed, "gravity")


def _spec_pair_value(c: _Ctx, a: str, b: str, key: str) -> tuple[float | None, str | None]:
    if c.spec is None:
        return None, None
    na, nb = c.model_names(a), c.model_names(b)
    if not na or not nb:  # S has no body for one side: it says nothing about this pair
        return None, None
    contacts = c.spec.get("contacts") if isinstance(c.spec.get("contacts"), dict) else {}
    pairs = contacts.get("pairs") if isinstance(contacts.get("pairs"), list) else []
    for p in pairs[:4096]:
        if not isinstance(p, dict):
            continue
        pa, pb = p.get("a"), p.get("b")
        if (pa in na and pb in nb) or (pa in nb and pb in na):
            v = _coef(p.get(key))
            if v is not None:
                return v, "spec: contacts.pairs"
    v = _coef(_get(contacts, "default", key))
    if v is not None:
        return v, "spec: contacts.default"
    va = _coef(_get(c.matched.get(a), "material", key))
    vb = _coef(_get(c.matched.get(b), "material", key))
    if va is None and vb is None:
        return None, None
    rule = GT_MIXING[c.dim][key]
    how = f"{rule} of materials" if va is not None and vb is not None else "one side's material"
    return _mix(va, vb, rule), f"spec: {how}"


def _prog_pair_value(c: _Ctx, a: str, b: str, key: str) -> tuple[float | None, str | None]:
    for sa, sb, p in c.prog_pairs():
        v = _coef(p.get(key))
        if v is None:
            continue
        if (a in sa and b in sb) or (a in sb and b in sa):
            return v, f"program: {p.get('pattern')}"
    va = _coef(_get(c.prog_bodies.get(a), key, "value"))
    vb = _coef(_get(c.prog_bodies.get(b), key, "value"))
    if va is not None or vb is not None:
        mixing = c.prog.get("mixing") or GT_MIXING[c.dim]
        rule = mixing.get(key, "product")
        how = f"{rule} of body values" if va is not None and vb is not None else \
            "one body's value"
        return _mix(va, vb, rule), f"program: {how}"
    v = _coef(_get(c.prog.get("default"), key, "value"))
    if v is not None:
        return v, f"program: {_get(c.prog.get('default'), key, 'pattern')}"
    return None, None


def _pair_param(c: _Ctx, ident: dict, key: str) -> dict:
    items = []
    for a, b in _pairs(ident.get(key)):
        gt = _gt_pair(c.gt, a, b, key)
        model, source = _spec_pair_value(c, a, b, key)
        if model is None:
            model, source = _prog_pair_value(c, a, b, key)
        items.append(_item(model, gt, source, pair=[a, b]))
    return _summary(items, bool(items), key)


def _prog_mass(c: _Ctx, gid: str) -> float | None:
    d = c.prog_bodies.get(gid) or {}
    m = _num(_get(d, "mass", "value"), MAX_MASS)
    if m is not None:
        return m if m > 0 else None
    rho, area = _num(_get(d, "density", "value"), MAX_MASS), _num(_get(d, "area", "value"))
    if rho and area and rho > 0 and area > 0:
        return rho * area
    return None


def _mass_ratio(c: _Ctx, ident: dict) -> dict:
    items = []
    ppm_model = c.model_ppm or c.gt_ppm
    for a, b in _pairs(ident.get("mass_ratio")):
        ga = _body_mass(c.gt_bodies.get(a), c.dim, c.gt_ppm)
        gb = _body_mass(c.gt_bodies.get(b), c.dim, c.gt_ppm)
        gt = math.log(ga / gb) if ga and gb else None
        ma = _body_mass(c.matched.get(a), c.dim, ppm_model)
        mb = _body_mass(c.matched.get(b), c.dim, ppm_model)
        source = "spec"
        if not (ma and mb):
            ma, mb, source = _prog_mass(c, a), _prog_mass(c, b), "program"
        model = math.log(ma / mb) if ma and mb else None
        it = _item(model, gt, source, pair=[a, b])
        it.update(model_masses=[ma, mb] if model is not None else None, gt_masses_kg=[ga, gb])
        items.append(it)
    return _summary(items, bool(items), "mass_ratio")


def _speed(c: _Ctx, ident: dict) -> dict:
    ids = [i for i in (ident.get("initial_velocity") or []) if isinstance(i, str)] \
        if isinstance(ident.get("initial_velocity"), list) else []
    items = []
    for gid in ids:
        gt, gt_px = _body_speed(c.gt_bodies.get(gid), c.dim, c.gt_ppm)
        model, source, extra = None, None, {}
        body = c.matched.get(gid)
        if body is not None:
            ppm = c.model_ppm or c.gt_ppm
            model, px = _body_speed(body, c.dim, ppm)
            if model is not None:
                source = "spec" if c.dim == "3d" else \
                    f"spec (px/s / {'S' if c.model_ppm else 'gt'} px_per_m)"
                if px is not None and gt_px is not None:
                    extra = {"err_px_s": abs(px - gt_px)}
        if model is None:
            vel = (c.prog_bodies.get(gid) or {}).get("velocity")
            value = _vec_norm(_get(vel, "value"), 1e9) if vel else None
            pattern = _get(vel, "pattern")
            unit = _get(vel, "unit") or "len"
            if value is None and len(ids) == 1 and c.prog.get("free_velocity"):
                value = _num(c.prog["free_velocity"].get("value"), 1e9)
                pattern, unit = c.prog["free_velocity"].get("pattern"), "len"
            if value is not None:
                model, how = c.prog_length(value, unit, 1)
                source = f"program: {pattern} -> {how}"
                if model is not None and model > MAX_SPEED:
                    model = None
        items.append(_item(model, gt, source, body=gid, **extra))
    return _summary(items, bool(items), "speed")


def parameter_recovery(gt_spec: Any, spec: Any = None, program: Any = None,
                       language: Any = None) -> dict[str, Any]:
    """The per-scene breakdown: for each parameter its status (``scored``, ``not_revealed``,
    ``not_determinable``), error, mean model and ground-truth values, source and items, plus
    ``_meta`` (body matching, program engine and units). JSON-serialisable; never raises."""
    if not isinstance(gt_spec, dict):
        return {p: _summary([], False, p) for p in PARAMS} | {
            "_meta": {"error": "no ground-truth spec"}}
    try:
        c = _Ctx(gt_spec, spec, program, language)
        ident = _get(gt_spec, "ground_truth", "identifiable")
        ident = ident if isinstance(ident, dict) else {}
        out = {"gravity": _gravity(c, ident),
               "restitution": _pair_param(c, ident, "restitution"),
               "friction": _pair_param(c, ident, "friction"),
               "mass_ratio": _mass_ratio(c, ident),
               "speed": _speed(c, ident)}
        out["_meta"] = {
            "dim": c.dim, "spec_present": c.spec is not None,
            "spec_body_match": {g: b.get("id") for g, b in c.matched.items()},
            "program_engine": c.prog.get("engine"),
            "program_length_unit": c.prog.get("length_unit"),
            "program_px_per_m": c.prog.get("px_per_m"),
            "program_body_match": c.prog_names,
            "gt_px_per_m": c.gt_ppm, "model_px_per_m": c.model_ppm, "time_scale": c.ts}
        return json.loads(json.dumps(out, default=str))
    except (RecursionError, MemoryError, ValueError, TypeError, KeyError, AttributeError,
            IndexError, OverflowError, ZeroDivisionError) as exc:
        return {p: _summary([], False, p) for p in PARAMS} | {
            "_meta": {"error": f"{type(exc).__name__}: {exc}"[:300]}}


def recovery_for(inp: MetricInput) -> dict[str, Any]:
    """The breakdown of one scene, computed once and kept in ``inp.extra[EXTRA_KEY]``."""
    rec = inp.extra.get(EXTRA_KEY) if isinstance(inp.extra, dict) else None
    if isinstance(rec, dict):
        return rec
    try:
        gt = inp.scene.spec
    except Exception:  # noqa: BLE001 - an unreadable ground truth: nothing to score
        gt = None
    rec = parameter_recovery(gt, inp.spec, inp.program, inp.language)
    if isinstance(inp.extra, dict):
        inp.extra[EXTRA_KEY] = rec
    return rec


class ParamError(Metric):
    """Absolute error of one recovered parameter (see the module docstring)."""

    param = ""
    direction = LOWER
    score_range = (0.0, float("inf"))
    family = "physics"
    kind = SCENE
    needs = ("spec", "program")
    weights = None
    version = "2"  # tint-tolerant matching of S bodies by colour

    details_key = "param_recovery"

    def details(self, inp: MetricInput) -> dict:
        """The whole breakdown (every parameter: status, model and ground-truth values, where
        each came from), so a reader sees why a parameter was or was not scored."""
        return recovery_for(inp)

    def compute(self, inp: MetricInput) -> float:
        err = _get(recovery_for(inp), self.param, "err")
        v = _num(err)
        return float("nan") if v is None else v


class GravityError(ParamError):
    name, param = "param_gravity_err", "gravity"


class RestitutionError(ParamError):
    name, param = "param_restitution_err", "restitution"


class FrictionError(ParamError):
    name, param = "param_friction_err", "friction"


class MassRatioError(ParamError):
    name, param = "param_mass_ratio_err", "mass_ratio"


class SpeedError(ParamError):
    name, param = "param_speed_err", "speed"


METRICS = (GravityError, RestitutionError, FrictionError, MassRatioError, SpeedError)


# ------------------------------------------------------------------------------ GT table
def _load(spec: Any) -> dict | None:
    if isinstance(spec, dict):
        return spec
    try:
        return json.loads(Path(spec).read_text(encoding="utf-8"))
    except (OSError, ValueError, TypeError):
        return None


def gt_parameter_table(specs: Iterable[Any]) -> dict[str, Any]:
    """Mean ground-truth values over the scenes where the clip reveals them, beside the paper's.

    ``specs``: spec dicts or paths. Gravity: ‖g‖ over the scenes revealing gravity; restitution
    and friction: the effective pair coefficient over the revealed pairs; mass: kg of the
    dynamic bodies in revealed mass-ratio pairs (each body once per scene); speed: initial speed
    (m/s) of the revealed moving bodies. Returned per ``all``, ``2d`` and ``3d``:
    ``{param: {"mean": float | None, "n": int}}``, plus ``paper`` and ``paper_gpt5_mae``."""
    acc: dict[str, dict[str, list[float]]] = {
        g: {p: [] for p in PAPER_GT_MEANS} for g in ("all", "2d", "3d")}
    n_scenes = {"all": 0, "2d": 0, "3d": 0}
    for raw in specs:
        spec = _load(raw)
        if not isinstance(spec, dict):
            continue
        dim = "3d" if spec.get("dim") == "3d" else "2d"
        ident = _get(spec, "ground_truth", "identifiable")
        if not isinstance(ident, dict):
            continue
        ppm = _ppm(spec) if dim == "2d" else None
        bodies = _gt_bodies(spec)
        vals: dict[str, list[float]] = {p: [] for p in PAPER_GT_MEANS}
        if ident.get("gravity") is True:
            g = _vec_norm(_get(spec, "world", "gravity_m_s2"), MAX_G)
            if g is not None:
                vals["gravity"].append(g)
        for key in ("restitution", "friction"):
            for a, b in _pairs(ident.get(key)):
                v = _gt_pair(spec, a, b, key)
                if v is not None:
                    vals[key].append(v)
        seen: set[str] = set()
        for a, b in _pairs(ident.get("mass_ratio")):
            for gid in (a, b):
                if gid in seen:
                    continue
                seen.add(gid)
                m = _body_mass(bodies.get(gid), dim, ppm)
                if m is not None:
                    vals["mass"].append(m)
        for gid in ident.get("initial_velocity") or []:
            if isinstance(gid, str):
                s, _ = _body_speed(bodies.get(gid), dim, ppm)
                if s is not None:
                    vals["speed"].append(s)
        for group in ("all", dim):
            n_scenes[group] += 1
            for p, v in vals.items():
                acc[group][p].extend(v)
    out: dict[str, Any] = {}
    for group, params in acc.items():
        out[group] = {p: {"mean": (sum(v) / len(v)) if v else None, "n": len(v)}
                      for p, v in params.items()}
        out[group]["n_scenes"] = n_scenes[group]
    out["paper"] = dict(PAPER_GT_MEANS)
    out["paper_gpt5_mae"] = dict(PAPER_GPT5_MAE)
    return out


def format_gt_table(table: dict[str, Any]) -> str:
    """A Markdown table of `gt_parameter_table`'s means (n in parentheses) beside the paper's."""
    lines = ["| parameter | all | 2D | 3D | paper |", "|---|---|---|---|---|"]
    for p in PAPER_GT_MEANS:
        cells = []
        for group in ("all", "2d", "3d"):
            e = table.get(group, {}).get(p, {})
            cells.append("—" if e.get("mean") is None else f"{e['mean']:.2f} (n={e['n']})")
        lines.append(f"| {p} | {' | '.join(cells)} | {PAPER_GT_MEANS[p]:.2f} |")
    return "\n".join(lines)


@hookimpl
def visphy_register_metrics(register):
    for cls in METRICS:
        register(cls())
