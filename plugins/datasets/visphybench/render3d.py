"""The reference clip of a 3D scene: the ground-truth poses replayed by three.js in Chromium.

`visphy_plugins.engines.threejs.replay_html_3d` fills the threejs engine's 3D replay page with
a JSON payload (camera, lights, floor, bodies' shapes and colours, per-frame poses); it is a pure
function of (spec, poses, fps, n_frames), and the engine's reference program for 3D scenes is
the same page. `render_clip_3d` renders it in the sandbox's virtual time (frame k captured at
k / fps s, animation ticks every 1/60 s): the spec's fixed perspective camera, Lambert-shaded
colours under a hemisphere + directional light (shadow-mapped shadows only when
``render.shadows``; the generated scenes have none), translucent bodies (``opacity``) blended,
multisampled edges when ``render.antialias``, grey floor, white sky, pixel ratio 1. SwiftShader
rendering (its multisampling included) is deterministic, so the same
inputs give the same frames.
"""

from __future__ import annotations

import numpy as np

from visphy_plugins.engines.assets import BROWSER_ASSETS
from visphy_plugins.engines.threejs import replay_html_3d


def render_clip_3d(spec: dict, frame_poses, pool, timeout_s: float = 180.0) -> np.ndarray:
    """Render the reference clip (N×H×W×3 uint8, N = len(frame_poses)) with a BrowserPool."""
    from visphy_core.api.sandbox import VendorFiles

    poses = np.asarray(frame_poses, dtype=np.float64)
    fps = float(spec["world"]["video_fps"])
    n = len(poses)
    width, height = int(spec["camera"]["width"]), int(spec["camera"]["height"])
    html = replay_html_3d(spec, poses, fps, n)
    cap = pool.render_page(html, VendorFiles(BROWSER_ASSETS), [k / fps * 1000.0 for k in range(n)],
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
