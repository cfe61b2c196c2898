"""Well-formed model replies for tests and the fake provider servers: analysis, a ```json scene
spec S and a program in the language of the engine the prompt asks for.

Two kinds of program:

* generic (`GENERIC_PROGRAMS`): a red disc falling on a white background, one valid program per
  engine (a canvas page for the browser engines, a Manim scene, a bpy script), rendering on any
  scene of any size: what the fakes answer when they do not know the scene;
* the scene's own (`SceneBook`): when the fakes are given the benchmark's scenes, the request's
  first key frame names the scene, and the reply carries the asked engine's reference program
  (`Engine.program_from_spec`, what the oracle model answers), its analysis and its spec.

`engine_of` tells the engine from the prompt: each engine's instructions (`Engine.instructions`)
are part of the prompt text, word for word.
"""


from __future__ import annotations

import base64
import hashlib
import io
import json
import threading
from functools import lru_cache
from typing import Any, Iterable, Iterator

import numpy as np

ANALYSIS = ("A red ball falls from rest under gravity. It accelerates downwards, hits the floor "
            "and bounces slightly before it settles. Nothing else moves.")

SPEC_2D = {"schema": "visphy-scene/1", "dim": "2d",
           "world": {"gravity_m_s2": [0.0, -9.8], "units": {"px_per_m": 6.0}},
           "bodies": [{"id": "red_ball", "category": "circle", "dynamic": True,
                       "color_rgb": [243, 79, 70], "shape": {"type": "circle", "radius_px": 8},
                       "pose": {"x_px": 32.0, "y_px": 50.0, "angle_rad": 0.0},
                       "velocity": {"vx_px_s": 0.0, "vy_px_s": 0.0, "omega_rad_s": 0.0},
                       "material": {"density_kg_m2": 0.25, "friction": 0.5,
                                    "restitution": 0.2}}]}

HTML_PROGRAM = """<html><body style="margin:0;background:white">
<canvas id="c" width="64" height="64"></canvas>
<script>
const cv = document.getElementById('c'), ctx = cv.getContext('2d');
let y = 8, v = 0;
function draw() {
  v += 0.15; y = Math.min(cv.height - 8, y + v);
  ctx.fillStyle = '#ffffff'; ctx.fillRect(0, 0, cv.width, cv.height);
  ctx.fillStyle = '#f34f46'; ctx.beginPath(); ctx.arc(cv.width / 2, y, 8, 0, 2 * Math.PI);
  ctx.fill();
  requestAnimationFrame(draw);
}
setupRecording(cv, 3400);
requestAnimationFrame(draw);
</script></body></html>"""

MANIM_PROGRAM = """from manim import *

class GeneratedScene(Scene):
    def construct(self):
        ball = Circle(radius=0.5, color=RED, fill_opacity=1).shift(UP * 2.5)
        self.add(ball)
        self.play(ball.animate.shift(DOWN * 5), run_time=3, rate_func=rate_functions.ease_in_quad)
        self.wait(0.4)
"""

BLENDER_PROGRAM = """import math

import bpy

scene = bpy.context.scene
W, H = scene.render.resolution_x, scene.render.resolution_y
fps = scene.render.fps
scene.world = bpy.data.worlds.new("w")
scene.world.color = (1, 1, 1)
scene.display.shading.light = 'FLAT'
scene.display.shading.color_type = 'MATERIAL'
scene.display.render_aa = 'OFF'

cam_data = bpy.data.cameras.new("cam")
cam_data.type = 'ORTHO'
cam_data.ortho_scale = max(W, H)
cam = bpy.data.objects.new("cam", cam_data)
cam.location = (W / 2, H / 2, 100)
scene.collection.objects.link(cam)
scene.camera = cam

r = max(2.0, min(W, H) / 8)
mesh = bpy.data.meshes.new("ball")
mesh.from_pydata([(r * math.cos(2 * math.pi * i / 48), r * math.sin(2 * math.pi * i / 48), 0)
                  for i in range(48)], [], [tuple(range(48))])
ball = bpy.data.objects.new("ball", mesh)
scene.collection.objects.link(ball)
mat = bpy.data.materials.new("red")
mat.diffuse_color = (0.9, 0.08, 0.06, 1)
ball.data.materials.append(mat)

g = 9.8 * H / 3.0
y, v, dt = H - r, 0.0, 1.0 / fps
for f in range(scene.frame_start, scene.frame_end + 1):
    ball.location = (W / 2, y, 0)
    ball.keyframe_insert("location", frame=f)
    v -= g * dt
    y = max(r, y + v * dt)
"""

#: engine name -> (fence language, a generic program that renders on any scene)
GENERIC_PROGRAMS = {"threejs": ("html", HTML_PROGRAM), "p5": ("html", HTML_PROGRAM),
                    "svg": ("html", HTML_PROGRAM), "manim": ("python", MANIM_PROGRAM),
                    "blender": ("python", BLENDER_PROGRAM)}


def reply(language: str = "html", spec: dict | None = None, program: str | None = None,
          analysis: str = ANALYSIS) -> str:
    """A complete reply in the format every model is asked for: the generic program of
    ``language`` (``html``: the canvas page; ``python``: the Manim scene) unless ``program``
    is given."""
    if program is None:
        program = HTML_PROGRAM if language == "html" else MANIM_PROGRAM
    return (f"{analysis}\n\n```json\n{json.dumps(spec or SPEC_2D, indent=1)}\n```\n\n"
            f"```{language}\n{program}\n```\n")


def _describe(spec: dict) -> str:
    from visphy_core.api.calls import describe_spec

    return describe_spec(spec) or ANALYSIS


def engine_reply(engine: str) -> str:
    """The generic reply for ``engine`` (a name in `GENERIC_PROGRAMS`)."""
    language, program = GENERIC_PROGRAMS[engine]
    return reply(language, program=program)


# ---------------------------------------------------------------------------- reading requests
def strings(body: Any) -> Iterator[str]:
    """Every string in a decoded request body, depth first (any provider's wire format)."""
    if isinstance(body, str):
        yield body
    elif isinstance(body, dict):
        for value in body.values():
            yield from strings(value)
    elif isinstance(body, list):
        for item in body:
            yield from strings(item)


_PNG_B64 = "iVBORw0KGgo"  # base64 of the PNG signature


def first_png(body: Any) -> bytes | None:
    """The first base64 PNG in a request body (an OpenAI data URL, an Anthropic ``image``
    source, a Gemini ``inlineData``), or None."""
    for text in strings(body):
        data = text.split(",", 1)[1] if text.startswith("data:image/png;base64,") else text
        if data.startswith(_PNG_B64):
            data = data.replace("-", "+").replace("_", "/")
            return base64.b64decode(data + "=" * (-len(data) % 4))
    return None


@lru_cache(maxsize=1)
def _engine_instructions() -> tuple[tuple[str, str], ...]:
    from visphy_plugins.engines.blender import BlenderEngine
    from visphy_plugins.engines.manim import ManimEngine
    from visphy_plugins.engines.p5 import P5Engine
    from visphy_plugins.engines.svg import SvgEngine
    from visphy_plugins.engines.threejs import ThreeJsEngine

    pairs = []
    for cls in (BlenderEngine, ManimEngine, P5Engine, SvgEngine, ThreeJsEngine):
        engine = cls()
        for dim in ("2d", "3d"):
            pairs.append((engine.name, engine.instructions(dim)))
    return tuple(pairs)


def engine_of(body: Any) -> str | None:
    """The engine whose instructions the request's prompt holds, or None (not a program
    request, or an engine this module does not know)."""
    texts = [t for t in strings(body) if not t.startswith((_PNG_B64, "data:"))]
    for name, instructions in _engine_instructions():
        if any(instructions in t for t in texts):
            return name
    return None


def _pixels_key(png: bytes) -> str:
    from PIL import Image

    with Image.open(io.BytesIO(png)) as img:
        rgb = np.asarray(img.convert("RGB"))
    return hashlib.sha256(repr(rgb.shape).encode() + rgb.tobytes()).hexdigest()


class SceneBook:
    """Scenes told apart by their first key frame: the image a request starts with names the
    scene (pixel-exact, whatever the PNG encoder), and `reply_for` answers the asked engine's
    reference program for it."""

    def __init__(self, scenes: Iterable[Any], frames: tuple[int, ...] = (1,)):
        self.scenes = list(scenes)
        self.frames = frames
        self._index: dict[str, Any] | None = None
        self._lock = threading.Lock()

    def _build(self) -> dict[str, Any]:
        from visphy_core.api.media import png_bytes

        with self._lock:
            if self._index is None:
                index = {}
                for scene in self.scenes:
                    for k in self.frames:
                        index.setdefault(_pixels_key(png_bytes(scene.key_frame(k))), scene)
                self._index = index
        return self._index

    def scene_of(self, body: Any) -> Any | None:
        png = first_png(body)
        return None if png is None else self._build().get(_pixels_key(png))

    def reply_for(self, body: Any, engine: str) -> str | None:
        """The reference-program reply of ``engine`` for the request's scene, or None (no
        known scene, or no reference program for it on that engine)."""
        scene = self.scene_of(body)
        if scene is None:
            return None
        try:
            program = _engine(engine).program_from_spec(scene)
        except (ValueError, NotImplementedError):
            return None
        spec = scene.spec or SPEC_2D
        return reply(program.language, spec=spec, program=program.source,
                     analysis=_describe(spec))


def _engine(name: str) -> Any:
    from visphy_plugins.engines.blender import BlenderEngine
    from visphy_plugins.engines.manim import ManimEngine
    from visphy_plugins.engines.p5 import P5Engine
    from visphy_plugins.engines.svg import SvgEngine
    from visphy_plugins.engines.threejs import ThreeJsEngine

    classes = {"blender": BlenderEngine, "manim": ManimEngine, "p5": P5Engine,
               "svg": SvgEngine, "threejs": ThreeJsEngine}
    return classes[name]()


def program_reply(body: Any, book: SceneBook | None = None) -> str:
    """What a fake provider answers a program request: the scene's reference program in the
    engine the prompt asks for when ``book`` knows the scene, else that engine's generic
    program (the browser page when the prompt names no known engine)."""
    engine = engine_of(body)
    if engine is None:
        return reply("html")
    if book is not None:
        text = book.reply_for(body, engine)
        if text is not None:
            return text
    return engine_reply(engine)
