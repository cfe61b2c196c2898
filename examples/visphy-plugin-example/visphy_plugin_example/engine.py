"""Engine ``example_boxes``: a program is a list of boxes in free flight, drawn with numpy.

A reply's ```boxes block is JSON: ``{"background": [r, g, b], "boxes": [{"x", "y", "vx", "vy",
"ax", "ay", "w", "h", "rgb"}]}`` in pixels and seconds, y down. Frame k shows every box at
t = k / fps. Nothing the model wrote is executed, so no sandbox is needed; an engine that runs
model code does so in `visphy_core.api.sandbox` (browser or bubblewrap process).
"""

from __future__ import annotations

import json

import numpy as np

from visphy_core.api.engine import (Engine, FailureClass, Program, ProgramRejected,
                                    RenderContract, RenderResult)
from visphy_core.api.extract import extract_code
from visphy_core.api.hookspecs import hookimpl

KEYS = {"x", "y", "vx", "vy", "ax", "ay", "w", "h", "rgb"}


class BoxesEngine(Engine):
    name = "example_boxes"
    language = "boxes"      # the fence the prompt asks for
    version = "1"           # bump when the frames change: part of every render cache key

    def instructions(self, dim: str) -> str:
        return ("Answer with a ```boxes block of JSON as in this engine's docstring: each "
                "box's top-left corner, velocity and constant acceleration in pixels and "
                "seconds (y points down), its size and its rgb colour.")

    def extract(self, text: str) -> Program:
        # no_code, truncated and wrong_language are raised by the shared extractor
        return Program(self.language, extract_code(text, (self.language,)))

    def validate(self, program: Program) -> None:
        try:
            boxes = json.loads(program.source)["boxes"]
        except (ValueError, KeyError, TypeError) as exc:
            raise ProgramRejected(FailureClass.SYNTAX_ERROR, f"not a boxes program: {exc}")
        for i, box in enumerate(boxes):
            if not isinstance(box, dict) or KEYS - set(box):
                raise ProgramRejected(FailureClass.SYNTAX_ERROR,
                                      f"box {i} needs the keys {', '.join(sorted(KEYS))}")

    def render(self, program: Program, contract: RenderContract) -> RenderResult:
        # A bad program is a RenderResult with a failure class, never an exception.
        try:
            self.validate(program)
        except ProgramRejected as exc:
            return RenderResult(None, failure=exc.failure, error=str(exc))
        doc = json.loads(program.source)
        frames = np.empty((contract.n_frames, contract.height, contract.width, 3), np.uint8)
        for k in range(contract.n_frames):
            t = k / contract.fps
            frames[k] = doc.get("background", [255, 255, 255])
            for b in doc["boxes"]:
                x = round(b["x"] + b["vx"] * t + 0.5 * b["ax"] * t * t)
                y = round(b["y"] + b["vy"] * t + 0.5 * b["ay"] * t * t)
                frames[k, max(y, 0):max(y + b["h"], 0), max(x, 0):max(x + b["w"], 0)] = b["rgb"]
        return RenderResult(frames, isolation="none (nothing executed)")

    def program_from_spec(self, scene) -> Program:
        """The ground truth as boxes: each dynamic body of a 2D spec (y up) as a 10-px box in
        free flight from its initial pose; contacts are not modelled."""
        spec = scene.spec or {}
        world, height = spec.get("world", {}), scene.clip.height
        ppm = world.get("units", {}).get("px_per_m", 1.0)
        gx, gy = (g * ppm for g in world.get("gravity_m_s2", (0.0, 0.0)))
        boxes = [{"x": b["pose"]["x_px"] - 5, "y": height - b["pose"]["y_px"] - 5,
                  "vx": b["velocity"]["vx_px_s"], "vy": -b["velocity"]["vy_px_s"], "ax": gx,
                  "ay": -gy, "w": 10, "h": 10, "rgb": [0, 0, 0]}
                 for b in spec.get("bodies", []) if b.get("dynamic")]
        return Program(self.language, json.dumps({"boxes": boxes}), spec=scene.spec)


@hookimpl
def visphy_register_engines(register):
    register(BoxesEngine.name, BoxesEngine)  # factory(cfg) -> Engine
