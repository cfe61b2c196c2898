"""The validity ordering's (ii) clips: the physics of the ground truth X changed and
re-simulated (Box2D in 2D, cannon-es in 3D), drawn like the truth (`INTERVENTIONS`):

gravity ×0.5 and ×2; restitution ±0.3 (clamped to [0, 0.98]); friction ×0.25 and +0.4 (every
body material, the default contact and every explicit pair); one dynamic body removed
(`removed_body`: preferably not the main mover, and one whose absence changes another body's
motion); a different outcome for the action body (`action_body`: the dynamic body with the
largest initial speed, else the red ball): initial speed ×1.5 and its horizontal direction
reversed when it is thrown, a horizontal kick toward the middle of the scene (`KICK_PX_S` /
`KICK_M_S`) when it starts at rest.

A variant whose clip equals the truth exactly is skipped (``skipped``: why; `study.make_clips`);
each kept one records its ``deviation`` (`deviation`): how far (image px; 3D positions
projected through the camera, `positions_px`) its bodies get from the truth's, so a summary may
count only clearly wrong clips (``min_px``, `ClipScore.visible`). The spec edits here
(`with_gravity`, `with_material`, the action body's velocity) are also the dose series' (`dose`).
"""

from __future__ import annotations

import copy
import dataclasses
import math
from typing import Callable

import numpy as np

from visphy_plugins.studies.validity.clips import Truth
from visphy_plugins.studies.validity.perturbation import _materials

GRAVITY = (0.5, 2.0)
RESTITUTION_DELTA = 0.3
RESTITUTION_RANGE = (0.0, 0.98)
FRICTION_SCALE = 0.25
FRICTION_DELTA = 0.4
SPEED = 1.5
KICK_PX_S = 40.0           # 2D: 40 px/s (the clip shows one simulated second per frame)
KICK_M_S = 1.5             # 3D
MOVING_PX = 1.0           # a body whose image moves at least this far "moves"
VISIBLE_PX = 2.0          # a change of motion anyone can see (`removed_body`, `visible`)


# --------------------------------------------------------------------------- (ii) physics
Edit = Callable[[dict, Truth], "tuple[dict | None, str]"]


@dataclasses.dataclass(frozen=True)
class Intervention:
    """One physics-wrong variant: ``edit(spec, truth)`` → (the changed spec, what changed), or
    (None, why not) where it does not apply."""

    name: str
    edit: Edit


def with_material(spec: dict, key: str, fn: Callable[[float], float]) -> dict:
    """``spec`` with ``key`` (friction, restitution) of every material and contact through
    ``fn``."""
    out = copy.deepcopy(spec)
    for m in _materials(out):
        if key in m:
            m[key] = float(fn(float(m[key])))
    return out


def with_gravity(spec: dict, factor: float) -> dict:
    out = copy.deepcopy(spec)
    out["world"]["gravity_m_s2"] = [float(g) * factor for g in out["world"]["gravity_m_s2"]]
    return out


def _linear(body: dict, dim: str) -> np.ndarray:
    v = body.get("velocity") or {}
    if dim == "2d":
        return np.array([v.get("vx_px_s", 0.0), v.get("vy_px_s", 0.0)], dtype=np.float64)
    return np.asarray(v.get("linear_m_s", [0.0, 0.0, 0.0]), dtype=np.float64)


def _set_linear(body: dict, dim: str, vel: np.ndarray) -> None:
    if dim == "2d":
        body["velocity"]["vx_px_s"], body["velocity"]["vy_px_s"] = (float(vel[0]),
                                                                    float(vel[1]))
    else:
        body["velocity"]["linear_m_s"] = [float(v) for v in vel]


def action_body(spec: dict) -> str | None:
    """The body whose start decides the outcome: the dynamic body with the largest initial
    speed; when every body starts at rest, the red ball (else the first dynamic body)."""
    dynamic = [b for b in spec["bodies"] if b.get("dynamic")]
    if not dynamic:
        return None
    speeds = [float(np.linalg.norm(_linear(b, spec["dim"]))) for b in dynamic]
    if max(speeds) > 0:
        return dynamic[int(np.argmax(speeds))]["id"]
    red = [b["id"] for b in dynamic if b["id"] == "red_ball"]
    return red[0] if red else dynamic[0]["id"]


def positions_px(spec: dict, poses: np.ndarray) -> np.ndarray:
    """Every body's position in image pixels per frame (frames × bodies × 2): 2D poses are
    pixels already; 3D positions are projected through the spec's pinhole camera."""
    poses = np.asarray(poses, dtype=np.float64)
    if spec["dim"] == "2d":
        return poses[:, :, :2]
    cam = spec["camera"]
    eye = np.asarray(cam["position"], dtype=np.float64)
    fwd = np.asarray(cam["look_at"], dtype=np.float64) - eye
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, np.asarray(cam.get("up", [0.0, 1.0, 0.0]), dtype=np.float64))
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    d = poses[:, :, :3] - eye
    depth = np.maximum(d @ fwd, 1e-6)
    focal = (float(cam["height"]) / 2.0) / math.tan(math.radians(float(cam["fov_deg"])) / 2.0)
    return np.stack([float(cam["width"]) / 2.0 + focal * (d @ right) / depth,
                     float(cam["height"]) / 2.0 - focal * (d @ up) / depth], axis=-1)


def displacements(truth: Truth) -> dict[str, float]:
    """Per dynamic body, the largest distance (image px) it gets from its start in the truth."""
    pos = positions_px(truth.spec, truth.poses)
    far = np.linalg.norm(pos - pos[:1], axis=2).max(axis=0)
    return {b["id"]: float(far[i]) for i, b in enumerate(truth.spec["bodies"])
            if b.get("dynamic")}


def deviation(truth: Truth, spec: dict, poses: np.ndarray) -> float:
    """How far a re-simulated spec's dynamic bodies get from the truth's: the largest distance
    (image px) between a body's positions in the two rollouts at the same frame, over the
    bodies both have."""
    ids = [b["id"] for b in spec["bodies"]]
    mine, theirs = positions_px(spec, poses), positions_px(truth.spec, truth.poses)
    n = min(len(mine), len(theirs))
    far = 0.0
    for i, b in enumerate(truth.spec["bodies"]):
        if b.get("dynamic") and b["id"] in ids:
            j = ids.index(b["id"])
            far = max(far, float(np.linalg.norm(mine[:n, j] - theirs[:n, i], axis=1).max()))
    return far


def removed_body(truth: Truth) -> str | None:
    """Which dynamic body `remove` takes out. Candidates in order: the moving bodies other than
    the main mover (the action body if it moves, else the farthest mover; farthest first), the
    still dynamic bodies (spec order), the main mover. The first whose removal changes another
    body's motion by at least `VISIBLE_PX` is taken (the physics changes, not only the
    drawing); where none does, the first candidate."""
    far = displacements(truth)
    if not far:
        return None
    moving = sorted((b for b, d in far.items() if d >= MOVING_PX), key=far.get, reverse=True)
    action = action_body(truth.spec)
    main = action if action in moving else (moving[0] if moving else None)
    order = [b for b in moving if b != main] + [b for b in far if b not in moving]
    order += [main] if main is not None else []
    for body in order:
        spec = without_body(truth.spec, body)
        try:
            poses = truth.renderer.simulate(spec)
        except Exception:  # noqa: BLE001 - a candidate that fails is not taken
            continue
        if deviation(truth, spec, poses) >= VISIBLE_PX:
            return body
    return order[0]


def without_body(spec: dict, body_id: str) -> dict:
    """``spec`` without body ``body_id`` (and its explicit contact pairs)."""
    out = copy.deepcopy(spec)
    out["bodies"] = [b for b in out["bodies"] if b["id"] != body_id]
    out["contacts"]["pairs"] = [p for p in out["contacts"]["pairs"]
                                if body_id not in (p.get("a"), p.get("b"))]
    return out


def _gravity(factor: float) -> Edit:
    return lambda spec, truth: (with_gravity(spec, factor), f"gravity ×{factor:g}")


def _restitution(delta: float) -> Edit:
    lo, hi = RESTITUTION_RANGE
    return lambda spec, truth: (with_material(spec, "restitution",
                                              lambda e: min(hi, max(lo, e + delta))),
                                f"restitution {delta:+g} (clamped to [{lo:g}, {hi:g}])")


def _friction_scale(spec: dict, truth: Truth):
    return with_material(spec, "friction", lambda f: f * FRICTION_SCALE), \
        f"friction ×{FRICTION_SCALE:g}"


def _friction_add(spec: dict, truth: Truth):
    return with_material(spec, "friction", lambda f: f + FRICTION_DELTA), \
        f"friction {FRICTION_DELTA:+g}"


def _remove(spec: dict, truth: Truth):
    body = removed_body(truth)
    if body is None:
        return None, "no dynamic body"
    n_dynamic = sum(1 for b in spec["bodies"] if b.get("dynamic"))
    return without_body(spec, body), (f"{body} removed" + (" (the only dynamic body)"
                                                            if n_dynamic == 1 else ""))


def _thrown(spec: dict) -> tuple[dict | None, np.ndarray]:
    bid = action_body(spec)
    if bid is None:
        return None, np.zeros(2)
    body = next(b for b in spec["bodies"] if b["id"] == bid)
    return body, _linear(body, spec["dim"])


def _speed(spec: dict, truth: Truth):
    body, vel = _thrown(spec)
    if body is None or not np.any(vel):
        return None, "the action body starts at rest (see kick)"
    out = copy.deepcopy(spec)
    _set_linear(next(b for b in out["bodies"] if b["id"] == body["id"]), spec["dim"],
                vel * SPEED)
    return out, f"{body['id']}'s initial speed ×{SPEED:g}"


def _mirror(spec: dict, truth: Truth):
    body, vel = _thrown(spec)
    if body is None or not np.any(vel):
        return None, "the action body starts at rest (see kick)"
    out = copy.deepcopy(spec)
    flipped = vel.copy()
    if spec["dim"] == "2d":
        flipped[0] = -flipped[0]
    else:
        flipped[[0, 2]] = -flipped[[0, 2]]
    _set_linear(next(b for b in out["bodies"] if b["id"] == body["id"]), spec["dim"], flipped)
    return out, f"{body['id']}'s horizontal direction reversed"


def _kick(spec: dict, truth: Truth):
    body, vel = _thrown(spec)
    if body is None:
        return None, "no dynamic body"
    if np.any(vel):
        return None, "the action body is thrown (see speed, mirror)"
    out = copy.deepcopy(spec)
    target = next(b for b in out["bodies"] if b["id"] == body["id"])
    if spec["dim"] == "2d":
        width = float(spec["world"]["units"]["canvas_px"][0])
        sign = 1.0 if target["pose"]["x_px"] <= width / 2.0 else -1.0
        _set_linear(target, "2d", np.array([sign * KICK_PX_S, 0.0]))
        what = f"{body['id']} kicked {sign * KICK_PX_S:+g} px/s horizontally"
    else:
        x, _, z = target["pose"]["position_m"]
        d = np.array([-x, 0.0, -z], dtype=np.float64)
        d = d / np.linalg.norm(d) if np.linalg.norm(d) > 1e-9 else np.array([1.0, 0.0, 0.0])
        _set_linear(target, "3d", d * KICK_M_S)
        what = f"{body['id']} kicked {KICK_M_S:g} m/s horizontally toward the middle"
    return out, what


INTERVENTIONS: list[Intervention] = [
    *[Intervention(f"gravity_x{f:g}", _gravity(f)) for f in GRAVITY],
    Intervention(f"restitution{RESTITUTION_DELTA:+g}", _restitution(RESTITUTION_DELTA)),
    Intervention(f"restitution{-RESTITUTION_DELTA:+g}", _restitution(-RESTITUTION_DELTA)),
    Intervention(f"friction_x{FRICTION_SCALE:g}", _friction_scale),
    Intervention(f"friction{FRICTION_DELTA:+g}", _friction_add),
    Intervention("remove", _remove),
    Intervention(f"speed_x{SPEED:g}", _speed),
    Intervention("mirror", _mirror),
    Intervention("kick", _kick),
]
