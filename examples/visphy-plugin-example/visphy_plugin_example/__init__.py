"""Example visphy plugin: registers a model, its config entry, and a metric."""

from __future__ import annotations

import base64
from dataclasses import dataclass

import numpy as np

from visphy_core.api.config_schema import ModelConfig
from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.metrics import LOWER, Metric, MetricInput
from visphy_core.api.model import Model, ModelRequest, ModelResponse

PAGE = """<!DOCTYPE html>
<html><head><style>body{{margin:0;background:#fff}}</style></head>
<body><img id="still" src="data:image/png;base64,{png}" style="display:none">
<canvas id="c" width="{w}" height="{h}"></canvas>
<script>
const canvas = document.getElementById('c');
const ctx = canvas.getContext('2d');
setupRecording(canvas, 1000);
function draw() {{
  ctx.drawImage(document.getElementById('still'), 0, 0, {w}, {h});
  requestAnimationFrame(draw);
}}
window.addEventListener('load', draw);
</script></body></html>"""


@dataclass
class StillConfig(ModelConfig):
    name: str = "example_still"


class StillModel(Model):
    """Paints the first key frame for the whole clip: the static baseline."""

    name = "example_still"
    version = "1"

    def generate(self, request: ModelRequest) -> ModelResponse:
        first = request.images[0]
        import io

        from PIL import Image

        w, h = Image.open(io.BytesIO(first.png)).size
        html = PAGE.format(png=base64.b64encode(first.png).decode(), w=w, h=h)
        text = ("Nothing in this baseline moves: it holds the first frame.\n\n"
                f"```html\n{html}\n```\n")
        return ModelResponse(text=text)


class MeanAbsoluteError(Metric):
    name = "example_mae"
    direction = LOWER
    score_range = (0.0, 255.0)

    def compute(self, inp: MetricInput) -> float:
        diff = inp.reference.astype(np.float64) - inp.generated.astype(np.float64)
        return float(np.abs(diff).mean())


@hookimpl
def visphy_register_configs(config_store):
    config_store.store(group="model", name="example_still", node=StillConfig)


@hookimpl
def visphy_register_models(register):
    register("example_still", StillModel)


@hookimpl
def visphy_register_metrics(register):
    register(MeanAbsoluteError())
