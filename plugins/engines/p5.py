"""Engine ``p5``: HTML + p5.js 1.11 (drawing) with matter-js 0.20 (physics; cannon.js 0.6.2's
``CANNON`` is there too), run in headless Chromium in virtual time.

p5 drives ``draw()`` through ``requestAnimationFrame`` and reads ``performance.now()``, so under the
sandbox's virtual clock ``frameCount``, ``deltaTime``, ``frameRate()`` and ``millis()`` all follow
virtual time: one ``draw()`` per animation tick (≈60 Hz), the first during start-up at t = 0.
Global mode (``setup()``/``draw()``/``preload()`` on ``window``, started by p5 on the load event)
and instance mode (``new p5(sketch)``) both work; the capture waits until every sketch has
finished ``preload()`` and ``setup()``. 2D only: a 3D scene has no p5 reference program.
"""

from __future__ import annotations

from visphy_core.api.engine import Program
from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.scene import Scene
from visphy_plugins.engines.browser_base import BrowserEngine, fill_template, replay_payload_2d
from visphy_plugins.engines.native import native_payload

INSTRUCTIONS_2D = """
Write a single self-contained HTML file that uses p5.js (version 1.11, global `p5`) to draw and
matter-js (version 0.20, global `Matter`) to simulate; the page provides both (and cannon.js 0.6.2
as the global `CANNON`), so do not load any library from the network. Use p5's `setup()` and
`draw()` (global or instance mode): in `setup()` create exactly one canvas the size of the video
with `createCanvas(width, height)`, and build rigid bodies that match the first frame's layout,
with initial velocities or impulses consistent with the later frame. p5 only draws: the physics
engine moves the bodies. Advance it by a fixed time step once per `draw()` (for example
`Matter.Engine.update(engine, 1000 / 60)`) and draw every body at its simulated position and angle
in the flat colours of the images, with `noStroke()`. Call `setupRecording(canvas.elt,
durationMs)` once (with the canvas returned by `createCanvas`) to record a finite clip.
""".strip()

INSTRUCTIONS_3D = """
The p5 engine draws 2D scenes only. Write a single self-contained HTML file that uses p5.js
(global `p5`) to draw and matter-js (global `Matter`) to simulate a 2D side view of the scene: one
canvas the size of the video from `createCanvas`, a fixed physics time step once per `draw()`,
and `setupRecording(canvas.elt, durationMs)` called once to record a finite clip.
""".strip()

#: Registers every p5 sketch (global or instance mode) and tells the sandbox when all of them
#: have finished preload() and setup(): asynchronous loading happens outside virtual time.
P5_READY = """<script>
(function () {
  if (!window.p5 || !window.__visphy) return;
  var sketches = [], globalSketch = false;
  // 'init' hooks run in every p5 constructor; in global mode `this` is window.
  p5.prototype.registerMethod('init', function () {
    if (this === window) globalSketch = true; else sketches.push(this);
  });
  // p5 paces draw() from the end of setup(), so its first draw() would come one tick after
  // t = 0 and frame 0 would show only what setup() drew. As in a browser, where the first
  // animation frame follows setup() by about one frame period, date setup back by one period:
  // draw() #1 then runs at t = 0 (with deltaTime = one period), draw() #n at (n - 1) ticks.
  p5.prototype.registerMethod('afterSetup', function () {
    var s = this === window ? p5.instance : this;
    if (!s || !s._targetFrameRate) return;
    var period = 1000 / s._targetFrameRate, now = window.performance.now();
    s._lastTargetFrameTime = now - period;
    s._lastRealFrameTime = now - period;
  });
  window.__visphy.addReadyCheck(function () {
    var wantsGlobal = typeof window.setup === 'function' || typeof window.draw === 'function';
    if (globalSketch || (wantsGlobal && sketches.length === 0)) {
      // global mode starts once the page has loaded, if setup() or draw() is defined
      if (!p5.instance || !p5.instance._setupDone) return false;
    }
    return sketches.every(function (s) { return s._setupDone; });
  });
})();
</script>"""


class P5Engine(BrowserEngine):
    name = "p5"
    version = "2"  # 2: flags (library_substituted, no_recording_call, canvas_resized, partial_clip)
    supports_3d = False
    preload = ("p5.min.js", "matter.min.js", "cannon.min.js")
    paper_retry = (0.853, 0.979)  # the paper's success: first attempt, after one retry

    def instructions(self, dim: str) -> str:
        return INSTRUCTIONS_3D if dim == "3d" else INSTRUCTIONS_2D

    def head_extras(self, dim: str) -> list[str]:
        return [P5_READY]

    def program_from_spec(self, scene: Scene) -> Program:
        payload = replay_payload_2d(scene, self.name)
        return Program(language=self.language, source=fill_template("p5_replay_2d.html", payload),
                       spec=scene.spec)

    def native_program_from_spec(self, scene: Scene) -> Program:
        """The same replay drawn with p5's circle()/rect()/beginShape() and its default
        smoothing (`visphy_plugins.engines.native`); 2D only."""
        replay_payload_2d(scene, self.name)  # NotImplementedError for a 3D scene
        return Program(language=self.language,
                       source=fill_template("p5_native_2d.html", native_payload(scene)),
                       spec=scene.spec)


@hookimpl
def visphy_register_engines(register):
    register("p5", P5Engine)
