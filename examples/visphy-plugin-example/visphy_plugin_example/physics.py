"""Simulator ``example_euler``: point masses under gravity (semi-implicit Euler, no contacts).

A scene spec names its simulator in ``world.engine``; the spec track and the variance
normalisation re-simulate specs through the plugin registered under that name
(`visphy_core.api.physics.physics_for`). A rollout gives every body's pose (x_px, y_px, angle)
at each frame, with the world step and time of the frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.physics import Physics


@dataclass
class Rollout:
    body_ids: list[str]
    frame_poses: np.ndarray      # n_frames × n_bodies × 3
    frame_steps: np.ndarray
    frame_times_s: np.ndarray


class EulerPhysics(Physics):
    name = "example_euler"
    dim = "2d"

    def simulate(self, spec: dict, timeout_s: float = 60.0) -> Rollout:
        w = spec["world"]
        ppm, dt = float(w["units"]["px_per_m"]), float(w["dt_s"])
        gravity = np.asarray(w["gravity_m_s2"], float) * ppm          # px/s², y up
        bodies = spec["bodies"]
        pos = np.array([[b["pose"]["x_px"], b["pose"]["y_px"]] for b in bodies], float)
        vel = np.array([[b["velocity"]["vx_px_s"], b["velocity"]["vy_px_s"]] for b in bodies],
                       float)
        moving = np.array([bool(b.get("dynamic", True)) for b in bodies])[:, None]
        steps = [w["first_frame_after_steps"] + w["steps_per_frame"] * k
                 for k in range(w["n_frames"])]
        poses = np.zeros((len(steps), len(bodies), 3))
        for step in range(steps[-1] + 1):
            if step in steps:
                poses[steps.index(step), :, :2] = pos
            vel = vel + dt * gravity * moving
            pos = pos + dt * vel
        return Rollout([b["id"] for b in bodies], poses, np.asarray(steps),
                       np.asarray(steps, float) * dt)


@hookimpl
def visphy_register_physics(register):
    register(EulerPhysics.name, EulerPhysics)  # world.engine name, factory() -> Physics
