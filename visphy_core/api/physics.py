"""Ground-truth physics as plugins: the simulator that rolls a scene spec out, by world engine.

A scene spec names its simulator in ``world.engine`` (``box2d`` for the 2D benchmark,
``cannon-es`` for the 3D one). The spec track and the variance normalisation re-simulate specs
(the model's S; the ground truth's nudged twin) through whichever plugin registered that name
(``visphy_register_physics``: ``register("box2d", Box2DPhysics)``), so the core knows no
simulator.
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np


class Rollout(Protocol):
    """A simulated clip: per-frame poses of every body (2D: x_px, y_px, angle; 3D: position
    and quaternion xyzw), the world step of each frame and its time."""

    body_ids: list[str]
    frame_poses: np.ndarray
    frame_steps: np.ndarray
    frame_times_s: np.ndarray


class Physics:
    """One simulator. ``name`` is the ``world.engine`` value it simulates; ``dim`` 2d or 3d."""

    name: str = ""
    dim: str = "2d"

    def simulate(self, spec: dict, timeout_s: float = 60.0) -> Rollout:
        """Roll ``spec`` (a full, valid scene spec) out under its own world settings."""
        raise NotImplementedError


def physics_for(spec: dict) -> Physics:
    """The registered simulator of ``spec["world"]["engine"]`` (``KeyError`` naming the
    installed ones when none is)."""
    from visphy_core.api.registry import get_registry

    engine = str((spec.get("world") or {}).get("engine", ""))
    factory: Any = get_registry().get("physics", engine)
    return factory()
