"""Model ``oracle``: answers from the ground truth, so the whole pipeline runs without an API key.

Its reply has the format every model must use (analysis, ```json spec, fenced program), and the
program is the engine's trusted reference program for the scene (`Engine.program_from_spec`).
It measures the ceiling the pipeline itself allows (rendering, encoding, scoring), not a model.
"""

from __future__ import annotations

import json
import time

from visphy_core.hookspecs import hookimpl
from visphy_core.model import Model, ModelRequest, ModelResponse, PrivilegedRequest
from visphy_core.references import describe_spec


class OracleModel(Model):
    """The only privileged model: the pipeline hands it a `PrivilegedRequest`."""

    name = "oracle"
    version = "1"
    privileged = True

    def generate(self, request: ModelRequest) -> ModelResponse:
        start = time.perf_counter()
        if not isinstance(request, PrivilegedRequest) or request.scene is None \
                or request.engine is None:
            return ModelResponse(text="", error="the oracle needs the scene and the engine",
                                 error_kind="bad_request")
        try:
            program = request.engine.program_from_spec(request.scene)
        except (ValueError, NotImplementedError) as exc:
            return ModelResponse(text="", error=f"oracle: {exc}")
        spec = request.scene.spec or {}
        text = (f"{describe_spec(spec)}\n\n```json\n{json.dumps(spec, indent=1)}\n```\n\n"
                f"```{program.language}\n{program.source}\n```\n")
        return ModelResponse(text=text, usage={}, cost_usd=0.0,
                             latency_s=time.perf_counter() - start)


@hookimpl
def visphy_register_models(register):
    register("oracle", OracleModel)
