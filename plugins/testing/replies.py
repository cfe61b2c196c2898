"""Well-formed model replies for tests: analysis, a ```json scene spec S and a program that
renders on any scene (a red disc falling on a white canvas of the contract's size)."""

from __future__ import annotations

import json

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


def reply(language: str = "html", spec: dict | None = None) -> str:
    """A complete reply in the format every model is asked for."""
    program = HTML_PROGRAM if language == "html" else MANIM_PROGRAM
    return (f"{ANALYSIS}\n\n```json\n{json.dumps(spec or SPEC_2D, indent=1)}\n```\n\n"
            f"```{language}\n{program}\n```\n")
