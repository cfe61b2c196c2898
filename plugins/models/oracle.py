"""Model ``oracle``: answers from the ground truth, so the whole pipeline runs without an API key.

Its reply has the format every model must use (analysis, ```json spec, fenced program), and the
program is the engine's trusted reference program for the scene (`Engine.program_from_spec`).
It measures the ceiling the pipeline itself allows (rendering, encoding, scoring), not a model.
"""

from __future__ import annotations

import json
import time

from visphy_core.hookspecs import hookimpl
from visphy_core.model import Model, ModelRequest, ModelResponse


def describe_motion(spec: dict) -> str:
    """A plain-English motion analysis built from the ground-truth spec and contact events."""
    bodies = spec.get("bodies", [])
    moving = [b["id"] for b in bodies if b.get("dynamic")]
    static = [b["id"] for b in bodies if not b.get("dynamic")]
    events = spec.get("ground_truth", {}).get("events", [])
    pairs = []
    for ev in events:
        pair = f"{ev['a']} and {ev['b']}"
        if ev.get("type") == "contact_begin" and pair not in pairs:
            pairs.append(pair)
    g = abs(spec.get("world", {}).get("gravity_m_s2", [0, -9.8])[1])
    sentences = [
        f"The scene contains {len(bodies)} objects: {', '.join(b['id'] for b in bodies)}.",
        f"The dynamic bodies are {', '.join(moving) or 'none'}; "
        f"{', '.join(static) or 'nothing'} stays fixed.",
        f"Gravity of {g:g} m/s² pulls the dynamic bodies down from rest.",
    ]
    if pairs:
        sentences.append(f"Contacts occur between {'; '.join(pairs[:6])}.")
    sentences.append("Friction and restitution at the contacts slow the bodies until they settle.")
    return " ".join(sentences)


class OracleModel(Model):
    name = "oracle"
    version = "1"

    def generate(self, request: ModelRequest) -> ModelResponse:
        start = time.perf_counter()
        if request.scene is None or request.engine is None:
            return ModelResponse(text="", error="the oracle needs the scene and the engine")
        try:
            program = request.engine.program_from_spec(request.scene)
        except (ValueError, NotImplementedError) as exc:
            return ModelResponse(text="", error=f"oracle: {exc}")
        spec = request.scene.spec or {}
        text = (f"{describe_motion(spec)}\n\n```json\n{json.dumps(spec, indent=1)}\n```\n\n"
                f"```{program.language}\n{program.source}\n```\n")
        return ModelResponse(text=text, usage={}, cost_usd=0.0,
                             latency_s=time.perf_counter() - start)


@hookimpl
def visphy_register_models(register):
    register("oracle", OracleModel)
