"""Reusable 2D building blocks of PHYRE-style scenes: bodies, geometry helpers and the spec wrapper.

Why a separate module: every 2D template family (combinatorial PhyWorld-style scenes, law-probing
scenes) composes the same PHYRE objects, and their geometry must agree with what `spec.category_of`
reports, so the conventions live here once:

* ball -> circle; bar -> thin box (W/50 thick, length/thickness >= 4 -> "line"); box -> rectangle
  (keep length/thickness < 4); jar -> three-part compound (base + two walls) -> "u_shape";
  standing sticks -> an X of two thin bars, stored as five disjoint convex parts (centre
  parallelogram + four arms, so areas and centroids stay exact) -> "composite_shape";
  triangle -> 3-vertex polygon; other convex polygons (5+ vertices) -> "composite_shape";
* polygon vertices are given relative to the area centroid, so a body's pose is its centre;
* dynamic bodies get PHYRE's material (density 0.25, friction 0.5, restitution 0.2) unless a
  template overrides the density (mass-ratio scenes);
* bodies meant to rest on something are placed `GAP` px above it, so nothing overlaps at t = 0.

Besides single bodies the module holds the random *groups* PhyWorld-style templates combine
(`GROUPS`: a tilted bar, a ball on a shelf, a jar, a box tower, a seesaw, standing sticks, ...;
each `g_*` draws sizes, pose and colours from an rng) and `Layout`, the occupancy grid that
rejection-samples groups so they sit `MARGIN` px apart and entirely on screen.
"""
# size: the 2D building blocks every template family composes

from __future__ import annotations

import math
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from visphy_core.api.scene import SPEC_SCHEMA
from visphy_core.api.spec import PHYRE_PROFILE, category_of, local_polygons, transform_points
from visphy_plugins.datasets.visphybench.filters import window_mask
from visphy_plugins.datasets.visphybench.raster2d import PALETTE

BAR = PHYRE_PROFILE["bar_thickness_px"]  # 10.24 px, PHYRE bars are W/50 thick
CANVAS = tuple(int(v) for v in PHYRE_PROFILE["canvas_px"])  # (512, 512)
W, H = CANVAS
#: Minimum clearance (px) between groups placed by `Layout`.
MARGIN = 3.0
#: Clearance (px) between a resting body and its support at t = 0.
GAP = 0.5
DYNAMIC_COLORS = ("gray", "green", "blue")
STATIC_COLORS = ("black", "purple")
#: `world.profile` of scenes that keep PHYRE's constants except gravity (gravity law templates).
GRAVITY_PROFILE = "phyre-gravity"


# ------------------------------------------------------------------------------------ bodies
def body(bid: str, color: str, shape: dict, x: float, y: float, angle: float = 0.0,
         dynamic: bool = True, velocity: Sequence[float] | None = None,
         density: float | None = None) -> dict:
    """One spec body; `velocity` is (vx_px_s, vy_px_s, omega_rad_s); category from geometry."""
    out: dict[str, Any] = {"id": bid, "category": "", "dynamic": bool(dynamic),
                           "color_rgb": list(PALETTE[color]), "shape": shape,
                           "pose": {"x_px": float(x), "y_px": float(y),
                                    "angle_rad": float(angle)}}
    if dynamic:
        vx, vy, w = velocity if velocity is not None else (0.0, 0.0, 0.0)
        out["velocity"] = {"vx_px_s": float(vx), "vy_px_s": float(vy), "omega_rad_s": float(w)}
        out["material"] = {
            "density_kg_m2": float(PHYRE_PROFILE["density_kg_m2"] if density is None else density),
            "friction": PHYRE_PROFILE["friction"], "restitution": PHYRE_PROFILE["restitution"]}
    out["category"] = category_of(out)
    return out


def ball(bid: str, color: str, r: float, x: float, y: float, dynamic: bool = True,
         velocity: Sequence[float] | None = None, density: float | None = None) -> dict:
    """A PHYRE ball: circle of radius r px centred at (x, y)."""
    return body(bid, color, {"type": "circle", "radius_px": float(r)}, x, y, 0.0, dynamic,
                velocity, density)


def box(bid: str, color: str, length: float, thickness: float, x: float, y: float,
        angle: float = 0.0, dynamic: bool = True, density: float | None = None) -> dict:
    """A box centred at (x, y), `length` along its local x axis."""
    shape = {"type": "box", "length_px": float(length), "thickness_px": float(thickness)}
    return body(bid, color, shape, x, y, angle, dynamic, density=density)


def bar(bid: str, color: str, length: float, x: float, y: float, angle: float = 0.0,
        dynamic: bool = False, thickness: float = BAR, density: float | None = None) -> dict:
    """A PHYRE bar (a "line"): a box `thickness` px thick, static unless told otherwise."""
    return box(bid, color, length, thickness, x, y, angle, dynamic, density)


def jar(bid: str, color: str, width: float, height: float, x: float, y: float,
        angle: float = 0.0, dynamic: bool = True, wall: float = BAR,
        density: float | None = None) -> dict:
    """A U-shaped jar; its origin is the centre of the base, the walls stand on the base."""
    hw, ht = width / 2.0, wall / 2.0
    parts = [[[-hw, -ht], [hw, -ht], [hw, ht], [-hw, ht]],
             [[-hw, ht], [-hw + wall, ht], [-hw + wall, height], [-hw, height]],
             [[hw - wall, ht], [hw, ht], [hw, height], [hw - wall, height]]]
    return body(bid, color, {"type": "compound", "parts_px": parts}, x, y, angle, dynamic,
                density=density)


def _clip_half_plane(poly: np.ndarray, normal: np.ndarray, offset: float) -> np.ndarray:
    """Sutherland-Hodgman: the part of a convex polygon where normal . p >= offset."""
    out = []
    n = len(poly)
    for k in range(n):
        p, q = poly[k], poly[(k + 1) % n]
        dp, dq = float(normal @ p) - offset, float(normal @ q) - offset
        if dp >= 0:
            out.append(p)
        if (dp >= 0) != (dq >= 0):
            out.append(p + (q - p) * (dp / (dp - dq)))
    return np.array(out, dtype=np.float64).reshape(-1, 2)


def _clean(poly: np.ndarray) -> list[list[float]]:
    """Drop repeated vertices (clipping through a corner) and return plain lists."""
    keep = [p for k, p in enumerate(poly) if np.hypot(*(p - poly[k - 1])) > 1e-7]
    return [[float(x), float(y)] for x, y in keep]


def sticks_parts(length: float, spread: float, thickness: float = BAR) -> list[list[list[float]]]:
    """Five disjoint convex parts forming an X of two bars crossing at their centres.

    The bars point at pi/2 +- spread/2 from the local x axis (an X standing on two legs).
    """
    half_l, half_t = length / 2.0, thickness / 2.0
    rects, normals = [], []
    for ang in (math.pi / 2 - spread / 2, math.pi / 2 + spread / 2):
        rect = np.array([[-half_l, -half_t], [half_l, -half_t], [half_l, half_t],
                         [-half_l, half_t]])
        rects.append(transform_points(rect, (0.0, 0.0, ang)))
        normals.append(np.array([-math.sin(ang), math.cos(ang)]))
    (rect_a, rect_b), (n_a, n_b) = rects, normals
    centre = _clip_half_plane(_clip_half_plane(rect_a, n_b, -half_t), -n_b, -half_t)
    parts = [centre,
             _clip_half_plane(rect_a, n_b, half_t), _clip_half_plane(rect_a, -n_b, half_t),
             _clip_half_plane(rect_b, n_a, half_t), _clip_half_plane(rect_b, -n_a, half_t)]
    return [_clean(p) for p in parts]


def sticks(bid: str, color: str, length: float, spread: float, x: float, y: float,
           angle: float = 0.0, dynamic: bool = True, thickness: float = BAR,
           density: float | None = None) -> dict:
    """PHYRE "standing sticks": an X of two thin bars (a composite_shape) centred at (x, y)."""
    shape = {"type": "compound", "parts_px": sticks_parts(length, spread, thickness)}
    return body(bid, color, shape, x, y, angle, dynamic, density=density)


def polygon(bid: str, color: str, vertices: Iterable[Sequence[float]], x: float, y: float,
            angle: float = 0.0, dynamic: bool = True, density: float | None = None) -> dict:
    """A convex polygon (CCW vertices, any origin); recentred so the pose is its area centroid."""
    pts = np.asarray(list(vertices), dtype=np.float64)
    xs, ys = pts[:, 0], pts[:, 1]
    cross = xs * np.roll(ys, -1) - np.roll(xs, -1) * ys
    area = cross.sum() / 2.0
    cx = ((xs + np.roll(xs, -1)) * cross).sum() / (6 * area)
    cy = ((ys + np.roll(ys, -1)) * cross).sum() / (6 * area)
    local = [[float(px - cx), float(py - cy)] for px, py in pts]
    return body(bid, color, {"type": "polygon", "vertices_px": local}, x, y, angle, dynamic,
                density=density)


def triangle(bid: str, color: str, base: float, height: float, x: float, y: float,
             apex: float = 0.5, angle: float = 0.0, dynamic: bool = True,
             density: float | None = None) -> dict:
    """A triangle on a horizontal base; the apex sits at `apex` (0..1) of the base's length."""
    verts = [[0.0, 0.0], [base, 0.0], [apex * base, height]]
    return polygon(bid, color, verts, x, y, angle, dynamic, density)


def regular_polygon(bid: str, color: str, n: int, r: float, x: float, y: float,
                    angle: float = 0.0, dynamic: bool = True) -> dict:
    """A regular n-gon of circumradius r (n >= 5 gives a composite_shape, n = 3 a triangle)."""
    verts = [[r * math.cos(2 * math.pi * k / n), r * math.sin(2 * math.pi * k / n)]
             for k in range(n)]
    return polygon(bid, color, verts, x, y, angle, dynamic)


# ---------------------------------------------------------------------------------- geometry
def world_polygons(b: dict, pose: Sequence[float] | None = None) -> list[np.ndarray]:
    """Convex parts of a non-circular body in world px at `pose` (default: its spec pose)."""
    p = b["pose"] if pose is None else {"x_px": pose[0], "y_px": pose[1], "angle_rad": pose[2]}
    return [transform_points(part, (p["x_px"], p["y_px"], p["angle_rad"]))
            for part in local_polygons(b["shape"])]


def extent(b: dict) -> tuple[float, float, float, float]:
    """Exact world bounding box (xmin, xmax, ymin, ymax) of a body at its spec pose."""
    if b["shape"]["type"] == "circle":
        r, x, y = b["shape"]["radius_px"], b["pose"]["x_px"], b["pose"]["y_px"]
        return x - r, x + r, y - r, y + r
    pts = np.concatenate(world_polygons(b))
    return (float(pts[:, 0].min()), float(pts[:, 0].max()), float(pts[:, 1].min()),
            float(pts[:, 1].max()))


def moved(b: dict, dx: float = 0.0, dy: float = 0.0) -> dict:
    """The body translated by (dx, dy) (in place) - returned for chaining."""
    b["pose"]["x_px"] = float(b["pose"]["x_px"] + dx)
    b["pose"]["y_px"] = float(b["pose"]["y_px"] + dy)
    return b


def rest_on_floor(b: dict, floor_y: float = 0.0, gap: float = GAP) -> dict:
    """Shift a body vertically so its lowest point is `gap` px above `floor_y`."""
    return moved(b, dy=floor_y + gap - extent(b)[2])


def on_bar(bar_body: dict, along: float, above: float) -> tuple[float, float]:
    """World point `along` px from a bar's centre along its axis, `above` px over its top face."""
    a = bar_body["pose"]["angle_rad"]
    off = bar_body["shape"]["thickness_px"] / 2.0 + above
    return (bar_body["pose"]["x_px"] + along * math.cos(a) - off * math.sin(a),
            bar_body["pose"]["y_px"] + along * math.sin(a) + off * math.cos(a))


def top_of(b: dict) -> float:
    """Highest world y of a body."""
    return extent(b)[3]


def uniquify_ids(bodies: list[dict]) -> list[dict]:
    """Rename repeated ids in order: gray_ball, gray_ball_2, gray_ball_3 (in place)."""
    seen: dict[str, int] = {}
    for b in bodies:
        base = b["id"]
        seen[base] = seen.get(base, 0) + 1
        if seen[base] > 1:
            b["id"] = f"{base}_{seen[base]}"
    return bodies


# -------------------------------------------------------------------- layout sampling
class LayoutFull(Exception):
    """A drawn group does not fit into the layout; draw again."""


def inflate_shape(shape: dict, m: float) -> dict:
    """The shape grown by m px (mitred offset of every convex part)."""
    kind = shape["type"]
    if kind == "circle":
        return {"type": "circle", "radius_px": shape["radius_px"] + m}
    if kind == "box":
        return {"type": "box", "length_px": shape["length_px"] + 2 * m,
                "thickness_px": shape["thickness_px"] + 2 * m}
    parts = [shape["vertices_px"]] if kind == "polygon" else shape["parts_px"]
    grown = []
    for part in parts:
        p = np.asarray(part, dtype=np.float64)
        e = np.roll(p, -1, axis=0) - p
        n = np.stack([e[:, 1], -e[:, 0]], axis=1) / np.hypot(e[:, 0], e[:, 1])[:, None]
        prev = np.roll(n, 1, axis=0)
        grown.append((p + m * (prev + n) / (1.0 + (prev * n).sum(axis=1))[:, None]).tolist())
    return {"type": "compound", "parts_px": grown}


class Layout:
    """Occupancy grid of the bodies placed so far, each grown by `MARGIN` px.

    Groups (a support and what rests on it) are placed whole: a group fits when each of its
    bodies is on screen and misses every earlier body by `MARGIN` px. A non-strict layout
    accepts every group (the last attempt of a template keeps its draw).
    """

    def __init__(self, strict: bool = True) -> None:
        self.occ = np.zeros((H, W), dtype=bool)
        self.halo = np.zeros((H, W), dtype=bool)  # extra keep-out for `clear_halo` groups
        self.strict = strict

    def _free(self, b: dict) -> bool:
        return self._misses(b, self.occ)

    def _misses(self, b: dict, grid: np.ndarray) -> bool:
        """The body lies on screen and none of its pixels is set in `grid`."""
        xmin, xmax, ymin, ymax = extent(b)
        if xmin < 2 or xmax > W - 2 or ymin < 0.25 or ymax > H - 2:
            return False
        p = b["pose"]
        r, c, m = window_mask(b, (p["x_px"], p["y_px"], p["angle_rad"]), W, H)
        return not np.any(grid[r:r + m.shape[0], c:c + m.shape[1]] & m)

    def add(self, group: list[dict], clear_halo: bool = False) -> list[dict]:
        """Occupy the group's space, or raise LayoutFull when it collides (strict mode).

        With `clear_halo` the group must also miss the halos (see `add_halo`)."""
        if self.strict and not all(self._free(b) and (not clear_halo or self._misses(b, self.halo))
                                   for b in group):
            raise LayoutFull
        for b in group:
            p = b["pose"]
            win = window_mask({"shape": inflate_shape(b["shape"], MARGIN)},
                              (p["x_px"], p["y_px"], p["angle_rad"]), W, H)
            if win is not None:
                r, c, m = win
                self.occ[r:r + m.shape[0], c:c + m.shape[1]] |= m
        return group

    def place(self, rng: np.random.Generator, build: Callable[[np.random.Generator], list[dict]],
              tries: int = 30) -> list[dict]:
        """Draw a group until it fits (raises LayoutFull after `tries` draws)."""
        for _ in range(tries):
            try:
                return self.add(build(rng))
            except LayoutFull:
                continue
        raise LayoutFull

    def try_place(self, rng: np.random.Generator,
                  build: Callable[[np.random.Generator], list[dict]],
                  tries: int = 12, clear_halo: bool = False) -> list[dict]:
        """Like `place`, but an optional group that does not fit is left out ([])."""
        for _ in range(tries):
            try:
                return self.add(build(rng), clear_halo)
            except LayoutFull:
                continue
        return []

    def add_halo(self, bodies: Iterable[dict], d: float) -> None:
        """Mark the bodies grown by d px as a halo that `clear_halo` groups keep out of."""
        for b in bodies:
            p = b["pose"]
            win = window_mask({"shape": inflate_shape(b["shape"], d)},
                              (p["x_px"], p["y_px"], p["angle_rad"]), W, H)
            if win is not None:
                r, c, m = win
                self.halo[r:r + m.shape[0], c:c + m.shape[1]] |= m

    def reserve(self, centres: Iterable[Sequence[float]], r: float) -> None:
        """Keep discs of radius r around `centres` free (a flight path later groups avoid)."""
        disc = {"shape": {"type": "circle", "radius_px": float(r) + MARGIN}}
        for x, y in centres:
            win = window_mask(disc, (float(x), float(y), 0.0), W, H)
            if win is not None:
                row, col, m = win
                self.occ[row:row + m.shape[0], col:col + m.shape[1]] |= m


def uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    """One float drawn uniformly from [lo, hi)."""
    return float(rng.uniform(lo, hi))


def dynamic_color(rng: np.random.Generator) -> str:
    """A PHYRE colour for a dynamic body (gray, green or blue)."""
    return str(rng.choice(DYNAMIC_COLORS))


def static_color(rng: np.random.Generator) -> str:
    """A PHYRE colour for a static body: black (70%) or purple."""
    return "black" if rng.random() < 0.7 else "purple"


def mirror(bodies: list[dict]) -> list[dict]:
    """Reflect bodies about the canvas' vertical midline (in place; polygons stay CCW)."""
    for b in bodies:
        p, s = b["pose"], b["shape"]
        p["x_px"], p["angle_rad"] = W - p["x_px"], -p["angle_rad"]
        if "velocity" in b:
            v = b["velocity"]
            v["vx_px_s"], v["omega_rad_s"] = -v["vx_px_s"], -v["omega_rad_s"]
        if s["type"] == "polygon":
            s["vertices_px"] = [[-x, y] for x, y in reversed(s["vertices_px"])]
        elif s["type"] == "compound":
            s["parts_px"] = [[[-x, y] for x, y in reversed(part)] for part in s["parts_px"]]
    return bodies


def centre_x(rng: np.random.Generator, half_width: float, lo: float = 0.0, hi: float = W) -> float:
    """A centre x keeping a group of half-width `half_width` inside [lo, hi] and the canvas."""
    a, b = max(lo + half_width, half_width + 4.0), min(hi - half_width, W - half_width - 4.0)
    return uniform(rng, a, b) if a < b else (a + b) / 2.0


# --------------------------------------------------------------------------- group builders
# Each builder draws one group of bodies (sizes, pose, colours) from rng; floor groups rest on
# the floor, air groups float in a band above it. `xr` restricts where the group's centre goes.
XR = tuple[float, float]
ALL: XR = (0.0, float(W))


def g_tbar(rng, xr: XR = ALL, yr: tuple[float, float] = (140, 370)) -> list[dict]:
    length, a = uniform(rng, 120, 230), uniform(rng, 0.15, 0.55) * rng.choice([-1.0, 1.0])
    c = static_color(rng)
    x = centre_x(rng, length / 2 * math.cos(a) + BAR, *xr)
    return [bar(f"{c}_bar", c, length, x, uniform(rng, *yr), a)]


def draw_shelf(rng, length: float, xr: XR, yr: tuple[float, float], tilt: float) -> dict:
    """A static bar of `length` px, tilted by at most `tilt` rad (something rests on it)."""
    c = static_color(rng)
    x = centre_x(rng, length / 2 + BAR, *xr)
    return bar(f"{c}_bar", c, length, x, uniform(rng, *yr), uniform(rng, -tilt, tilt))


def g_hbar_ball(rng, xr: XR = ALL, yr: tuple[float, float] = (150, 330)) -> list[dict]:
    shelf = draw_shelf(rng, uniform(rng, 110, 190), xr, yr, 0.06)
    r, c = uniform(rng, 10, 20), dynamic_color(rng)
    half = shelf["shape"]["length_px"] / 2 - r - 5
    return [shelf, ball(f"{c}_ball", c, r, *on_bar(shelf, uniform(rng, -half, half), r + GAP))]


def g_hbar_box(rng, xr: XR = ALL, yr: tuple[float, float] = (150, 330)) -> list[dict]:
    shelf = draw_shelf(rng, uniform(rng, 110, 190), xr, yr, 0.06)
    w, h, c = uniform(rng, 25, 50), uniform(rng, 25, 50), dynamic_color(rng)
    half = shelf["shape"]["length_px"] / 2 - w / 2 - 5
    x, y = on_bar(shelf, uniform(rng, -half, half), h / 2 + GAP)
    return [shelf, box(f"{c}_box", c, w, h, x, y, shelf["pose"]["angle_rad"])]


def g_pblock(rng, xr: XR = ALL, yr: tuple[float, float] = (150, 350)) -> list[dict]:
    w = uniform(rng, 40, 110)
    h = uniform(rng, max(20.0, w / 3.5), 60)
    x = centre_x(rng, w / 2, *xr)
    return [box("purple_box", "purple", w, h, x, uniform(rng, *yr), dynamic=False)]


def g_cup(rng, xr: XR = ALL, yr: tuple[float, float] = (120, 300)) -> list[dict]:
    w, h, c = uniform(rng, 70, 110), uniform(rng, 40, 70), static_color(rng)
    return [jar(f"{c}_jar", c, w, h, centre_x(rng, w / 2, *xr), uniform(rng, *yr), dynamic=False)]


def g_jar(rng, xr: XR = ALL, min_width: float = 0.0) -> list[dict]:
    lo = max(70.0, min_width)
    w, h, c = uniform(rng, lo, lo + 50), uniform(rng, 45, 85), dynamic_color(rng)
    return [rest_on_floor(jar(f"{c}_jar", c, w, h, centre_x(rng, w / 2, *xr), 0.0))]


def g_jar_ball(rng, xr: XR = ALL) -> list[dict]:
    jar = g_jar(rng, xr)[0]
    inner = -jar["shape"]["parts_px"][0][0][0] - BAR  # half the inner width
    r, c = uniform(rng, 10, min(20.0, inner - 4)), dynamic_color(rng)
    x = jar["pose"]["x_px"] + uniform(rng, -(inner - r - 3), inner - r - 3)
    return [jar, ball(f"{c}_ball", c, r, x, jar["pose"]["y_px"] + BAR / 2 + GAP + r)]


def g_box(rng, xr: XR = ALL) -> list[dict]:
    w, c = uniform(rng, 25, 60), dynamic_color(rng)
    h = uniform(rng, max(25.0, w / 3), min(60.0, 3 * w))
    return [box(f"{c}_box", c, w, h, centre_x(rng, w / 2, *xr), h / 2 + GAP)]


def g_stack(rng, xr: XR = ALL) -> list[dict]:
    w, h, r = uniform(rng, 40, 70), uniform(rng, 25, 50), uniform(rng, 10, 20)
    cb, cs = dynamic_color(rng), dynamic_color(rng)
    x = centre_x(rng, w / 2, *xr)
    return [box(f"{cb}_box", cb, w, h, x, h / 2 + GAP),
            ball(f"{cs}_ball", cs, r, x + uniform(rng, -w / 5, w / 5), h + 2 * GAP + r)]


def g_tower(rng, xr: XR = ALL) -> list[dict]:
    w1, h1 = uniform(rng, 40, 65), uniform(rng, 25, 45)
    w2, h2 = uniform(rng, 25, w1), uniform(rng, 20, 45)
    c1, c2 = dynamic_color(rng), dynamic_color(rng)
    x = centre_x(rng, w1 / 2, *xr)
    return [box(f"{c1}_box", c1, w1, h1, x, h1 / 2 + GAP),
            box(f"{c2}_box", c2, w2, h2, x + uniform(rng, -(w1 - w2) / 2, (w1 - w2) / 2),
                h1 + 2 * GAP + h2 / 2)]


def g_ball(rng, xr: XR = ALL) -> list[dict]:
    r, c = uniform(rng, 12, 28), dynamic_color(rng)
    return [ball(f"{c}_ball", c, r, centre_x(rng, r, *xr), r + GAP)]


def g_sticks(rng, xr: XR = ALL) -> list[dict]:
    length, spread, c = uniform(rng, 70, 130), uniform(rng, 0.5, 1.1), dynamic_color(rng)
    half = length / 2 * math.sin(spread / 2) + BAR
    return [rest_on_floor(sticks(f"{c}_sticks", c, length, spread, centre_x(rng, half, *xr), 0))]


def g_tri(rng, xr: XR = ALL) -> list[dict]:
    base, c = uniform(rng, 40, 80), dynamic_color(rng)
    height, x = uniform(rng, 30, 60), centre_x(rng, base / 2 + 20, *xr)
    tri = triangle(f"{c}_triangle", c, base, height, x, 0, apex=uniform(rng, 0.2, 0.8))
    return [rest_on_floor(tri)]


def g_wedge(rng, xr: XR = ALL) -> list[dict]:
    base, c = uniform(rng, 100, 170), static_color(rng)
    height, x = uniform(rng, 40, 90), centre_x(rng, base / 2 + 40, *xr)
    tri = triangle(f"{c}_triangle", c, base, height, x, 0, apex=float(rng.choice([0.0, 1.0])),
                   dynamic=False)
    return [rest_on_floor(tri)]


def g_bridge(rng, xr: XR = ALL) -> list[dict]:
    bw, bh, span = uniform(rng, 18, 28), uniform(rng, 35, 65), uniform(rng, 60, 120)
    length = span + bw + uniform(rng, 20, 60)
    cb, cp = dynamic_color(rng), dynamic_color(rng)
    x = centre_x(rng, length / 2, *xr)
    return [box(f"{cb}_box", cb, bw, bh, x - span / 2, bh / 2 + GAP),
            box(f"{cb}_box", cb, bw, bh, x + span / 2, bh / 2 + GAP),
            bar(f"{cp}_bar", cp, length, x, bh + 2 * GAP + BAR / 2, dynamic=True)]


def g_seesaw(rng, xr: XR = ALL) -> list[dict]:
    length, c = uniform(rng, 150, 230), dynamic_color(rng)
    x = centre_x(rng, length / 2, *xr)
    pivot = rest_on_floor(triangle("black_triangle", "black", uniform(rng, 40, 60),
                                   uniform(rng, 30, 50), x, 0, dynamic=False))
    plank = bar(f"{c}_bar", c, length, x + uniform(rng, -8, 8), top_of(pivot) + GAP + BAR / 2,
                dynamic=True)
    return [pivot, plank]


def g_plank(rng, xr: XR = ALL) -> list[dict]:
    length, c = uniform(rng, 60, 140), dynamic_color(rng)
    x = centre_x(rng, length / 2, *xr)
    return [bar(f"{c}_bar", c, length, x, BAR / 2 + GAP, dynamic=True)]


def g_dominoes(rng, xr: XR = ALL) -> list[dict]:
    w, h, c = uniform(rng, 15, 20), uniform(rng, 40, 58), dynamic_color(rng)
    d = uniform(rng, max(28.0, w + 10), 45)
    x = centre_x(rng, d + w / 2, *xr)
    return [box(f"{c}_box", c, w, h, x + k * d, h / 2 + GAP) for k in (-1, 0, 1)]


def g_pblock_floor(rng, xr: XR = ALL) -> list[dict]:
    w, h = uniform(rng, 40, 90), uniform(rng, 30, 80)
    x = centre_x(rng, w / 2, *xr)
    return [box("purple_box", "purple", w, h, x, h / 2 + GAP, dynamic=False)]


# Scenery (`templates_2d.decorate` adds it around a template's story): small static balls and
# bars in the air, balls and boxes resting on the floor, static purple blocks. Resting or static,
# so it moves only when the story's bodies run into it. `area` (px^2) sets an object's size
# (clipped to a PHYRE-like range: the smallest size once the scene is full); without it the
# size is drawn.
def _ball_radius(rng, area: float | None) -> float:
    if area is None:
        return uniform(rng, 8, 18)
    return float(np.clip(math.sqrt(max(area, 0.0) / math.pi) * uniform(rng, 0.85, 1.15), 8, 30))


def _box_sides(rng, area: float | None, lo: float, hi: float) -> tuple[float, float]:
    side = uniform(rng, lo, hi) if area is None else float(
        np.clip(math.sqrt(max(area, 0.0)), lo, hi))
    aspect = uniform(rng, 0.6, 1.6)
    return (float(np.clip(side * math.sqrt(aspect), lo, hi)),
            float(np.clip(side / math.sqrt(aspect), lo, hi)))


def g_static_ball(rng, xr: XR = ALL, yr: tuple[float, float] = (90, 440),
                  area: float | None = None) -> list[dict]:
    r, c = _ball_radius(rng, area), static_color(rng)
    return [ball(f"{c}_ball", c, r, centre_x(rng, r, *xr), uniform(rng, *yr), dynamic=False)]


def g_floor_ball(rng, xr: XR = ALL, area: float | None = None) -> list[dict]:
    r, c = _ball_radius(rng, area), dynamic_color(rng)
    return [ball(f"{c}_ball", c, r, centre_x(rng, r, *xr), r + GAP)]


def g_short_bar(rng, xr: XR = ALL, yr: tuple[float, float] = (90, 440),
                area: float | None = None) -> list[dict]:
    length = uniform(rng, 60, 130) if area is None else float(
        np.clip(max(area, 0.0) / BAR * uniform(rng, 0.85, 1.15), 50, 180))
    a, c = uniform(rng, -0.6, 0.6), static_color(rng)
    x = centre_x(rng, length / 2 * abs(math.cos(a)) + BAR, *xr)
    return [bar(f"{c}_bar", c, length, x, uniform(rng, *yr), a)]


def g_small_box(rng, xr: XR = ALL, area: float | None = None) -> list[dict]:
    (w, h), c = _box_sides(rng, area, 18, 48), dynamic_color(rng)
    return [box(f"{c}_box", c, w, h, centre_x(rng, w / 2, *xr), h / 2 + GAP)]


def g_small_block(rng, xr: XR = ALL, yr: tuple[float, float] = (90, 440),
                  area: float | None = None) -> list[dict]:
    w, h = _box_sides(rng, area, 18, 48)
    return [box("purple_box", "purple", w, h, centre_x(rng, w / 2, *xr), uniform(rng, *yr),
                dynamic=False)]


GROUPS: dict[str, Callable[..., list[dict]]] = {
    "tbar": g_tbar, "hbar_ball": g_hbar_ball, "hbar_box": g_hbar_box, "pblock": g_pblock,
    "cup": g_cup, "jar": g_jar, "jar_ball": g_jar_ball, "box": g_box, "stack": g_stack,
    "tower": g_tower, "ball": g_ball, "sticks": g_sticks, "tri": g_tri, "wedge": g_wedge,
    "bridge": g_bridge, "seesaw": g_seesaw, "plank": g_plank, "dominoes": g_dominoes,
    "pblock_floor": g_pblock_floor, "static_ball": g_static_ball, "floor_ball": g_floor_ball,
    "short_bar": g_short_bar, "small_box": g_small_box, "small_block": g_small_block,
}


# ------------------------------------------------------------------------------- the wrapper
def contact_pair(a: str | dict, b: str | dict, friction: float | None = None,
                 restitution: float | None = None) -> dict:
    """An explicit contact material for a body pair (ids or bodies); PHYRE values by default."""
    ida = a if isinstance(a, str) else a["id"]
    idb = b if isinstance(b, str) else b["id"]
    return {"a": ida, "b": idb,
            "friction": float(PHYRE_PROFILE["friction"] if friction is None else friction),
            "restitution": float(PHYRE_PROFILE["restitution"] if restitution is None
                                 else restitution)}


def scene2d(template_id: int, variant: int, family: str, description: str, bodies: list[dict],
            gravity: float | Sequence[float] | None = None,
            contacts: Iterable[dict | Sequence[Any]] | None = None) -> dict:
    """Wrap bodies into an un-simulated `visphy-scene/1` 2D spec with PHYRE's world constants.

    `gravity` is a magnitude in m/s^2 (pointing down) or an (x, y) vector; any value other than
    PHYRE's 9.8 down switches `world.profile` to "phyre-gravity" (the PHYRE profile pins g).
    `contacts` are explicit pair materials: dicts as made by `contact_pair` or tuples
    (a, b, friction, restitution). `seed` is 0: the caller fills it in.
    """
    p = PHYRE_PROFILE
    g = list(p["gravity_m_s2"])
    if gravity is not None:
        g = [0.0, -float(gravity)] if np.isscalar(gravity) else [float(v) for v in gravity]
    profile = "phyre" if np.allclose(g, p["gravity_m_s2"], rtol=0, atol=1e-12) else GRAVITY_PROFILE
    pairs = [dict(c) if isinstance(c, dict) else contact_pair(*c) for c in (contacts or [])]
    return {
        "schema": SPEC_SCHEMA, "scene_id": f"task{template_id:05d}_{variant:03d}",
        "template_id": f"{template_id:05d}", "variant": int(variant), "seed": 0,
        "dim": "2d", "family": family, "description": description,
        "difficulty": {"label": "easy", "score": 0.0, "features": {}},
        "world": {
            "engine": "box2d", "engine_version": "2.3.10", "profile": profile,
            "units": {"px_per_m": p["px_per_m"], "canvas_px": list(p["canvas_px"]),
                      "origin": "bottom-left", "y_up": True, "angles": "rad_ccw"},
            "gravity_m_s2": g, "dt_s": p["dt_s"],
            "solver": {"velocity_iterations": p["velocity_iterations"],
                       "position_iterations": p["position_iterations"]},
            "steps_per_frame": p["steps_per_frame"],
            "first_frame_after_steps": p["first_frame_after_steps"],
            "n_frames": 17, "video_fps": 5,
            "walls": {"thickness_px": 5.0, "sides": ["bottom", "left", "right", "top"]},
            "damping": {"linear": 0.0, "angular": 0.01}, "allow_sleep": True,
        },
        "render": {"background_rgb": list(PALETTE["white"]), "antialias": False,
                   "codec": "h264", "pix_fmt": "yuv420p"},
        "bodies": bodies,
        "contacts": {"default": {"friction": p["friction"], "restitution": p["restitution"]},
                     "pairs": pairs},
        "ground_truth": {"trajectory": None, "events": [],
                         "identifiable": {"gravity": False, "initial_velocity": [],
                                          "restitution": [], "friction": [], "mass_ratio": []}},
        "digest_sha256": None,
    }
