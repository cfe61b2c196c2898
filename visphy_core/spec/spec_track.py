"""The spec track: the model's scene specification S, simulated by visphy's own physics and rendered
by the engine's trusted reference program, scored like the program's own video.

A model can understand the physics and still fail to code it (or code it well from a wrong reading
of the frames). The spec track separates the two: S is data, never code, so it runs through the same
simulator as the ground truth (the one its ``world.engine`` names) under the scene's clip contract
(world step, frame count, fps, canvas, camera, render settings all taken from the ground truth), and
the engine's reference program replays the result. Its scores carry the ``spec.`` prefix
(``spec.psnr``, ``spec.track_pos_err``…).

What S may set: gravity (and in 2D the pixels-per-metre scale), the bodies (ids, categories,
colours, shapes, poses, velocities, materials) and the contact table. Everything else is the
ground truth's. A merged spec that fails the simulator's own validation, or a simulation that
fails, is a spec-track failure with a reason (``spec_track.error``), never a silent gap.
"""

from __future__ import annotations

import copy
import dataclasses
from typing import Any

import numpy as np

from visphy_core.api.scene import Scene

PROFILE = "spec-track"
MAX_BODIES = 64          # S is untrusted data: bound the simulation's size
MAX_SPEED = 1e4          # m/s (2D: px/s / px_per_m): beyond this a body is not physics


class SpecTrackError(ValueError):
    """S cannot be simulated (invalid after merging, or the simulation failed)."""


def merged_spec(gt: dict, reply: dict) -> dict:
    """The full scene spec the spec track simulates: the ground truth's world, camera, render
    and clip contract with S's gravity, scale, bodies and contacts."""
    if not isinstance(reply, dict) or not isinstance(reply.get("bodies"), list):
        raise SpecTrackError("S has no bodies")
    if len(reply["bodies"]) > MAX_BODIES:
        raise SpecTrackError(f"S has {len(reply['bodies'])} bodies (at most {MAX_BODIES})")
    spec = copy.deepcopy(gt)
    world = reply.get("world") or {}
    spec.pop("splits", None)  # added by the dataset writer, not part of the simulated spec
    spec["world"]["profile"] = PROFILE
    if "gravity_m_s2" in world:
        spec["world"]["gravity_m_s2"] = [float(v) for v in world["gravity_m_s2"]]
    ppm = (world.get("units") or {}).get("px_per_m")
    if gt["dim"] == "2d" and ppm is not None:
        spec["world"]["units"]["px_per_m"] = float(ppm)
    spec["bodies"] = copy.deepcopy(reply["bodies"])
    contacts = copy.deepcopy(reply.get("contacts") or {})
    spec["contacts"] = {"default": contacts.get("default", gt["contacts"]["default"]),
                        "pairs": contacts.get("pairs", [])}
    _check_speeds(spec)
    try:
        if gt["dim"] == "2d":
            from visphy_core.spec.spec2d import validate_spec

            validate_spec(spec)
        else:
            from visphy_core.spec.spec3d import validate_spec_3d

            validate_spec_3d(spec)
    except (ValueError, KeyError, TypeError) as exc:
        raise SpecTrackError(str(exc).splitlines()[0][:300]) from None
    return spec


def _check_speeds(spec: dict) -> None:
    ppm = float(spec["world"].get("units", {}).get("px_per_m", 1.0) or 1.0)
    for b in spec["bodies"]:
        v = b.get("velocity") or {}
        if "linear_m_s" in v:
            speed = float(np.linalg.norm(v["linear_m_s"]))
        else:
            speed = float(np.hypot(v.get("vx_px_s", 0.0), v.get("vy_px_s", 0.0))) / ppm
        if not np.isfinite(speed) or speed > MAX_SPEED:
            raise SpecTrackError(f"body {b.get('id')!r}: initial speed {speed:g} m/s is not "
                                 "physical")


def simulate(spec: dict, timeout_s: float = 60.0):
    """The rollout of a merged spec by the simulator registered for its ``world.engine``
    (`visphy_core.api.physics`)."""
    from visphy_core.api.physics import physics_for

    try:
        physics = physics_for(spec)
    except KeyError as exc:
        raise SpecTrackError(str(exc.args[0]) if exc.args else str(exc)) from None
    try:
        rollout = physics.simulate(spec, timeout_s=timeout_s)
    except Exception as exc:  # noqa: BLE001 - any simulator failure is S's failure here
        raise SpecTrackError(f"simulation failed: {str(exc).splitlines()[0][:300]}") from None
    if not np.all(np.isfinite(rollout.frame_poses)):
        raise SpecTrackError("simulation diverged (non-finite poses)")
    return rollout


def spec_scene(scene: Scene, reply: dict, timeout_s: float = 60.0) -> Scene:
    """``scene`` with S's physics: its spec is the merged spec and its trajectory the rollout
    of S, so ``engine.program_from_spec`` replays S exactly like it replays the ground truth."""
    if scene.spec is None:
        raise SpecTrackError("the scene has no ground-truth spec (only generated benchmarks do)")
    return simulated_scene(scene, merged_spec(scene.spec, reply), timeout_s=timeout_s)


def simulated_scene(scene: Scene, spec: dict, timeout_s: float = 60.0,
                    rollout: Any = None) -> Scene:
    """``scene`` with ``spec`` (a full, valid scene spec) as its spec and the rollout of
    ``spec`` as its trajectory (``rollout``: that simulation, when the caller already ran it)."""
    rollout = simulate(spec, timeout_s=timeout_s) if rollout is None else rollout
    trajectory: dict[str, Any] = {
        "body_ids": np.array(rollout.body_ids, dtype=str),
        "frame_poses": rollout.frame_poses, "frame_steps": rollout.frame_steps,
        "frame_times_s": rollout.frame_times_s}
    out = dataclasses.replace(scene)
    out.__dict__["spec"] = spec             # cached_property slots of the frozen dataclass
    out.__dict__["trajectory"] = trajectory
    return out
