"""Model ``oracle``: answers from the ground truth, so the whole pipeline runs without an API key.

Its reply has the format every model must use (analysis, ```json spec, fenced program), and the
program is one of the engine's trusted reference programs for the scene, chosen by
``model.style``:

* ``exact`` (default): `Engine.program_from_spec`, which reproduces the benchmark's alias-free
  raster. It measures the ceiling the pipeline itself allows (rendering, encoding, scoring), not
  a model; on 2D scenes its clip is nearly byte-identical on every engine.
* ``native``: `Engine.native_program_from_spec`, the same ground-truth poses drawn with the
  engine's own primitives and default anti-aliasing (p5 ``circle``/``rect``/``beginShape``,
  three.js meshes with ``antialias: true``, SVG elements, Manim mobjects, Blender meshes): the
  engine's intrinsic ceiling, what a perfect program loses to the engine's drawing. An engine
  without one answers an error (a ``model_error`` row).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from enum import Enum

from visphy_core.api.calls import describe_spec
from visphy_core.api.config_schema import ModelConfig
from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.model import (
    Model,
    ModelRequest,
    ModelResponse,
    PrivilegedRequest,
    config_identity,
)
from visphy_core.api.settings import cfg_get


class OracleStyle(str, Enum):
    """``model.style``: which reference program the oracle answers with."""

    exact = "exact"
    native = "native"


@dataclass
class OracleConfig(ModelConfig):
    """``conf/model/oracle.yaml``."""

    style: OracleStyle = OracleStyle.exact


def _style(cfg) -> str:
    value = cfg_get(cfg, "style", "exact")
    return str(getattr(value, "value", value) or "exact")


class OracleModel(Model):
    """The only privileged model: the pipeline hands it a `PrivilegedRequest`."""

    name = "oracle"
    version = "1"
    privileged = True

    @property
    def style(self) -> str:
        return _style(self.cfg)

    def identity(self) -> str:
        # the exact oracle keeps the identity it had before ``style`` existed (its cached
        # replies stay valid); the native one adds its style
        settings = json.loads(config_identity(self.name, self.version, self.cfg))[2]
        settings.pop("style", None)
        if self.style != "exact":
            settings["style"] = self.style
        return config_identity(self.name, self.version, settings or None)

    def generate(self, request: ModelRequest) -> ModelResponse:
        start = time.perf_counter()
        if not isinstance(request, PrivilegedRequest) or request.scene is None \
                or request.engine is None:
            return ModelResponse(text="", error="the oracle needs the scene and the engine",
                                 error_kind="bad_request")
        style = self.style
        if style not in ("exact", "native"):
            return ModelResponse(text="", error=f"oracle: model.style={style!r}; valid: "
                                                "exact, native", error_kind="bad_request")
        try:
            if style == "native":
                program = request.engine.native_program_from_spec(request.scene)
            else:
                program = request.engine.program_from_spec(request.scene)
        except (ValueError, NotImplementedError) as exc:
            return ModelResponse(text="", error=f"oracle: {exc}")
        spec = request.scene.spec or {}
        # the program's block holds its source exactly (a newline is added only where the
        # source lacks one): what the engine extracts is the reference program itself, so the
        # spec track's replay of S is the same render (`render_cached`'s memo), not another
        end = "" if program.source.endswith("\n") else "\n"
        text = (f"{describe_spec(spec)}\n\n```json\n{json.dumps(spec, indent=1)}\n```\n\n"
                f"```{program.language}\n{program.source}{end}```\n")
        return ModelResponse(text=text, usage={}, cost_usd=0.0,
                             latency_s=time.perf_counter() - start)


@hookimpl
def visphy_register_configs(config_store):
    config_store.store(group="model", name="schema_oracle", node=OracleConfig)


@hookimpl
def visphy_register_models(register):
    register("oracle", OracleModel)
