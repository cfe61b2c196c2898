"""Validity filter for generated 2D candidates: layouts and rollouts a benchmark must not hold.

Why: templates draw random layouts, and some draws are broken in ways a viewer (or a model) would
notice - bodies drawn on top of each other, objects cut by the frame, nothing happening, a body
passing through a static one, or Box2D's per-step translation clamp shaping the motion (then the
"physics" is an engine artefact no other engine reproduces). The builder redraws such candidates.

Reasons (each reported at most once, in this order):

* ``overlap``    two bodies share a pixel at t = 0 (masks drawn with the rasteriser's fill rule);
* ``offscreen``  some body is not entirely inside the canvas at t = 0 (exact geometry);
* ``static``     no dynamic body's position gets more than 15 px from its start during the clip;
* ``tunnelling`` a dynamic body's origin leaves the canvas at some step, or its mask overlaps a
  static body's mask by more than 20 px at some video frame;
* ``speed_cap``  some body moves faster than half of Box2D's cap, b2_maxTranslation / dt
  (2 m per step -> 120 m/s at 60 Hz), i.e. > 60 m/s, measured from consecutive step poses.

Masks are computed only inside each shape's pixel window, so a check costs milliseconds.
"""

from __future__ import annotations

import math

import numpy as np

from visphy_core.api.spec import local_polygons, transform_points
from visphy_plugins.physics.box2d import Rollout, total_steps

REASONS = ("overlap", "offscreen", "static", "tunnelling", "speed_cap")
MIN_MOTION_PX = 15.0
TUNNEL_OVERLAP_PX = 20
#: Box2D 2.3's b2_maxTranslation (metres per step).
B2_MAX_TRANSLATION_M = 2.0
SPEED_CAP_FRACTION = 0.5

Window = tuple[int, int, np.ndarray]  # (row0, col0, bool mask)


def window_mask(b: dict, pose: np.ndarray | tuple[float, float, float], width: int,
                height: int) -> Window | None:
    """A body's pixel mask inside its bounding window, same fill rule as `raster2d`.

    Pixel (i, j) (row 0 on top) is covered iff its centre (i + .5, j + .5), with world
    y = height - image y, lies in the shape or on its boundary. None when nothing is on canvas.
    """
    x, y, a = float(pose[0]), float(pose[1]), float(pose[2])
    shape = b["shape"]
    if shape["type"] == "circle":
        r = float(shape["radius_px"])
        polys, box_ = None, (x - r, x + r, y - r, y + r)
    else:
        polys = [transform_points(p, (x, y, a)) for p in local_polygons(shape)]
        pts = np.concatenate(polys)
        box_ = (pts[:, 0].min(), pts[:, 0].max(), pts[:, 1].min(), pts[:, 1].max())
    xmin, xmax, ymin, ymax = box_
    i0, i1 = max(0, math.ceil(xmin - 0.5)), min(width, math.floor(xmax - 0.5) + 1)
    j0 = max(0, math.ceil(height - ymax - 0.5))
    j1 = min(height, math.floor(height - ymin - 0.5) + 1)
    if i0 >= i1 or j0 >= j1:
        return None
    xs = (np.arange(i0, i1, dtype=np.float64) + 0.5)[None, :]
    ys = (height - (np.arange(j0, j1, dtype=np.float64) + 0.5))[:, None]
    if polys is None:
        return j0, i0, (xs - x) ** 2 + (ys - y) ** 2 <= r * r
    mask = np.zeros((j1 - j0, i1 - i0), dtype=bool)
    for poly in polys:
        part = np.ones_like(mask)
        nxt = np.roll(poly, -1, axis=0)
        for (x0, y0), (x1, y1) in zip(poly, nxt):
            part &= (x1 - x0) * (ys - y0) - (y1 - y0) * (xs - x0) >= 0
        mask |= part
    return j0, i0, mask


def shared_pixels(wa: Window | None, wb: Window | None) -> int:
    """Number of pixels two window masks have in common."""
    if wa is None or wb is None:
        return 0
    (ra, ca, ma), (rb, cb, mb) = wa, wb
    r0, r1 = max(ra, rb), min(ra + ma.shape[0], rb + mb.shape[0])
    c0, c1 = max(ca, cb), min(ca + ma.shape[1], cb + mb.shape[1])
    if r0 >= r1 or c0 >= c1:
        return 0
    return int(np.count_nonzero(ma[r0 - ra:r1 - ra, c0 - ca:c1 - ca]
                                & mb[r0 - rb:r1 - rb, c0 - cb:c1 - cb]))


def _canvas(spec: dict) -> tuple[int, int]:
    w, h = spec["world"]["units"]["canvas_px"]
    return int(w), int(h)


def _pose(b: dict) -> tuple[float, float, float]:
    p = b["pose"]
    return float(p["x_px"]), float(p["y_px"]), float(p["angle_rad"])


def overlapping_pairs(spec: dict) -> list[tuple[str, str]]:
    """Body id pairs whose t = 0 masks share at least one pixel."""
    width, height = _canvas(spec)
    bodies = spec["bodies"]
    wins = [window_mask(b, _pose(b), width, height) for b in bodies]
    return [(bodies[i]["id"], bodies[j]["id"]) for i in range(len(bodies))
            for j in range(i + 1, len(bodies)) if shared_pixels(wins[i], wins[j]) > 0]


def offscreen_ids(spec: dict, tol: float = 1e-6) -> list[str]:
    """Ids of bodies not entirely inside the canvas at t = 0 (exact geometry)."""
    width, height = _canvas(spec)
    out = []
    for b in spec["bodies"]:
        x, y, a = _pose(b)
        if b["shape"]["type"] == "circle":
            r = float(b["shape"]["radius_px"])
            lo, hi = np.array([x - r, y - r]), np.array([x + r, y + r])
        else:
            pts = np.concatenate([transform_points(p, (x, y, a))
                                  for p in local_polygons(b["shape"])])
            lo, hi = pts.min(axis=0), pts.max(axis=0)
        if lo[0] < -tol or lo[1] < -tol or hi[0] > width + tol or hi[1] > height + tol:
            out.append(b["id"])
    return out


def speed_cap_m_s(spec: dict) -> float:
    """The speed above which a rollout is rejected: half of b2_maxTranslation / dt."""
    return SPEED_CAP_FRACTION * B2_MAX_TRANSLATION_M / float(spec["world"]["dt_s"])


def _tunnelling(spec: dict, rollout: Rollout, poses: np.ndarray, dyn: np.ndarray) -> bool:
    width, height = _canvas(spec)
    xy = poses[:, dyn, :2]
    if np.any((xy[..., 0] < 0) | (xy[..., 0] > width) | (xy[..., 1] < 0) | (xy[..., 1] > height)):
        return True
    bodies = spec["bodies"]
    statics = [(i, window_mask(b, _pose(b), width, height))
               for i, b in enumerate(bodies) if not b["dynamic"]]
    statics = [(i, w) for i, w in statics if w is not None]
    if not statics:
        return False
    for k in range(len(rollout.frame_poses)):
        for i in np.flatnonzero(dyn):
            win = window_mask(bodies[i], rollout.frame_poses[k, i], width, height)
            if win is None:
                continue
            for _, swin in statics:
                if shared_pixels(win, swin) > TUNNEL_OVERLAP_PX:
                    return True
    return False


def validity_problems(spec: dict, rollout: Rollout) -> list[str]:
    """Reason keys (subset of `REASONS`, in that order) why a simulated candidate is unusable."""
    problems = []
    if overlapping_pairs(spec):
        problems.append("overlap")
    if offscreen_ids(spec):
        problems.append("offscreen")
    dyn = np.array([b["dynamic"] for b in spec["bodies"]], dtype=bool)
    poses = rollout.step_poses[:min(total_steps(spec), len(rollout.step_poses) - 1) + 1]
    if dyn.any():
        disp = np.hypot(*(poses[:, dyn, :2] - poses[0, dyn, :2]).transpose(2, 0, 1))
        moving = bool(disp.max() > MIN_MOTION_PX)
    else:
        moving = False
    if not moving:
        problems.append("static")
    if dyn.any() and _tunnelling(spec, rollout, poses, dyn):
        problems.append("tunnelling")
    if len(poses) > 1:
        step_px = np.hypot(*np.diff(poses[:, :, :2], axis=0).transpose(2, 0, 1))
        speed = step_px.max() / float(spec["world"]["units"]["px_per_m"]) / float(
            spec["world"]["dt_s"])
        if speed > speed_cap_m_s(spec):
            problems.append("speed_cap")
    return problems
