"""Ground-truth rollouts of 3D scene specs with cannon-es 0.20.0, run by Node.js.

Why Node: the 3D subset of VisPhyBench is Three.js + Cannon, and the reference rollout should come
from the very library a model's program uses in the browser. `sim3d.mjs` imports the vendored
``cannon-es/dist/cannon-es.js`` (the file the pages load as ``/vendor/cannon-es.js``), builds
the world from the spec (fixed ``world.step(dt)``, no substeps, no sleeping, an explicit
ContactMaterial per body pair, a static plane floor) and returns every body's pose after every
step. Frame k of the clip is the state after ``first_frame_after_steps + steps_per_frame * k``
steps (frame 0 = the initial state; 4 steps of 1/60 s per frame at 15 fps).

The integrator is cannon's semi-implicit Euler: a body falling from rest is at
``y0 - g dt² n(n+1)/2`` after n steps, i.e. ``g dt t / 2`` (4.1 cm at t = 0.5 s) below the
continuous ``y0 - g t²/2``; the ground truth is the discrete rollout.
"""

from __future__ import annotations

import base64
import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np

from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.physics import Physics, Rollout, trajectory_digest
from visphy_core.api.spec import body_mass

SIM_SCRIPT = Path(__file__).with_name("sim3d.mjs")
POSE_LAYOUT = ("x_m", "y_m", "z_m", "qx", "qy", "qz", "qw")


class NodeUnavailable(RuntimeError):
    """Node.js is not installed, so cannon-es cannot run."""


#: The one rollout digest (`visphy_core.api.physics.trajectory_digest`), by its 3D callers' name.
trajectory_digest_3d = trajectory_digest


def find_node() -> str:
    path = os.environ.get("VISPHY_NODE") or shutil.which("node") or shutil.which("nodejs")
    if not path:
        raise NodeUnavailable("Node.js not found: install nodejs (Debian `apt-get install nodejs`, "
                              "done by `make setup`) or set VISPHY_NODE to simulate 3D scenes")
    return path


def cannon_es_path() -> Path:
    """The vendored cannon-es ES module: $VISPHY_CANNON_ES, else the engines' asset cache."""
    env = os.environ.get("VISPHY_CANNON_ES")
    if env:
        path = Path(env)
    else:
        from visphy_core.api.sandbox import require_assets

        path = require_assets() / "cannon-es" / "dist" / "cannon-es.js"
    if not path.is_file():
        raise FileNotFoundError(f"cannon-es not found at {path}: run `python -m visphy_core setup`")
    return path


def total_steps_3d(spec: dict) -> int:
    """Number of cannon steps needed to reach the last frame."""
    w = spec["world"]
    return w["steps_per_frame"] * (w["n_frames"] - 1) + w["first_frame_after_steps"]


def _decode(b64: str, dtype: str, shape: tuple[int, ...]) -> np.ndarray:
    return np.frombuffer(base64.b64decode(b64), dtype=dtype).reshape(shape).copy()


def simulate_3d(spec: dict, n_steps: int | None = None, timeout_s: float = 120.0) -> Rollout:
    """Simulate a validated 3D spec with cannon-es and record every body's pose after every step.

    `n_steps` defaults to the steps the clip needs; frames beyond a shorter run are omitted.
    """
    node = find_node()
    n_steps = total_steps_3d(spec) if n_steps is None else int(n_steps)
    payload = json.dumps({"spec": spec, "masses": [body_mass(b) for b in spec["bodies"]],
                          "n_steps": n_steps}, separators=(",", ":"))
    env = dict(os.environ, NODE_NO_WARNINGS="1")
    try:
        proc = subprocess.run([node, str(SIM_SCRIPT), str(cannon_es_path())], input=payload,
                              capture_output=True, text=True, timeout=timeout_s, env=env)
    except subprocess.TimeoutExpired:
        raise RuntimeError(f"{spec.get('scene_id')}: cannon-es simulation exceeded "
                           f"{timeout_s:g} s") from None
    if proc.returncode != 0:
        lines = [ln for ln in proc.stderr.strip().splitlines() if ln.strip()]
        tail = " | ".join(lines[-3:]) or f"exit code {proc.returncode}"
        raise RuntimeError(f"{spec.get('scene_id')}: cannon-es simulation failed: {tail}")
    out = json.loads(proc.stdout)
    ids = tuple(out["body_ids"])
    nb = len(ids)
    steps = _decode(out["step_poses"], "<f8", (n_steps + 1, nb, 7))
    vels = _decode(out["step_velocities"], "<f8", (n_steps + 1, nb, 6))
    touching = _decode(out["step_touching"], "u1", (n_steps + 1, nb)).astype(bool)
    w = spec["world"]
    dt = float(w["dt_s"])
    first, spf = w["first_frame_after_steps"], w["steps_per_frame"]
    frame_steps = np.array([first + spf * k for k in range(w["n_frames"])
                            if first + spf * k <= n_steps], dtype=np.int64)
    events = [{"t_s": round(e["step"] * dt, 9), "step": int(e["step"]), "type": e["type"],
               "a": e["a"], "b": e["b"], "normal_speed_m_s": round(float(e["normal_speed_m_s"]), 6)}
              for e in out["events"]]
    return Rollout(body_ids=ids, frame_poses=steps[frame_steps].copy(), step_poses=steps,
                     frame_steps=frame_steps, frame_times_s=frame_steps.astype(np.float64) * dt,
                     events=events, step_velocities=vels, step_touching=touching,
                     pair_stats=out["pair_stats"],
                     initial_penetration_m={k: float(v)
                                            for k, v in out["initial_penetration_m"].items()})


class CannonPhysics(Physics):
    """``world.engine = "cannon-es"``: the 3D benchmark's simulator, run by Node.js."""

    name = "cannon-es"
    dim = "3d"

    def simulate(self, spec: dict, timeout_s: float = 60.0) -> Rollout:
        return simulate_3d(spec, timeout_s=timeout_s)


@hookimpl
def visphy_register_physics(register):
    register(CannonPhysics.name, CannonPhysics)
