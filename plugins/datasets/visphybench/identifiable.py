"""Which physical parameters a clip can actually reveal (2D and 3D rollouts alike).

The parameter-recovery study must only score what the video shows, so each flag is derived from
the rollout, at the clip's frame interval (steps_per_frame · dt):

- gravity: some dynamic body touches nothing over three consecutive frames (one second
  difference of free flight is visible);
- initial_velocity: the bodies that start with a non-zero velocity (the others are known to
  start at rest);
- restitution: pairs whose rebound e·v_n keeps a body airborne for at least one frame interval
  (2 e v_n / g ≥ interval);
- friction: pairs sliding for at least one frame interval;
- mass_ratio: pairs of dynamic bodies that collide at ≥ 1 m/s (momentum exchange is visible).
"""

from __future__ import annotations

import numpy as np

from visphy_core.api.spec import contact_table


def _moving_at_start(body: dict) -> bool:
    v = body.get("velocity") or {}
    values = []
    for value in v.values():
        values.extend(value if isinstance(value, list) else [value])
    return any(abs(float(x)) > 0 for x in values)


def identifiable_params(spec: dict, rollout) -> dict:
    w = spec["world"]
    interval = w["steps_per_frame"] * w["dt_s"]
    g = float(np.linalg.norm(w["gravity_m_s2"]))
    touching, fs = rollout.step_touching, rollout.frame_steps
    gravity = False
    for i, body in enumerate(spec["bodies"]):
        if not body["dynamic"]:
            continue
        for k in range(len(fs) - 2):
            if not touching[fs[k]:fs[k + 2] + 1, i].any():
                gravity = True
                break
    default, table = contact_table(spec)
    dynamic = {b["id"] for b in spec["bodies"] if b["dynamic"]}
    restitution, friction, mass_ratio = [], [], []
    for key, st in rollout.pair_stats.items():
        a, b = key.split("|")
        e = table.get(frozenset((a, b)), default)["restitution"]
        if g > 0 and 2 * e * st["max_normal_speed_m_s"] / g >= interval:
            restitution.append([a, b])
        if st["steps_sliding"] * w["dt_s"] >= interval:
            friction.append([a, b])
        if a in dynamic and b in dynamic and st["max_normal_speed_m_s"] >= 1.0:
            mass_ratio.append([a, b])
    moving = [b["id"] for b in spec["bodies"] if b["dynamic"] and _moving_at_start(b)]
    return {"gravity": gravity, "initial_velocity": moving, "restitution": restitution,
            "friction": friction, "mass_ratio": mass_ratio}
