"""Native-drawing reference programs: the ground truth drawn with each engine's own primitives.

Every engine has two trusted reference programs for a ground-truth scene, both reading the same
replay payload (`visphy_core.spec.replay`: per-frame poses, shapes, colours):

* **exact** (`Engine.program_from_spec`): reproduces the benchmark's alias-free raster (p5 writes
  the pixels into ``pixels[]``, Manim shows a pre-rasterised image, the others draw real shapes
  tuned to the rasteriser's pixel-centre rule). It is the plumbing ceiling: the oracle clip is
  (nearly) byte-identical across engines, so cross-engine oracle numbers test the pipeline.
* **native** (`Engine.native_program_from_spec`): draws the same poses the way a correct model
  program would, with the engine's own primitives and its default anti-aliasing — p5
  ``circle``/``rect``/``beginShape`` (smoothing on), three.js ``CircleGeometry``/
  ``PlaneGeometry``/``ShapeGeometry`` with ``antialias: true``, SVG ``<circle>``/``<rect>``/
  ``<polygon>`` (default ``shape-rendering``), Manim ``Circle``/``Rectangle``/``Polygon``
  (Cairo), Blender meshes (a 64-gon disc, planes, n-gons) with a Principled-BSDF material under
  Workbench's default anti-aliasing. It is that engine's intrinsic ceiling: what a perfect
  program loses to the engine's own rasterisation.

In 3D the exact programs of three.js and Blender already draw meshes with the engine's own
renderer (the 3D ground truth *is* a three.js render, anti-aliased), so their native program is
the exact one; p5, SVG and Manim have no 3D reference program of either kind.

`native_payload` is the replay payload plus, per 2D body, ``outline``: the body drawn as one
polygon. A compound (a jar: three abutting bars) becomes one simple, possibly concave polygon
(the union of its parts), as a program would draw a U shape: drawn part by part, anti-aliased
edges that touch leave a visible seam where no edge is.
"""

from __future__ import annotations

import math

from visphy_core.api.spec import replay_payload

#: Segments of a disc where the engine draws circles as polygons (three.js, Blender): the
#: chord of a 64-gon stays within r·(1 − cos(π/64)) < 0.07 px of a 56 px circle.
DISC_SEGMENTS = 64

_EPS = 1e-6


def native_payload(scene) -> dict:
    """The scene's replay payload with, in 2D, each non-circle body's ``outline`` (local px,
    y up, CCW): its single polygon, the union outline of a compound's abutting parts, or absent
    when the parts do not join into one simple outline (the program then draws the parts)."""
    payload = replay_payload(scene)
    payload["style"] = "native"
    if payload["dim"] != "2d":
        return payload
    for body in payload["bodies"]:
        parts = body.get("polygons")
        if not parts:
            continue
        outline = parts[0] if len(parts) == 1 else union_outline(parts)
        if outline is not None:
            body["outline"] = [[round(float(x), 6) + 0.0, round(float(y), 6) + 0.0]
                               for x, y in outline]
    return payload


def union_outline(parts: list) -> list[list[float]] | None:
    """The outline of the union of convex CCW polygons that only touch along edges (no
    overlap), as one CCW loop without collinear vertices; None when the parts do not make one
    simple loop (overlapping or disjoint parts)."""
    pts = [[(float(x), float(y)) for x, y in part] for part in parts]
    vertices = [p for part in pts for p in part]
    edges: list[tuple[tuple[float, float], tuple[float, float]]] = []
    for part in pts:
        for i, a in enumerate(part):
            b = part[(i + 1) % len(part)]
            # split the edge at every vertex of another part that lies on it (T-junctions)
            on = [v for v in vertices if _on_segment(v, a, b)]
            on.sort(key=lambda v: (v[0] - a[0]) ** 2 + (v[1] - a[1]) ** 2)
            chain = [a] + on + [b]
            edges += [(p, q) for p, q in zip(chain, chain[1:]) if not _same(p, q)]
    # an edge shared by two parts appears once in each direction: both are inside the union
    kept = [e for e in edges if not any(_same(e[0], f[1]) and _same(e[1], f[0]) for f in edges)]
    if len(kept) < 3:
        return None
    loop = [kept[0][0]]
    current = kept[0]
    used = {0}
    while not _same(current[1], loop[0]):
        nxt = [i for i, e in enumerate(kept) if i not in used and _same(e[0], current[1])]
        if len(nxt) != 1:
            return None  # a branch or a dead end: not one simple loop
        used.add(nxt[0])
        current = kept[nxt[0]]
        loop.append(current[0])
    if len(used) != len(kept):
        return None  # several loops (disjoint parts or a hole)
    loop = _drop_collinear(loop)
    area = sum(p[0] * q[1] - q[0] * p[1] for p, q in zip(loop, loop[1:] + loop[:1])) / 2.0
    parts_area = sum(abs(_area(part)) for part in pts)
    if len(loop) < 3 or area <= 0 or not math.isclose(area, parts_area, rel_tol=1e-6,
                                                         abs_tol=1e-6):
        return None  # overlapping parts: the loop does not bound their total area
    return [[p[0], p[1]] for p in loop]


def _same(p, q) -> bool:
    return abs(p[0] - q[0]) <= _EPS and abs(p[1] - q[1]) <= _EPS


def _on_segment(v, a, b) -> bool:
    """v strictly inside segment ab (not an end point)."""
    if _same(v, a) or _same(v, b):
        return False
    dx, dy = b[0] - a[0], b[1] - a[1]
    length2 = dx * dx + dy * dy
    if length2 == 0:
        return False
    cross = (v[0] - a[0]) * dy - (v[1] - a[1]) * dx
    if abs(cross) > _EPS * math.sqrt(length2):
        return False
    t = ((v[0] - a[0]) * dx + (v[1] - a[1]) * dy) / length2
    return 0.0 < t < 1.0


def _area(poly) -> float:
    return sum(p[0] * q[1] - q[0] * p[1] for p, q in zip(poly, poly[1:] + poly[:1])) / 2.0


def _drop_collinear(loop):
    out = list(loop)
    changed = True
    while changed and len(out) > 3:
        changed = False
        for i in range(len(out)):
            a, b, c = out[i - 1], out[i], out[(i + 1) % len(out)]
            cross = (b[0] - a[0]) * (c[1] - b[1]) - (b[1] - a[1]) * (c[0] - b[0])
            if abs(cross) <= _EPS * max(1.0, math.dist(a, b) * math.dist(b, c)):
                del out[i]
                changed = True
                break
    return out
