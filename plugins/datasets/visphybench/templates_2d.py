"""visphy's 96 PHYRE-style 2D templates (179 variants): combinatorial and law-probing families.

Why two families: VisPhyBench's 2D scenes are PhyWorld's *combinatorial* scenes - a red action
ball dropped or launched into a random combination of PHYRE building blocks (bars, jars, boxes,
standing sticks, balls, triangles) - and those never vary the world's constants. visphy adds
*law* templates that vary exactly one law PHYRE keeps fixed (gravity, restitution, friction,
initial velocity, mass ratio), so parameter recovery (docs/metrics.md) has signal.

Contract: `make(rng, variant)` returns an un-simulated 2D spec (seed 0; the builder fills it) and
draws everything from `rng`. Layouts are rejection-sampled on an occupancy grid
(`blocks2d.Layout`: bodies at least 3 px apart, fully on screen), so a candidate fails the
validity filter only through its dynamics; the last of `LAYOUT_TRIES` attempts keeps its draw
and leaves the verdict to the builder's filter.
Which categories a template contains never depends on `rng` (only positions, sizes, angles,
colours and law values do), so the category shares of the benchmark are fixed by the template mix
(see `category_shares`); `variant` picks the action's target (combinatorial) or the half of the
law's range (law templates, so the two variants of a law template differ in their law).
Sizes follow the published clips: the red ball is 17-56 px in radius (median about 39), and
`decorate` adds scenery around each story (balls, bars and blocks that are static or rest on the
floor, sized to fill 3.4-5 % of the frame, clear of the red ball's free flight and of the room it
needs to roll off the story's supports), so a scene holds about 7.7 objects in the paper's mix.
"""
# size: the 2D template catalogue, one entry per template family

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from visphy_core.api.spec import CATEGORIES, category_of, shape_area_centroid
from visphy_plugins.datasets.visphybench import blocks2d as bk
from visphy_plugins.datasets.visphybench.blocks2d import (
    ALL,
    BAR,
    GAP,
    GROUPS,
    XR,
    Layout,
    LayoutFull,
    centre_x,
    draw_shelf,
    dynamic_color,
    g_ball,
    g_box,
    g_dominoes,
    g_hbar_box,
    g_jar,
    g_pblock,
    g_seesaw,
    g_sticks,
    g_tbar,
    mirror,
    uniform,
)

W, H = bk.CANVAS
LAYOUT_TRIES = 40
#: Category shares of VisPhyBench (docs/benchmark.md), the target of the template mix.
#: Shares over the 2D scenes alone. They equal the paper's benchmark-wide shares except for
#: triangles, which the 3D subset's ramps mostly provide (11 of the 30 3D scenes have a wedge):
#: 2D keeps 4 of 179 so the whole benchmark lands at 15 / 209 = 7.2% (paper 6.3%).
TARGET_SHARES = {"circle": 1.0, "line": 0.832, "rectangle": 0.628, "u_shape": 0.246,
                 "triangle": 0.022, "composite_shape": 0.073}


@dataclass(frozen=True)
class Template:
    """One scene template; `make(rng, variant)` draws an un-simulated spec of that variant."""

    template_id: int
    family: str  # "combinatorial" or "law"
    n_variants: int
    description: str
    make: Callable[[np.random.Generator, int], dict]
    law: str = ""  # the law a "law" template varies: gravity|restitution|friction|...


Builder = Callable[[np.random.Generator, "Layout", int], dict]


def _sampled(build: Builder) -> Callable[[np.random.Generator, int], dict]:
    """make(rng, variant): run a layout builder until it fits; the last attempt keeps its draw."""
    def make(rng: np.random.Generator, variant: int) -> dict:
        for k in range(LAYOUT_TRIES):
            try:
                return build(rng, Layout(strict=k < LAYOUT_TRIES - 1), variant)
            except LayoutFull:
                continue
        raise AssertionError("unreachable: the last attempt is not strict")
    return make


PHRASES = {
    "tbar": "a tilted static bar", "hbar_ball": "a ball on a static shelf",
    "hbar_box": "a box on a static shelf", "pblock": "a static purple block",
    "cup": "a static jar in the air", "jar": "a jar", "jar_ball": "a jar holding a ball",
    "box": "a box", "stack": "a box with a ball on top", "tower": "a tower of two boxes",
    "ball": "a ball", "sticks": "standing sticks", "tri": "a loose triangle",
    "wedge": "a static triangular ramp", "bridge": "a plank bridging two boxes",
    "seesaw": "a seesaw (plank on a static triangle)", "plank": "a plank lying on the floor",
    "dominoes": "three standing dominoes", "pblock_floor": "a static purple block on the floor",
}


# ------------------------------------------------------------------------------ action ball
#: Red-ball radius (px) of the published 2D clips: min 17, median 39, max 56.
RED_RADIUS = (17.0, 56.0)


def red_radius(rng) -> float:
    """A red-ball radius in 17-56 px, skewed so the median is about 39 px (published clips)."""
    lo, hi = RED_RADIUS
    return lo + (hi - lo) * float(rng.random()) ** 0.9


def red_drop(rng, target: list[dict], y_min: float = 330.0, r: float | None = None) -> dict:
    """The red action ball at rest somewhere above a target group (it will fall onto it)."""
    r = red_radius(rng) if r is None else r
    ext = np.array([bk.extent(b) for b in target])
    xmin, xmax, ymax = ext[:, 0].min(), ext[:, 1].max(), ext[:, 3].max()
    inset = 0.15 * (xmax - xmin)
    x = float(np.clip(uniform(rng, xmin + inset, xmax - inset + 1e-9), r + 3, W - r - 3))
    lo, hi = max(ymax + r + 15, y_min), H - r - 4
    return bk.ball("red_ball", "red", r, x, uniform(rng, lo, hi) if lo < hi else hi)


def _aim(dx: float, dy: float, g: float, speed: float | None, deg: tuple[float, float],
         rng) -> tuple[float, float] | None:
    """(speed px/s, angle rad) of a throw covering (dx > 0, dy) px under gravity g px/s^2.

    Without a speed: an angle in `deg` whose required speed lies in 60-240 px/s. With a speed:
    the flatter of the two angles that reach the point (None when it cannot be reached).
    """
    if dx < 30:
        return None
    if speed is None:
        for _ in range(8):
            ang = math.radians(uniform(rng, *deg))
            den = 2 * math.cos(ang) ** 2 * (dx * math.tan(ang) - dy)
            if den > 0 and 60.0 <= math.sqrt(g * dx * dx / den) <= 240.0:
                return math.sqrt(g * dx * dx / den), ang
        return None
    disc = speed ** 4 - g * (g * dx * dx + 2 * dy * speed ** 2)
    if disc < 0:
        return None
    return speed, math.atan((speed ** 2 - math.sqrt(disc)) / (g * dx))


def red_launch(rng, target: list[dict] | None = None, speed: float | None = None,
               deg: tuple[float, float] = (10.0, 50.0), yr: tuple[float, float] = (120.0, 400.0),
               g: float = 9.8) -> dict:
    """The red action ball near a side edge, thrown towards the other side.

    With a target group it starts on the side away from the target and the throw is aimed at a
    point of the target's top (ignoring obstacles); when no aim is possible (or no target) it
    starts on the left and keeps `speed` (or 100-220 px/s) at an angle drawn from `deg`.
    """
    r = red_radius(rng)
    x0, y0, side = uniform(rng, r + 5, 90), uniform(rng, *yr), 1.0
    shot = None
    if target is not None:
        ext = np.array([bk.extent(b) for b in target])
        xt = uniform(rng, ext[:, 0].min(), ext[:, 1].max())
        if xt < W / 2:  # throw from the side away from the target
            x0, side = W - x0, -1.0
        shot = _aim(side * (xt - x0), ext[:, 3].max() + r - y0, g * PPM, speed, deg, rng)
    if shot is None:
        v = uniform(rng, 100, 220) if speed is None else speed
        shot = (v, math.radians(uniform(rng, *deg)))
    v, ang = shot
    return bk.ball("red_ball", "red", r, x0, y0,
                   velocity=(side * v * math.cos(ang), v * math.sin(ang), 0.0))


# ------------------------------------------------------------------------------- scenery
#: Scenery around every template's story, so a scene holds about 7 objects in the paper's mix
#: (1,523 objects over 209 scenes: 779 circles, 344 lines, 321 rectangles, ...): extra balls
#: (static in the air or resting on the floor), an extra static bar where the template already
#: has a line, an extra block or box where it already has a rectangle - so the categories a
#: template contains, and the benchmark's category shares, do not change.
EXTRA_BALLS = (1, 4)
P_EXTRA_BAR = 0.75
P_EXTRA_BOX = 0.8
#: Drawn share of the canvas the bodies of a scene cover (published clips: 3.3-4.4-6.6 % of a
#: frame is not background); scenery is sized to fill what the story leaves of it.
AREA_SHARE = (0.034, 0.05)
#: A sparse story gets extra balls (up to MAX_BALLS) while each would exceed BIG_BALL_AREA px^2.
MAX_BALLS, BIG_BALL_AREA = 5, math.pi * 24.0 ** 2
#: Seconds of the red ball's free flight kept clear of scenery (the clip lasts 3.4 s).
FLIGHT_S = 3.4


AIR_SCENERY = (bk.g_static_ball, bk.g_short_bar, bk.g_small_block)


def flight_path(ball: dict, g: float = 9.8, seconds: float = FLIGHT_S,
                dt: float = 1 / 30) -> list[tuple[float, float]]:
    """Centres of a ball's free flight (no obstacles) under g m/s^2, until it leaves the canvas."""
    p, v, r = ball["pose"], ball.get("velocity", {}), ball["shape"]["radius_px"]
    x0, y0 = p["x_px"], p["y_px"]
    vx, vy = v.get("vx_px_s", 0.0), v.get("vy_px_s", 0.0)
    out = []
    for k in range(int(seconds / dt) + 1):
        t = k * dt
        x, y = x0 + vx * t, y0 + vy * t - 0.5 * g * PPM * t * t
        if not (r <= x <= W - r and r <= y):
            break
        out.append((x, y))
    return out


def decorate(rng, layout: Layout, bodies: list[dict], g: float = 9.8,
             static_only: bool = False) -> list[dict]:
    """The story's bodies plus scenery placed clear of them and of the red ball's free flight.

    Scenery never moves on its own (static, or resting on the floor), so the story stays the
    red ball's; `static_only` keeps every extra body static (mass-ratio scenes compare the
    densities of all their dynamic bodies). Scenery that does not fit is left out.
    """
    cats = {category_of(b) for b in bodies}
    red = next(b for b in bodies if b["id"] == "red_ball")
    r_red = red["shape"]["radius_px"]
    layout.reserve(flight_path(red, g), r_red + 6)
    # scenery in the air leaves the red ball room to roll along and off the story's supports
    layout.add_halo([b for b in bodies if not b["dynamic"]], 2 * r_red + 4)
    area = sum(shape_area_centroid(b["shape"])[0] for b in bodies)
    target = W * H * uniform(rng, *AREA_SHARE)
    kinds = []
    if "line" in cats and rng.random() < P_EXTRA_BAR:
        kinds.append(bk.g_short_bar)
    if "rectangle" in cats and rng.random() < P_EXTRA_BOX:
        kinds.append(bk.g_small_block if static_only or rng.random() < 0.5 else bk.g_small_box)
    n_balls = int(rng.integers(EXTRA_BALLS[0], EXTRA_BALLS[1] + 1))
    while n_balls < MAX_BALLS and (target - area) / (len(kinds) + n_balls) > BIG_BALL_AREA:
        n_balls += 1  # a sparse story gets more scenery rather than giant balls
    for _ in range(n_balls):
        kinds.append(bk.g_static_ball if static_only or rng.random() < 0.6 else bk.g_floor_ball)
    extras: list[dict] = []
    for k, build in enumerate(kinds):
        share = (target - area) / (len(kinds) - k)  # what is left of the area, per object
        group = layout.try_place(rng, lambda r, b=build, a=share: b(r, area=a),
                                 clear_halo=build in AIR_SCENERY)
        area += sum(shape_area_centroid(b["shape"])[0] for b in group)
        extras += group
    return bodies + extras


def _finish(rng, bodies: list[dict]) -> list[dict]:
    """Mirror half of the layouts (the canvas is symmetric) and make ids unique."""
    if rng.random() < 0.5:
        mirror(bodies)
    return bk.uniquify_ids(bodies)


# ------------------------------------------------------------------- combinatorial family
_PLURALS = {"tbar": "tilted static bars", "jar": "jars", "ball": "balls", "pblock":
            "static purple blocks", "hbar_ball": "balls on static shelves", "hbar_box":
            "boxes on static shelves", "stack": "boxes with a ball on top", "tower":
            "towers of two boxes", "plank": "planks lying on the floor"}


def _describe(groups: tuple[str, ...], action: str) -> str:
    counts: dict[str, int] = {}
    for g in groups:
        counts[g] = counts.get(g, 0) + 1
    words = {2: "two", 3: "three"}
    items = [PHRASES[g] if n == 1 else f"{words[n]} {_PLURALS[g]}" for g, n in counts.items()]
    verb = "dropped onto" if action == "drop" else "launched sideways into"
    return f"red ball {verb} a scene with " + ", ".join(items)


def _combinatorial(tid: int, groups: tuple[str, ...], action: str) -> Builder:
    description = _describe(groups, action)

    def build(rng, layout: Layout, variant: int) -> dict:
        placed = [layout.place(rng, GROUPS[g]) for g in groups]
        target = placed[variant % len(placed)]  # the variant picks the group the ball aims at
        if action == "drop":
            red = layout.place(rng, lambda r: [red_drop(r, target)])
        else:
            red = layout.place(rng, lambda r: [red_launch(r, target)])
        bodies = _finish(rng, decorate(rng, layout, red + [b for g in placed for b in g]))
        return bk.scene2d(tid, variant, "combinatorial", description, bodies)
    return build


#: (groups, action, n_variants) of the 70 combinatorial templates, ids 10001..10070.
COMBINATIONS: tuple[tuple[tuple[str, ...], str, int], ...] = (
    # jars and static cups (u_shape)
    (("tbar", "jar"), "drop", 2), (("tbar", "tbar", "jar"), "drop", 2),
    (("hbar_ball", "jar"), "drop", 2), (("hbar_box", "jar"), "drop", 2),
    (("tbar", "jar_ball"), "drop", 2), (("pblock", "jar"), "drop", 2),
    (("cup", "tbar"), "drop", 2), (("cup", "box"), "launch", 2),
    (("jar", "box"), "launch", 2), (("jar", "ball", "ball"), "drop", 2),
    (("tbar", "jar", "box"), "drop", 2), (("bridge", "jar"), "drop", 2),
    (("tbar", "dominoes", "jar"), "drop", 2), (("sticks", "jar"), "launch", 1),
    (("tbar", "cup", "ball"), "drop", 2), (("jar", "jar", "tbar"), "drop", 2),
    (("hbar_ball", "jar", "box"), "drop", 2), (("tbar", "stack", "jar"), "drop", 1),
    # triangles: few in 2D, since the 3D ramps (wedges) already put a triangle in 11 scenes and
    # the paper counts triangles in 6.3% of all scenes
    (("tbar", "ball", "ball"), "drop", 2), (("seesaw", "ball"), "drop", 2),
    (("plank", "box"), "drop", 2), (("pblock", "box", "tbar"), "drop", 2),
    (("pblock", "ball"), "launch", 1),
    # standing sticks (composite_shape)
    (("tbar", "sticks"), "drop", 2), (("tbar", "sticks", "box"), "drop", 2),
    (("hbar_ball", "sticks"), "drop", 2), (("sticks", "stack"), "launch", 2),
    (("tbar", "tbar", "sticks"), "drop", 2),
    # bars, boxes and balls
    (("tbar", "box"), "drop", 2), (("tbar", "ball", "box"), "drop", 2),
    (("tbar", "stack"), "drop", 2), (("tbar", "tower"), "drop", 2),
    (("hbar_box", "ball"), "drop", 2), (("tbar", "tbar", "box"), "drop", 2),
    (("tbar", "tbar", "ball", "ball"), "drop", 2), (("bridge", "ball"), "drop", 2),
    (("plank", "box"), "launch", 2), (("tbar", "dominoes"), "drop", 2),
    (("dominoes",), "launch", 2), (("stack", "stack"), "launch", 2),
    (("tower", "ball"), "launch", 2), (("pblock", "ball"), "drop", 2),
    (("hbar_ball", "hbar_ball", "box"), "drop", 2), (("tbar", "plank", "ball"), "drop", 2),
    (("tbar", "hbar_box"), "drop", 2), (("tbar", "pblock", "box"), "drop", 2),
    (("hbar_box", "hbar_box"), "drop", 2), (("tbar", "bridge"), "drop", 2),
    (("tbar", "tbar", "tbar", "ball"), "drop", 2), (("tbar", "stack", "box"), "drop", 2),
    (("pblock", "tbar", "ball"), "drop", 2), (("hbar_ball", "tower"), "drop", 2),
    (("tbar", "ball"), "drop", 2), (("bridge", "box"), "launch", 2),
    (("tbar", "dominoes", "ball"), "drop", 2), (("hbar_ball", "tbar"), "drop", 2),
    (("plank", "plank", "ball"), "launch", 2), (("pblock_floor", "tbar", "box"), "drop", 2),
    (("tbar", "tbar", "stack"), "drop", 2), (("hbar_box", "stack"), "drop", 2),
    (("tbar", "ball", "ball"), "drop", 1), (("pblock", "pblock", "ball"), "drop", 1),
    (("tbar", "tbar", "ball"), "drop", 1), (("tbar", "hbar_ball", "ball"), "drop", 1),
    (("hbar_ball", "ball", "ball"), "drop", 1), (("tbar", "tbar"), "drop", 1),
    (("plank", "box", "ball"), "launch", 1), (("tbar", "plank", "tower"), "drop", 1),
    (("hbar_box", "tbar", "ball"), "drop", 1), (("pblock_floor", "ball"), "launch", 1),
)


# ----------------------------------------------------------------------------- law family
PPM = 6.0
LAW_VARIANTS = 2
GRAVITY_RANGE = (4.0, 16.0)
RESTITUTION_RANGE = (0.1, 0.9)
FRICTION_RANGE = (0.1, 0.9)
SPEED_RANGE_PX_S = (50.0, 250.0)
DENSITY_LIGHT, DENSITY_HEAVY = (0.1, 0.5), (1.0, 2.0)


def law_value(rng, variant: int, lo_hi: tuple[float, float], digits: int = 2) -> float:
    """A law value from the variant's share of the range (variant 0: low half, 1: high half)."""
    lo, hi = lo_hi
    a = lo + (hi - lo) * variant / LAW_VARIANTS
    b = lo + (hi - lo) * (variant + 1) / LAW_VARIANTS
    return round(uniform(rng, a, b), digits)


def _densities(rng, variant: int) -> tuple[float, float]:
    """(action ball, target) densities: variant 0 hits a light target, variant 1 a heavy one."""
    light = round(uniform(rng, *DENSITY_LIGHT), 2)
    heavy = round(uniform(rng, *DENSITY_HEAVY), 2)
    return (heavy, light) if variant == 0 else (light, heavy)


def _incline(rng, yr: tuple[float, float], xr: XR = ALL) -> dict:
    """A static bar rising to the right by 0.3-0.62 rad (tan 0.31-0.72: some boxes slide)."""
    length, a = uniform(rng, 200, 290), uniform(rng, 0.3, 0.62)
    return bk.bar("black_bar", "black", length, centre_x(rng, length / 2 * math.cos(a) + BAR, *xr),
                  uniform(rng, *yr), a)


def _box_on(rng, support: dict, along: float) -> dict:
    w, h, c = uniform(rng, 25, 45), uniform(rng, 20, 40), dynamic_color(rng)
    x, y = bk.on_bar(support, along, h / 2 + GAP)
    return bk.box(f"{c}_box", c, w, h, x, y, support["pose"]["angle_rad"])


def _ball_above(rng, support: dict, along: float, y_min: float = 380.0,
                r: float | None = None) -> dict:
    """Red ball at rest high above the point `along` px from a bar's centre."""
    r = red_radius(rng) if r is None else r
    x, y = bk.on_bar(support, along, r + 20)
    lo, hi = max(y, y_min), H - r - 4
    return bk.ball("red_ball", "red", r, float(np.clip(x, r + 3, W - r - 3)),
                   uniform(rng, lo, hi) if lo < hi else hi)


def _law_spec(rng, lay: Layout, tid: int, variant: int, description: str, bodies: list[dict],
              gravity: float | None = None, pairs=None, static_only: bool = False) -> dict:
    bodies = _finish(rng, decorate(rng, lay, bodies, 9.8 if gravity is None else gravity,
                                   static_only))
    contacts = [bk.contact_pair(a, b, f, e) for a, b, f, e in (pairs or [])]
    return bk.scene2d(tid, variant, "law", description, bodies, gravity=gravity,
                      contacts=contacts)


def _bar_into_jar(rng, lay: Layout, bar: dict) -> tuple[list[dict], list[dict]]:
    """A jar on the floor past the bar's lower end, and the red ball above its upper half."""
    half, up = bar["shape"]["length_px"] / 2, math.copysign(1.0, bar["pose"]["angle_rad"])
    low_x = bk.on_bar(bar, -up * half, 0)[0]
    xr = (low_x - 120, low_x + 40) if up > 0 else (low_x - 40, low_x + 120)
    rad = red_radius(rng)  # the jar is wide enough to catch the ball
    jar = lay.place(rng, lambda r: g_jar(r, xr=xr, min_width=2 * rad + 2 * BAR + 12))
    red = lay.place(rng, lambda r: [_ball_above(r, bar, up * uniform(r, 0.1, 0.8) * half,
                                                r=rad)])
    return red, jar


# Gravity: scenes with long free flight; g drawn in 4-16 m/s^2.
def law_gravity_arc(rng, lay: Layout, v: int, tid: int, desc: str) -> dict:
    g = law_value(rng, v, GRAVITY_RANGE)
    bar = lay.place(rng, lambda r: g_tbar(r, xr=(260, W), yr=(90, 240)))

    def red(r):
        rad = red_radius(r)
        y0 = uniform(r, rad + 20, 170)
        vy = uniform(r, 0.6, 0.95) * math.sqrt(2 * g * PPM * (440 - y0 - rad))
        return [bk.ball("red_ball", "red", rad, uniform(r, rad + 5, 100), y0,
                        velocity=(uniform(r, 40, 110), vy, 0.0))]
    return _law_spec(rng, lay, tid, v, desc, lay.place(rng, red) + bar, gravity=g)


def law_gravity_block(rng, lay: Layout, v: int, tid: int, desc: str) -> dict:
    g = law_value(rng, v, GRAVITY_RANGE)
    block = lay.place(rng, lambda r: g_pblock(r, yr=(140, 280)))
    floor = lay.place(rng, g_box) + lay.place(rng, g_ball)
    red = lay.place(rng, lambda r: [red_drop(r, block, y_min=400)])
    return _law_spec(rng, lay, tid, v, desc, red + block + floor, gravity=g)


def law_gravity_two_fall(rng, lay: Layout, v: int, tid: int, desc: str) -> dict:
    g = law_value(rng, v, GRAVITY_RANGE)
    bar = lay.place(rng, lambda r: g_tbar(r, yr=(90, 200)))

    def falling_box(r):
        w, h, c = uniform(r, 25, 50), uniform(r, 25, 50), dynamic_color(r)
        return [bk.box(f"{c}_box", c, w, h, centre_x(r, w / 2), uniform(r, 280, 450))]
    box_ = lay.place(rng, falling_box)
    red = lay.place(rng, lambda r: [red_drop(r, bar, y_min=380)])
    return _law_spec(rng, lay, tid, v, desc, red + bar + box_, gravity=g)


def law_gravity_bar_jar(rng, lay: Layout, v: int, tid: int, desc: str) -> dict:
    g = law_value(rng, v, GRAVITY_RANGE)
    bar = lay.place(rng, lambda r: g_tbar(r, yr=(200, 330)))[0]
    red, jar = _bar_into_jar(rng, lay, bar)
    return _law_spec(rng, lay, tid, v, desc, red + [bar] + jar, gravity=g)


def law_gravity_shelf_launch(rng, lay: Layout, v: int, tid: int, desc: str) -> dict:
    g = law_value(rng, v, GRAVITY_RANGE)
    def shelf_and_ball(r):
        shelf = draw_shelf(r, uniform(r, 120, 200), (0, 230), (220, 380), 0.0)
        rad = red_radius(r)
        along = -shelf["shape"]["length_px"] / 2 + rad + uniform(r, 5, 30)
        x, y = bk.on_bar(shelf, along, rad + GAP)
        speed = uniform(r, 40, 150)
        return [bk.ball("red_ball", "red", rad, x, y, velocity=(speed, 0.0, 0.0)), shelf]
    red, shelf = lay.place(rng, shelf_and_ball)
    right = bk.extent(shelf)[1]
    floor = lay.place(rng, lambda r: g_box(r, xr=(right, W))) + lay.place(rng, g_box)
    return _law_spec(rng, lay, tid, v, desc, [red, shelf] + floor, gravity=g)


def law_gravity_two_balls(rng, lay: Layout, v: int, tid: int, desc: str) -> dict:
    g = law_value(rng, v, GRAVITY_RANGE)
    bar = lay.place(rng, lambda r: g_tbar(r, yr=(90, 220)))

    def gray(r):
        rad, c = uniform(r, 10, 22), dynamic_color(r)
        return [bk.ball(f"{c}_ball", c, rad, centre_x(r, rad), uniform(r, 220, 360))]
    other = lay.place(rng, gray)
    red = lay.place(rng, lambda r: [red_drop(r, bar, y_min=380)])
    return _law_spec(rng, lay, tid, v, desc, red + bar + other, gravity=g)


# Restitution: bounces with an explicit pair restitution e in 0.1-0.9 (friction stays 0.5).
def _bounce(red: dict, other: dict | str, e: float) -> tuple:
    return (red, other, 0.5, e)


def law_bounce_bar(rng, lay: Layout, v: int, tid: int, desc: str) -> dict:
    e = law_value(rng, v, RESTITUTION_RANGE)
    bar = lay.place(rng, lambda r: [draw_shelf(r, uniform(r, 160, 300), ALL, (60, 180), 0.03)])
    red = lay.place(rng, lambda r: [red_drop(r, bar, y_min=420)])
    return _law_spec(rng, lay, tid, v, desc, red + bar, pairs=[_bounce(red[0], bar[0], e)])


def law_bounce_floor(rng, lay: Layout, v: int, tid: int, desc: str) -> dict:
    e = law_value(rng, v, RESTITUTION_RANGE)
    floor = lay.place(rng, g_box) + lay.place(rng, g_box)

    def red(r):
        rad = red_radius(r)
        return [bk.ball("red_ball", "red", rad, centre_x(r, rad), uniform(r, 400, H - rad - 4))]
    red_ = lay.place(rng, red)
    return _law_spec(rng, lay, tid, v, desc, red_ + floor,
                     pairs=[_bounce(red_[0], "wall_bottom", e)])


def law_bounce_block(rng, lay: Layout, v: int, tid: int, desc: str) -> dict:
    e = law_value(rng, v, RESTITUTION_RANGE)
    block = lay.place(rng, lambda r: g_pblock(r, yr=(180, 300)))
    bar = lay.place(rng, lambda r: g_tbar(r, yr=(70, 150)))
    red = lay.place(rng, lambda r: [red_drop(r, block, y_min=380)])
    return _law_spec(rng, lay, tid, v, desc, red + block + bar,
                     pairs=[_bounce(red[0], block[0], e), _bounce(red[0], bar[0], e)])


def law_bounce_bar_jar(rng, lay: Layout, v: int, tid: int, desc: str) -> dict:
    e = law_value(rng, v, RESTITUTION_RANGE)
    bar = lay.place(rng, lambda r: g_tbar(r, yr=(180, 320)))[0]
    red, jar = _bar_into_jar(rng, lay, bar)
    return _law_spec(rng, lay, tid, v, desc, red + [bar] + jar, pairs=[_bounce(red[0], bar, e)])


def law_bounce_two_balls(rng, lay: Layout, v: int, tid: int, desc: str) -> dict:
    e1, e2 = law_value(rng, v, RESTITUTION_RANGE), law_value(rng, v, RESTITUTION_RANGE)
    bar = lay.place(rng, lambda r: [draw_shelf(r, uniform(r, 300, 440), ALL, (60, 150), 0.03)])

    def gray(r):
        rad, c = uniform(r, 10, 22), dynamic_color(r)
        x = float(np.clip(bk.on_bar(bar[0], uniform(r, -140, 140), 0)[0], rad + 3, W - rad - 3))
        return [bk.ball(f"{c}_ball", c, rad, x, uniform(r, 250, 420))]
    other = lay.place(rng, gray)
    red = lay.place(rng, lambda r: [red_drop(r, bar, y_min=300)])
    return _law_spec(rng, lay, tid, v, desc, red + bar + other,
                     pairs=[_bounce(red[0], bar[0], e1), _bounce(other[0], bar[0], e2)])


# Friction: boxes on inclined static bars with an explicit pair friction mu in 0.1-0.9.
def _slide(box_: dict, bar: dict, mu: float) -> tuple:
    return (box_, bar, mu, 0.2)


def _incline_box(rng, lay: Layout, yr: tuple[float, float], xr: XR = ALL,
                 along: tuple[float, float] = (-0.1, 0.2)) -> tuple[dict, dict]:
    def build(r):
        bar = _incline(r, yr, xr)
        return [bar, _box_on(r, bar, uniform(r, *along) * bar["shape"]["length_px"])]
    bar, box_ = lay.place(rng, build)
    return bar, box_


def law_friction_ramp(rng, lay: Layout, v: int, tid: int, desc: str) -> dict:
    mu = law_value(rng, v, FRICTION_RANGE)
    bar, box_ = _incline_box(rng, lay, (150, 320))
    length = bar["shape"]["length_px"]
    red = lay.place(rng, lambda r: [_ball_above(r, bar, uniform(r, 0.32, 0.45) * length)])
    return _law_spec(rng, lay, tid, v, desc, red + [bar, box_], pairs=[_slide(box_, bar, mu)])


def law_friction_two_ramps(rng, lay: Layout, v: int, tid: int, desc: str) -> dict:
    mu1, mu2 = law_value(rng, v, FRICTION_RANGE), law_value(rng, v, FRICTION_RANGE)
    bar1, box1 = _incline_box(rng, lay, (280, 380))
    bar2, box2 = _incline_box(rng, lay, (90, 200))
    red = lay.place(rng, lambda r: [red_drop(r, [box1], y_min=400)])
    return _law_spec(rng, lay, tid, v, desc, red + [bar1, box1, bar2, box2],
                     pairs=[_slide(box1, bar1, mu1), _slide(box2, bar2, mu2)])


def law_friction_ramp_shelf(rng, lay: Layout, v: int, tid: int, desc: str) -> dict:
    mu = law_value(rng, v, FRICTION_RANGE)
    bar, box_ = _incline_box(rng, lay, (220, 330), xr=(150, W))
    low_x = bk.extent(bar)[0]
    shelf = lay.place(rng, lambda r: [draw_shelf(r, uniform(r, 140, 220), (0, low_x + 60),
                                                 (60, 150), 0.0)])[0]
    red = lay.place(rng, lambda r: [red_drop(r, [box_], y_min=380)])
    return _law_spec(rng, lay, tid, v, desc, red + [bar, box_, shelf],
                     pairs=[_slide(box_, bar, mu), _slide(box_, shelf, mu)])


def law_friction_ramp_ball(rng, lay: Layout, v: int, tid: int, desc: str) -> dict:
    mu = law_value(rng, v, FRICTION_RANGE)
    bar, box_ = _incline_box(rng, lay, (150, 300))
    floor = lay.place(rng, lambda r: g_ball(r, xr=(0, bk.extent(bar)[0] + 40)))
    red = lay.place(rng, lambda r: [red_drop(r, [box_], y_min=380)])
    return _law_spec(rng, lay, tid, v, desc, red + [bar, box_] + floor,
                     pairs=[_slide(box_, bar, mu)])


def law_friction_ramp_jar(rng, lay: Layout, v: int, tid: int, desc: str) -> dict:
    mu = law_value(rng, v, FRICTION_RANGE)
    bar, box_ = _incline_box(rng, lay, (170, 300), xr=(120, W))
    low_x = bk.extent(bar)[0]
    jar = lay.place(rng, lambda r: g_jar(r, xr=(low_x - 130, low_x + 30)))
    length = bar["shape"]["length_px"]
    red = lay.place(rng, lambda r: [_ball_above(r, bar, uniform(r, 0.32, 0.45) * length)])
    return _law_spec(rng, lay, tid, v, desc, red + [bar, box_] + jar, pairs=[_slide(box_, bar, mu)])


# Initial velocity: the red ball launched at 50-250 px/s in a template-specific direction.
def _launched(rng, lay: Layout, v: int, target: list[dict], deg: tuple[float, float],
              yr: tuple[float, float]) -> list[dict]:
    """The red ball thrown at `target` with a speed from the variant's half of 50-250 px/s."""
    speed = law_value(rng, v, SPEED_RANGE_PX_S, digits=1)
    return lay.place(rng, lambda r: [red_launch(r, target, speed=speed, deg=deg, yr=yr)])


def law_launch_shelf(rng, lay: Layout, v: int, tid: int, desc: str) -> dict:
    shelf = lay.place(rng, lambda r: g_hbar_box(r, xr=(230, W), yr=(120, 280)))
    floor = lay.place(rng, lambda r: g_box(r, xr=(150, W)))
    red = _launched(rng, lay, v, shelf[1:], (10, 40), (60, 250))
    return _law_spec(rng, lay, tid, v, desc, red + shelf + floor)


def law_launch_jar(rng, lay: Layout, v: int, tid: int, desc: str) -> dict:
    jar = lay.place(rng, lambda r: g_jar(r, xr=(200, W)))
    bar = lay.place(rng, lambda r: g_tbar(r, yr=(250, 400)))
    red = _launched(rng, lay, v, jar, (20, 60), (60, 250))
    return _law_spec(rng, lay, tid, v, desc, red + jar + bar)


def law_launch_dominoes(rng, lay: Layout, v: int, tid: int, desc: str) -> dict:
    dom = lay.place(rng, lambda r: g_dominoes(r, xr=(200, W)))
    red = _launched(rng, lay, v, dom, (-10, 20), (40, 150))
    return _law_spec(rng, lay, tid, v, desc, red + dom)


def law_launch_up(rng, lay: Layout, v: int, tid: int, desc: str) -> dict:
    bars = lay.place(rng, lambda r: g_tbar(r, yr=(250, 420))) + lay.place(
        rng, lambda r: g_tbar(r, yr=(250, 420)))
    red = _launched(rng, lay, v, bars[:1], (45, 80), (30, 120))
    return _law_spec(rng, lay, tid, v, desc, red + bars)


def law_launch_sticks(rng, lay: Layout, v: int, tid: int, desc: str) -> dict:
    st = lay.place(rng, lambda r: g_sticks(r, xr=(200, W)))
    bar = lay.place(rng, g_tbar)
    red = _launched(rng, lay, v, st, (0, 35), (60, 250))
    return _law_spec(rng, lay, tid, v, desc, red + st + bar)


# Mass ratio: the red ball (density d_red) hits dynamic bodies of density d_target.
def _long_shelf(rng) -> dict:
    return draw_shelf(rng, uniform(rng, 260, 420), ALL, (100, 300), 0.0)


def _roller(rng, shelf: dict, density: float) -> dict:
    """The red ball resting on a shelf's left part, rolling right at 80-200 px/s."""
    r = red_radius(rng)
    x, y = bk.on_bar(shelf, -shelf["shape"]["length_px"] / 2 + r + uniform(rng, 5, 20), r + GAP)
    return bk.ball("red_ball", "red", r, x, y, velocity=(uniform(rng, 80, 200), 0.0, 0.0),
                   density=density)


def law_mass_balls(rng, lay: Layout, v: int, tid: int, desc: str) -> dict:
    d_red, d_tgt = _densities(rng, v)

    def pair(r):
        shelf = _long_shelf(r)
        rad, c = uniform(r, 12, 22), dynamic_color(r)
        along = uniform(r, 0, shelf["shape"]["length_px"] / 2 - rad - 10)
        x, y = bk.on_bar(shelf, along, rad + GAP)
        return [_roller(r, shelf, d_red), bk.ball(f"{c}_ball", c, rad, x, y, density=d_tgt), shelf]
    return _law_spec(rng, lay, tid, v, desc, lay.place(rng, pair), static_only=True)


def law_mass_box_on_shelf(rng, lay: Layout, v: int, tid: int, desc: str) -> dict:
    d_red, d_tgt = _densities(rng, v)

    def pair(r):
        shelf = _long_shelf(r)
        w, h, c = uniform(r, 25, 45), uniform(r, 25, 45), dynamic_color(r)
        x, y = bk.on_bar(shelf, uniform(r, 0, shelf["shape"]["length_px"] / 2 - w / 2 - 10),
                         h / 2 + GAP)
        return [_roller(r, shelf, d_red), bk.box(f"{c}_box", c, w, h, x, y, density=d_tgt), shelf]
    return _law_spec(rng, lay, tid, v, desc, lay.place(rng, pair), static_only=True)


def law_mass_floor_boxes(rng, lay: Layout, v: int, tid: int, desc: str) -> dict:
    d_red, d_tgt = _densities(rng, v)

    def boxes(r):
        out = g_box(r, xr=(170, 310)) + g_box(r, xr=(330, W))
        for b in out:
            b["material"]["density_kg_m2"] = d_tgt
        return out
    floor = lay.place(rng, boxes)

    def red(r):
        rad = red_radius(r)
        return [bk.ball("red_ball", "red", rad, uniform(r, rad + 5, 120), rad + GAP,
                        velocity=(uniform(r, 80, 200), 0.0, 0.0), density=d_red)]
    return _law_spec(rng, lay, tid, v, desc, lay.place(rng, red) + floor, static_only=True)


def law_mass_seesaw(rng, lay: Layout, v: int, tid: int, desc: str) -> dict:
    d_red, d_tgt = _densities(rng, v)

    def seesaw(r):
        pivot, plank = g_seesaw(r, xr=(60, W - 60))
        plank["pose"]["x_px"] = pivot["pose"]["x_px"]  # balanced until something lands on it
        load = _box_on(r, plank, uniform(r, 0.3, 0.42) * plank["shape"]["length_px"])
        load["material"]["density_kg_m2"] = d_tgt
        return [pivot, plank, load]
    group = lay.place(rng, seesaw)
    plank = group[1]

    def red(r):
        ball_ = _ball_above(r, plank, -uniform(r, 0.3, 0.42) * plank["shape"]["length_px"])
        ball_["material"]["density_kg_m2"] = d_red
        return [ball_]
    return _law_spec(rng, lay, tid, v, desc, lay.place(rng, red) + group, static_only=True)


def law_mass_jar_on_shelf(rng, lay: Layout, v: int, tid: int, desc: str) -> dict:
    d_red, d_tgt = _densities(rng, v)

    def pair(r):
        shelf = _long_shelf(r)
        w, h, c = uniform(r, 60, 90), uniform(r, 40, 70), dynamic_color(r)
        x, y = bk.on_bar(shelf, uniform(r, 0, shelf["shape"]["length_px"] / 2 - w / 2 - 10),
                         BAR / 2 + GAP)
        return [_roller(r, shelf, d_red), bk.jar(f"{c}_jar", c, w, h, x, y, density=d_tgt), shelf]
    return _law_spec(rng, lay, tid, v, desc, lay.place(rng, pair), static_only=True)


#: (law, description, builder) of the 26 law templates, ids 10071..10096, two variants each.
LAWS: tuple[tuple[str, str, Callable[..., dict]], ...] = (
    ("gravity", "red ball thrown up in a long arc lands on a tilted bar (gravity varies)",
     law_gravity_arc),
    ("gravity", "red ball falls from high onto a static purple block (gravity varies)",
     law_gravity_block),
    ("gravity", "red ball and a box fall freely, the ball onto a tilted bar (gravity varies)",
     law_gravity_two_fall),
    ("gravity", "red ball falls onto a tilted bar and rolls into a jar (gravity varies)",
     law_gravity_bar_jar),
    ("gravity", "red ball rolls off a shelf and flies onto boxes (gravity varies)",
     law_gravity_shelf_launch),
    ("gravity", "red ball and a second ball fall from different heights (gravity varies)",
     law_gravity_two_balls),
    ("restitution", "red ball bounces on a horizontal static bar (restitution varies)",
     law_bounce_bar),
    ("restitution", "red ball bounces on the floor next to boxes (restitution varies)",
     law_bounce_floor),
    ("restitution", "red ball bounces off a static block onto a tilted bar (restitution varies)",
     law_bounce_block),
    ("restitution", "red ball bounces down a tilted bar towards a jar (restitution varies)",
     law_bounce_bar_jar),
    ("restitution", "two balls bounce on a long static bar (restitution varies per ball)",
     law_bounce_two_balls),
    ("friction", "red ball rolls down a ramp into a box resting on it (friction varies)",
     law_friction_ramp),
    ("friction", "boxes rest on two ramps, the ball falls on one (friction varies per box)",
     law_friction_two_ramps),
    ("friction", "a box slides down a ramp onto a shelf after the ball hits it (friction varies)",
     law_friction_ramp_shelf),
    ("friction", "red ball falls on a box on a ramp above a ball (friction varies)",
     law_friction_ramp_ball),
    ("friction", "red ball rolls down a ramp pushing a box towards a jar (friction varies)",
     law_friction_ramp_jar),
    ("initial_velocity", "red ball launched at a box on a shelf (launch speed varies)",
     law_launch_shelf),
    ("initial_velocity", "red ball launched towards a jar under a bar (launch speed varies)",
     law_launch_jar),
    ("initial_velocity", "red ball launched low at three dominoes (launch speed varies)",
     law_launch_dominoes),
    ("initial_velocity", "red ball launched steeply up between tilted bars (launch speed varies)",
     law_launch_up),
    ("initial_velocity", "red ball launched at standing sticks (launch speed varies)",
     law_launch_sticks),
    ("mass_ratio", "red ball rolls along a shelf into a ball (densities vary)", law_mass_balls),
    ("mass_ratio", "red ball rolls along a shelf into a box (densities vary)",
     law_mass_box_on_shelf),
    ("mass_ratio", "red ball rolls along the floor into two boxes (densities vary)",
     law_mass_floor_boxes),
    ("mass_ratio", "red ball lands on a seesaw carrying a box (densities vary)", law_mass_seesaw),
    ("mass_ratio", "red ball rolls along a shelf into a jar (densities vary)",
     law_mass_jar_on_shelf),
)


def _law_builder(tid: int, description: str, fn: Callable[..., dict]) -> Builder:
    return lambda rng, lay, variant: fn(rng, lay, variant, tid, description)


def _catalogue() -> list[Template]:
    out = []
    for k, (groups, action, n) in enumerate(COMBINATIONS):
        tid = 10001 + k
        out.append(Template(tid, "combinatorial", n, _describe(groups, action),
                            _sampled(_combinatorial(tid, groups, action))))
    for k, (law, description, fn) in enumerate(LAWS):
        tid = 10001 + len(COMBINATIONS) + k
        out.append(Template(tid, "law", LAW_VARIANTS, description,
                            _sampled(_law_builder(tid, description, fn)), law=law))
    return out


#: The 2D templates of the benchmark: 70 combinatorial + 26 law, 179 variants in all.
TEMPLATES_2D: list[Template] = _catalogue()


def template_by_id(template_id: int) -> Template:
    """The 2D template with this id (10001..10096)."""
    for t in TEMPLATES_2D:
        if t.template_id == template_id:
            return t
    raise KeyError(f"no 2D template {template_id}; valid: 10001..{10000 + len(TEMPLATES_2D)}")


def category_shares(specs: list[dict]) -> dict[str, float]:
    """Fraction of scenes that contain at least one body of each detection category."""
    counts = dict.fromkeys(CATEGORIES, 0)
    for spec in specs:
        for cat in {category_of(b) for b in spec["bodies"]}:
            counts[cat] += 1
    return {c: counts[c] / max(1, len(specs)) for c in CATEGORIES}
