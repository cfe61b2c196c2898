"""Ground-truth physics as plugins: the simulator that rolls a scene spec out, by world engine.

A scene spec names its simulator in ``world.engine``. The spec track and the variance
normalisation re-simulate specs (the model's S; the ground truth's nudged twin) through whichever
plugin registered that name (``visphy_register_physics``: ``register(name, factory)``) for the
spec's ``dim``, so the core knows no simulator.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass
class Rollout:
    """A simulated clip, the one shape every simulator returns: per-frame poses of every body
    (2D: x_px, y_px, angle in the spec's frame, y up; 3D: position in metres and quaternion
    xyzw), the world step of each frame and its time. The core reads only these four fields.

    What a simulator may add: ``step_poses[s]``, the state after s steps (s = 0: the initial
    state; ``frame_poses[k] = step_poses[frame_steps[k]]``); ``events``, contact begins
    ``{t_s, step, type: "contact_begin", a, b, normal_speed_m_s}`` (ids in spec order, walls or
    floor last); ``step_velocities[s]`` (B×6, 3D: linear then angular velocity);
    ``step_touching[s, b]``, body b touches anything (walls or floor included) in state s;
    ``pair_stats``, "a|b" to ``steps_touching``, ``steps_sliding`` and
    ``max_normal_speed_m_s``; ``initial_penetration_m``, "a|b" to the deepest
    interpenetration in the initial state (3D; ≤ 0: merely touching).
    """

    body_ids: tuple[str, ...] | list[str]
    frame_poses: np.ndarray
    frame_steps: np.ndarray
    frame_times_s: np.ndarray
    step_poses: np.ndarray | None = None
    events: list[dict] = field(default_factory=list)
    step_velocities: np.ndarray | None = None
    step_touching: np.ndarray | None = None
    pair_stats: dict[str, dict[str, float]] = field(default_factory=dict)
    initial_penetration_m: dict[str, float] = field(default_factory=dict)


def trajectory_digest(rollout: Rollout) -> str:
    """SHA-256 over body ids, frame steps/times and the frame and step pose arrays (float64
    LE): what a generated scene's ``digest_sha256`` records, 2D and 3D alike."""
    h = hashlib.sha256()
    h.update("\0".join(rollout.body_ids).encode())
    for arr, dtype in ((rollout.frame_steps, "<i8"), (rollout.frame_times_s, "<f8"),
                       (rollout.frame_poses, "<f8"), (rollout.step_poses, "<f8")):
        a = np.ascontiguousarray(arr, dtype=dtype)
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


class Physics:
    """One simulator. ``name`` is the ``world.engine`` value it simulates; ``dim`` 2d or 3d."""

    name: str = ""
    dim: str = "2d"

    def simulate(self, spec: dict, timeout_s: float = 60.0) -> Rollout:
        """Roll ``spec`` (a full, valid scene spec) out under its own world settings."""
        raise NotImplementedError


def physics_for(spec: dict) -> Physics:
    """The registered simulator of ``spec["world"]["engine"]`` (``KeyError`` naming the
    installed ones when none is, or saying so when it simulates another ``dim`` than the
    spec's)."""
    from visphy_core.api.registry import get_registry

    engine = str((spec.get("world") or {}).get("engine", ""))
    factory: Any = get_registry().get("physics", engine)
    physics = factory()
    dim = spec.get("dim", physics.dim)
    if physics.dim != dim:
        raise KeyError(f"physics {engine!r} simulates {physics.dim} scenes; this spec is {dim}")
    return physics
