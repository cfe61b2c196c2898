"""Ground-truth rollouts of 2D scene specs with Box2D 2.3.10 (the engine family PHYRE uses).

Why this module exists: generated VisPhyBench scenes need exact, reproducible trajectories. The
simulation follows the spec literally (PHYRE profile: 6 px/m, g = 9.8 m/s^2, dt = 1/60 s,
15/20 solver iterations, walls just outside the canvas) and records the pose of every body after
every step. Frame k of the clip is the state after `steps_per_frame * k + first_frame_after_steps`
steps (60k + 1 for PHYRE, which records after each step), so one video frame is one simulated
second and a free fall shows second differences of exactly 9.8 * 6 = 58.8 px/frame^2.

Contact materials come from `spec.contacts` and are written onto every Box2D contact in PreSolve,
so the ground truth never depends on Box2D's mixing rule (sqrt(f1 f2), max(e1, e2)), which other
engines (cannon: product) do not share.
"""

from __future__ import annotations

import Box2D
import numpy as np

from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.physics import Physics, Rollout
from visphy_core.api.physics import trajectory_digest as trajectory_digest  # 2D callers' name
from visphy_core.api.spec import WALL_IDS, contact_table, local_polygons

#: Tangential speed (m/s) above which a touching contact counts as sliding for `pair_stats`.
SLIDE_SPEED_M_S = 0.05


class _Listener(Box2D.b2ContactListener):
    """Overrides contact materials per pair and records body-pair contact begins."""

    def __init__(self, default: dict[str, float], pairs: dict[frozenset[str], dict[str, float]],
                 order: dict[str, int]) -> None:
        super().__init__()
        self.default, self.pairs, self.order = default, pairs, order
        self.step = 0
        self.events: list[dict] = []
        self.touch_count: dict[tuple[str, str], int] = {}
        self.max_speed: dict[tuple[str, str], float] = {}

    def _key(self, contact: Box2D.b2Contact) -> tuple[str, str]:
        a, b = contact.fixtureA.body.userData, contact.fixtureB.body.userData
        return (a, b) if self.order[a] <= self.order[b] else (b, a)

    def PreSolve(self, contact: Box2D.b2Contact, old_manifold: Box2D.b2Manifold) -> None:
        a, b = contact.fixtureA.body.userData, contact.fixtureB.body.userData
        mat = self.pairs.get(frozenset((a, b)), self.default)
        contact.friction = mat["friction"]
        contact.restitution = mat["restitution"]

    def BeginContact(self, contact: Box2D.b2Contact) -> None:
        key = self._key(contact)
        count = self.touch_count.get(key, 0)
        self.touch_count[key] = count + 1
        if count:  # another fixture pair of the same two bodies already touches (compounds)
            return
        body_a, body_b = contact.fixtureA.body, contact.fixtureB.body
        wm = contact.worldManifold
        n = wm.normal
        npts = contact.manifold.pointCount
        speeds = []
        for p in list(wm.points)[:max(npts, 1)]:
            va = body_a.GetLinearVelocityFromWorldPoint(p)
            vb = body_b.GetLinearVelocityFromWorldPoint(p)
            speeds.append((va.x - vb.x) * n.x + (va.y - vb.y) * n.y)
        speed = abs(float(np.mean(speeds)))
        self.max_speed[key] = max(self.max_speed.get(key, 0.0), speed)
        self.events.append({"step": self.step, "type": "contact_begin", "a": key[0], "b": key[1],
                            "normal_speed_m_s": speed})

    def EndContact(self, contact: Box2D.b2Contact) -> None:
        key = self._key(contact)
        self.touch_count[key] = max(0, self.touch_count.get(key, 0) - 1)


def _add_fixtures(body: Box2D.b2Body, shape: dict, ppm: float, density: float,
                  friction: float, restitution: float) -> None:
    kw = {"density": density, "friction": friction, "restitution": restitution}
    if shape["type"] == "circle":
        body.CreateFixture(shape=Box2D.b2CircleShape(radius=shape["radius_px"] / ppm), **kw)
        return
    for poly in local_polygons(shape):
        verts = [(float(x) / ppm, float(y) / ppm) for x, y in poly]
        body.CreateFixture(shape=Box2D.b2PolygonShape(vertices=verts), **kw)


def _add_walls(world: Box2D.b2World, spec: dict, ppm: float) -> list[Box2D.b2Body]:
    """Static boxes of `walls.thickness_px` just outside the canvas (floor at the bottom edge)."""
    w, h = spec["world"]["units"]["canvas_px"]
    t = spec["world"]["walls"]["thickness_px"]
    boxes = {"bottom": (w / 2, -t / 2, w / 2 + t, t / 2),
             "top": (w / 2, h + t / 2, w / 2 + t, t / 2),
             "left": (-t / 2, h / 2, t / 2, h / 2 + t),
             "right": (w + t / 2, h / 2, t / 2, h / 2 + t)}
    walls = []
    for side in ("bottom", "left", "right", "top"):
        if side not in spec["world"]["walls"]["sides"]:
            continue
        cx, cy, hx, hy = boxes[side]
        body = world.CreateStaticBody(position=(cx / ppm, cy / ppm), userData=f"wall_{side}")
        body.CreateFixture(shape=Box2D.b2PolygonShape(box=(hx / ppm, hy / ppm)), density=0.0)
        walls.append(body)
    return walls


def total_steps(spec: dict) -> int:
    """Number of Box2D steps needed to reach the last frame."""
    w = spec["world"]
    return w["steps_per_frame"] * (w["n_frames"] - 1) + w["first_frame_after_steps"]


def simulate_2d(spec: dict, n_steps: int | None = None) -> Rollout:
    """Simulate a validated 2D spec and record every body's pose after every step.

    `n_steps` defaults to the steps the clip needs; frames beyond a shorter run are omitted.
    """
    wcfg = spec["world"]
    ppm = float(wcfg["units"]["px_per_m"])
    dt = float(wcfg["dt_s"])
    default, pairs = contact_table(spec)
    ids = tuple(b["id"] for b in spec["bodies"])
    order = {bid: i for i, bid in enumerate(ids + WALL_IDS)}
    listener = _Listener(default, pairs, order)
    world = Box2D.b2World(gravity=tuple(float(g) for g in wcfg["gravity_m_s2"]),
                          doSleep=bool(wcfg.get("allow_sleep", True)), contactListener=listener)
    _add_walls(world, spec, ppm)
    bodies = []
    for b in spec["bodies"]:
        pose = b["pose"]
        kw = {"position": (pose["x_px"] / ppm, pose["y_px"] / ppm), "angle": pose["angle_rad"],
              "userData": b["id"]}
        mat = b.get("material", {"density_kg_m2": 0.0, **default})
        if b["dynamic"]:
            vel = b["velocity"]
            body = world.CreateDynamicBody(
                linearVelocity=(vel["vx_px_s"] / ppm, vel["vy_px_s"] / ppm),
                angularVelocity=vel["omega_rad_s"], linearDamping=wcfg["damping"]["linear"],
                angularDamping=wcfg["damping"]["angular"], **kw)
        else:
            body = world.CreateStaticBody(**kw)
        _add_fixtures(body, b["shape"], ppm, mat["density_kg_m2"] if b["dynamic"] else 0.0,
                      mat["friction"], mat["restitution"])
        bodies.append(body)

    n_steps = total_steps(spec) if n_steps is None else n_steps
    vel_it, pos_it = wcfg["solver"]["velocity_iterations"], wcfg["solver"]["position_iterations"]
    poses = np.empty((n_steps + 1, len(bodies), 3), dtype=np.float64)
    touching = np.zeros((n_steps + 1, len(bodies)), dtype=bool)
    steps_touching: dict[tuple[str, str], int] = {}
    steps_sliding: dict[tuple[str, str], int] = {}

    def record(s: int) -> None:
        for i, body in enumerate(bodies):
            p = body.position
            poses[s, i] = (p.x * ppm, p.y * ppm, body.angle)
        touched: set[tuple[str, str]] = set()
        slid: set[tuple[str, str]] = set()
        for c in world.contacts:
            if not c.touching:
                continue
            key = listener._key(c)
            for bid in key:
                if order[bid] < len(bodies):
                    touching[s, order[bid]] = True
            touched.add(key)
            if key in slid:
                continue
            wm = c.worldManifold
            ba, bb = c.fixtureA.body, c.fixtureB.body
            tx, ty = -wm.normal.y, wm.normal.x
            for p in list(wm.points)[:c.manifold.pointCount]:
                va = ba.GetLinearVelocityFromWorldPoint(p)
                vb = bb.GetLinearVelocityFromWorldPoint(p)
                if abs((va.x - vb.x) * tx + (va.y - vb.y) * ty) > SLIDE_SPEED_M_S:
                    slid.add(key)
                    break
        for key in touched:
            steps_touching[key] = steps_touching.get(key, 0) + 1
        for key in slid:
            steps_sliding[key] = steps_sliding.get(key, 0) + 1

    record(0)
    for s in range(1, n_steps + 1):
        listener.step = s
        world.Step(dt, vel_it, pos_it)
        record(s)

    first, spf = wcfg["first_frame_after_steps"], wcfg["steps_per_frame"]
    frame_steps = np.array([first + spf * k for k in range(wcfg["n_frames"])
                            if first + spf * k <= n_steps], dtype=np.int64)
    events = [{"t_s": round(e["step"] * dt, 9), "step": e["step"], "type": e["type"], "a": e["a"],
               "b": e["b"], "normal_speed_m_s": round(e["normal_speed_m_s"], 6)}
              for e in listener.events]
    stats = {f"{a}|{b}": {"steps_touching": steps_touching.get((a, b), 0),
                          "steps_sliding": steps_sliding.get((a, b), 0),
                          "max_normal_speed_m_s": listener.max_speed.get((a, b), 0.0)}
             for a, b in sorted(set(steps_touching) | set(listener.max_speed),
                                key=lambda k: (order[k[0]], order[k[1]]))}
    return Rollout(body_ids=ids, frame_poses=poses[frame_steps].copy(), step_poses=poses,
                   frame_steps=frame_steps, frame_times_s=frame_steps.astype(np.float64) * dt,
                   events=events, step_touching=touching, pair_stats=stats)


def frame_second_differences(rollout: Rollout, body: int = 0, axis: int = 1) -> np.ndarray:
    """Second differences of one body's frame coordinate (px/frame^2); -g*ppm in free fall."""
    y = rollout.frame_poses[:, body, axis]
    return y[2:] - 2 * y[1:-1] + y[:-2]


class Box2DPhysics(Physics):
    """``world.engine = "box2d"``: the 2D benchmark's simulator (the spec track and the
    variance normalisation re-simulate 2D specs through it)."""

    name = "box2d"
    dim = "2d"

    def simulate(self, spec: dict, timeout_s: float = 60.0) -> Rollout:
        return simulate_2d(spec)


@hookimpl
def visphy_register_physics(register):
    register(Box2DPhysics.name, Box2DPhysics)
