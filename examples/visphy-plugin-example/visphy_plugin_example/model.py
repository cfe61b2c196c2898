"""Model ``example_still``: a "nothing moves" baseline that needs no API key.

It writes an HTML program painting the first key frame onto a canvas for the whole clip, so it
runs with the browser engines (``threejs``, ``p5``, ``svg``). Its config entry is in
``configs.py`` (``model=example_still``).
"""

from __future__ import annotations

import base64
import io

from PIL import Image

from visphy_core.api.hookspecs import hookimpl
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


class StillModel(Model):
    """Paints the first key frame for the whole clip: the static baseline."""

    name = "example_still"
    version = "1"  # bump when the reply changes: it is part of every cached reply's key

    def generate(self, request: ModelRequest) -> ModelResponse:
        # A request holds only what the paper gives a model: the prompt, the key frames, the
        # clip contract. A provider failure is returned (ModelResponse.error), never raised.
        first = request.images[0]
        w, h = Image.open(io.BytesIO(first.png)).size
        html = PAGE.format(png=base64.b64encode(first.png).decode(), w=w, h=h)
        text = ("Nothing in this baseline moves: it holds the first frame.\n\n"
                f"```html\n{html}\n```\n")
        return ModelResponse(text=text)


@hookimpl
def visphy_register_models(register):
    register(StillModel.name, StillModel)  # factory(cfg) -> Model: the class itself
