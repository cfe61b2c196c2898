"""Engine ``threejs``: HTML + three.js (r160 UMD global ``THREE`` or r187 ES module ``three``)
with ``CANNON`` (cannon.js 0.6.2) or ``cannon-es``, run in headless Chromium in virtual time.

`replay_html_3d` fills ``templates/threejs_replay_3d.html`` with a scene's replay payload: the
engine's reference program for 3D scenes, and the page the generated benchmark renders its 3D
ground truth with (`visphy_plugins.datasets.visphybench.render3d`), so the two are one page.
"""

from __future__ import annotations

from pathlib import Path

from visphy_core.api.engine import Program
from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.scene import Scene
from visphy_core.api.spec import fill, payload_from, replay_payload
from visphy_plugins.engines.browser_base import BrowserEngine
from visphy_plugins.engines.native import native_payload

TEMPLATES = Path(__file__).with_name("templates")

INSTRUCTIONS_2D = """
Write a single self-contained HTML file. The page provides the global `THREE` (three.js r160) and
the global `CANNON` (cannon.js 0.6.2 API); do not load any library from the network. Use an
orthographic camera looking at the x-y plane, one canvas the size of the video, rigid bodies that
match the first frame's layout, and initial velocities or impulses consistent with the later frame.
Step a physics simulation with a fixed time step inside a requestAnimationFrame loop, and call
`setupRecording(renderer.domElement, durationMs)` once to record a finite clip.
""".strip()

INSTRUCTIONS_3D = """
Write a single self-contained HTML file. The page provides the global `THREE` (three.js r160) and
the global `CANNON` (cannon.js 0.6.2 API); do not load any library from the network. Use a fixed
perspective camera matching the view in the images, a rigid-body simulation stepped with a fixed
time step inside a requestAnimationFrame loop, and call `setupRecording(renderer.domElement,
durationMs)` once to record a finite clip.
""".strip()


def replay_html_3d(spec: dict, frame_poses, fps: float, n_frames: int) -> str:
    """The self-contained 3D replay page (loads /vendor/three.min.js, calls setupRecording);
    ``frame_poses`` in the order of ``spec["bodies"]``."""
    payload = payload_from(spec, [b["id"] for b in spec["bodies"]], frame_poses, fps=fps,
                           n_frames=n_frames)
    return fill((TEMPLATES / "threejs_replay_3d.html").read_text(), payload)


class ThreeJsEngine(BrowserEngine):
    name = "threejs"
    version = "3"  # 3: flags (library_substituted, no_recording_call, canvas_resized, partial_clip)
    supports_3d = True
    preload = ("three.min.js", "cannon.min.js")
    paper_retry = (0.979, 0.990)  # the paper's success: first attempt, after one retry

    def instructions(self, dim: str) -> str:
        return INSTRUCTIONS_3D if dim == "3d" else INSTRUCTIONS_2D

    def program_from_spec(self, scene: Scene) -> Program:
        spec, traj = scene.spec, scene.trajectory
        if spec is None or traj is None:
            raise ValueError(f"{scene.scene_id}: the reference program needs the scene's spec and "
                             "trajectory (generated benchmarks have both)")
        if scene.dim == "3d":
            html = replay_html_3d(spec, traj["frame_poses"], scene.clip.fps, scene.clip.n_frames)
            return Program(language=self.language, source=html, spec=spec)
        html = fill((TEMPLATES / "threejs_replay_2d.html").read_text(), replay_payload(scene))
        return Program(language=self.language, source=html, spec=spec)

    def native_program_from_spec(self, scene: Scene) -> Program:
        """2D: meshes (CircleGeometry, PlaneGeometry, ShapeGeometry) under an anti-aliased
        renderer (`visphy_plugins.engines.native`). 3D: the exact reference program, which
        already draws three.js meshes with the ground truth's own renderer and multisampling."""
        if scene.dim == "3d":
            return self.program_from_spec(scene)
        html = fill((TEMPLATES / "threejs_native_2d.html").read_text(), native_payload(scene))
        return Program(language=self.language, source=html, spec=scene.spec)


@hookimpl
def visphy_register_engines(register):
    register("threejs", ThreeJsEngine)
