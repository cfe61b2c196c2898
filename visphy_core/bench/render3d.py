"""The reference clip of a 3D scene: the ground-truth poses replayed by three.js in Chromium.

`replay_html_3d` fills ``visphy_core/bench/threejs_replay_3d.html`` with a JSON payload
(camera, lights, floor, bodies' shapes and colours, per-frame poses); it is a pure function of
(spec, poses, fps, n_frames), and the threejs engine's reference program for 3D scenes is the
same page. `render_clip_3d` renders it in the sandbox's virtual time (frame k captured at
k / fps s, animation ticks every 1/60 s): perspective camera from the spec, Lambert materials
under a fixed hemisphere + directional light (with shadows when ``render.shadows``), grey floor,
white sky, no antialiasing, pixel ratio 1. SwiftShader rendering is deterministic, so the same
inputs give the same frames.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

def _template_path() -> Path:
    """visphy_core/bench/threejs_replay_3d.html: the replay page of the ground truth (the
    threejs engine's reference program for 3D scenes uses it too)."""
    return Path(__file__).with_name("threejs_replay_3d.html")


def _round(v: float, nd: int) -> float:
    return round(float(v), nd) + 0.0


def replay_payload_3d(spec: dict, frame_poses, fps: float, n_frames: int) -> dict:
    """The JSON the replay page reads (poses rounded to 1 µm and 1e-7)."""
    poses = np.asarray(frame_poses, dtype=np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (len(spec["bodies"]), 7):
        raise ValueError(f"{spec.get('scene_id')}: frame_poses shape {poses.shape} is not "
                         f"(frames, {len(spec['bodies'])}, 7)")
    cam, render, floor = spec["camera"], spec["render"], spec["world"]["floor"]
    return {
        "width": int(cam["width"]), "height": int(cam["height"]), "fps": float(fps),
        "n_frames": int(n_frames),
        "camera": {"fov_deg": float(cam["fov_deg"]), "near": float(cam.get("near", 0.1)),
                   "far": float(cam.get("far", 100.0)), "position": list(cam["position"]),
                   "look_at": list(cam["look_at"]), "up": list(cam.get("up", [0.0, 1.0, 0.0]))},
        "background_rgb": list(render["background_rgb"]),
        "shadows": bool(render.get("shadows", False)),
        "lighting": {"hemisphere": render["lighting"]["hemisphere"],
                     "directional": render["lighting"]["directional"]},
        "floor": {"y": float(floor["y"]), "color_rgb": list(floor["color_rgb"]),
                  "size_m": float(floor.get("size_m", 60.0))},
        "bodies": [{"id": b["id"], "color_rgb": list(b["color_rgb"]), "shape": b["shape"]}
                   for b in spec["bodies"]],
        "frame_poses": [[[_round(v, 6) for v in p[:3]] + [_round(v, 7) for v in p[3:]]
                         for p in frame] for frame in poses],
    }


def replay_html_3d(spec: dict, frame_poses, fps: float, n_frames: int) -> str:
    """The self-contained replay page (loads /vendor/three.min.js, calls setupRecording)."""
    payload = replay_payload_3d(spec, frame_poses, fps, n_frames)
    html = _template_path().read_text()
    return html.replace("__SCENE_JSON__", json.dumps(payload, separators=(",", ":")))


def render_clip_3d(spec: dict, frame_poses, pool, timeout_s: float = 180.0) -> np.ndarray:
    """Render the reference clip (N×H×W×3 uint8, N = len(frame_poses)) with a BrowserPool."""
    from visphy_core.js_assets import VendorFiles

    poses = np.asarray(frame_poses, dtype=np.float64)
    fps = float(spec["world"]["video_fps"])
    n = len(poses)
    width, height = int(spec["camera"]["width"]), int(spec["camera"]["height"])
    html = replay_html_3d(spec, poses, fps, n)
    cap = pool.render_page(html, VendorFiles(), [k / fps * 1000.0 for k in range(n)],
                           width=width, height=height, timeout_s=timeout_s, seed=0,
                           tick_ms=1000.0 / 60.0)
    sid = spec.get("scene_id")
    if cap.infra_error or cap.timed_out or cap.errors or cap.no_canvas:
        why = cap.infra_error or ("timed out" if cap.timed_out else None) or (
            cap.errors[0].splitlines()[0] if cap.errors else "no canvas")
        raise RuntimeError(f"{sid}: 3D replay failed to render: {why}")
    if len(cap.frames) != n:
        raise RuntimeError(f"{sid}: 3D replay gave {len(cap.frames)} frames, expected {n}")
    frames = np.stack(cap.frames)
    if frames.shape != (n, height, width, 3):
        raise RuntimeError(f"{sid}: 3D replay frames are {frames.shape}, expected "
                           f"{(n, height, width, 3)}")
    return frames
