"""Engine ``svg``: an HTML page with an inline ``<svg>`` animated by script (requestAnimationFrame,
setInterval) or declaratively (SMIL ``<animate>``, CSS animations), captured frame by frame by
screenshots of the viewport in headless Chromium, in virtual time.

There is no physics engine (docs/running.md: scripted animation): the program integrates the motion
itself. Timers and animation frames follow the sandbox's virtual clock; SMIL timelines are paused
and seeked with ``svg.setCurrentTime(t)``, CSS and Web Animations with ``currentTime``, before each
capture, so frame k always shows t = k / fps. 2D only.
"""

from __future__ import annotations

from visphy_core.api.engine import FailureClass, Program, ProgramRejected
from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.scene import Scene
from visphy_plugins.engines.browser_base import BrowserEngine, fill_template, replay_payload_2d
from visphy_plugins.engines.native import native_payload

INSTRUCTIONS_2D = """
Write a single self-contained HTML file whose body holds one inline `<svg>` element the size of
the video (`width`, `height` and `viewBox` in pixels, y pointing down) at the top-left corner of
the page, on a page without margins. No physics engine is available: animate the scene with
JavaScript (`requestAnimationFrame` or `setInterval`) that integrates the motion itself with a
fixed time step (gravity, velocities, collisions and bounces as you judge them from the images),
or with SMIL `<animate>` / `<animateTransform>` elements. Match the first frame's layout with one
element per object (`<circle>`, `<rect>`, `<polygon>`) in the flat colours of the images, no
strokes, and make the motion consistent with the later frame. Start the animation at page load;
everything in the viewport is recorded. You may call `setupRecording(svgElement, durationMs)`
once to state the clip length. Do not load anything from the network.
""".strip()

INSTRUCTIONS_3D = """
The SVG engine draws 2D scenes only. Write a single self-contained HTML file with one inline
`<svg>` the size of the video showing a 2D projection of the scene from the camera of the images,
animated by JavaScript (`requestAnimationFrame` or `setInterval`) that integrates the motion with
a fixed time step; no physics engine is available and nothing may be loaded from the network.
""".strip()

#: Pages get no default margins (a program's own CSS still wins).
RESET_CSS = ("<style>html, body { margin: 0; padding: 0; overflow: hidden; }"
             "body > svg:first-of-type { display: block; }</style>")


class SvgEngine(BrowserEngine):
    name = "svg"
    version = "2"  # 2: flags (library_substituted, partial_clip), blocked requests named
    supports_3d = False
    preload = ()
    capture = "screenshot"
    #: The instructions make setupRecording optional: capture is the viewport in virtual time,
    #: so a page that never calls it is not flagged ``no_recording_call``.
    expects_recording_call = False

    def instructions(self, dim: str) -> str:
        return INSTRUCTIONS_3D if dim == "3d" else INSTRUCTIONS_2D

    def head_extras(self, dim: str) -> list[str]:
        return [RESET_CSS]

    def validate(self, program: Program) -> None:
        # Declarative pages are programs too: an <svg> animated by SMIL or CSS needs no <script>.
        low = program.source.lower()
        if "<svg" not in low and "<script" not in low:
            raise ProgramRejected(FailureClass.NO_CODE, "the HTML program has neither <svg> nor "
                                  "<script>")

    def program_from_spec(self, scene: Scene) -> Program:
        payload = replay_payload_2d(scene, self.name)
        return Program(language=self.language, source=fill_template("svg_replay_2d.html", payload),
                       spec=scene.spec)

    def native_program_from_spec(self, scene: Scene) -> Program:
        """The same replay as <circle>/<rect>/<polygon> elements with the browser's default
        (anti-aliased) shape rendering (`visphy_plugins.engines.native`); 2D only."""
        replay_payload_2d(scene, self.name)  # NotImplementedError for a 3D scene
        return Program(language=self.language,
                       source=fill_template("svg_native_2d.html", native_payload(scene)),
                       spec=scene.spec)


@hookimpl
def visphy_register_engines(register):
    register("svg", SvgEngine)
