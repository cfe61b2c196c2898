"""`python -m visphy_core ARGS` with an inline model plugin ``counting`` (tests/test_resume.py).

``counting`` is the oracle whose replies can be scripted per scene and attempt, and that appends
one line per `generate` call to the file named by ``VISPHY_COUNTER`` (flushed and fsynced before
the reply is returned), so a test can count the model calls a killed and resumed run made.

``VISPHY_SCRIPT`` (JSON): ``{scene_id: [reply kind for attempt 1, attempt 2]}`` with kinds
``oracle`` (the reference program), ``broken`` (a runtime error) and ``no_code``.
"""

from __future__ import annotations

import json
import os
import sys
import time

from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.model import ModelResponse

BROKEN = ("```html\n<html><body><canvas id='c'></canvas><script>undefinedFunction();</script>"
          "</body></html>\n```")


def main(argv: list[str]) -> int:
    from visphy_core.api.registry import get_plugin_manager, get_registry
    from visphy_core.cli.main import main as cli_main
    from visphy_plugins.models.oracle import OracleModel

    script = json.loads(os.environ.get("VISPHY_SCRIPT", "{}"))
    delay = float(os.environ.get("VISPHY_MODEL_DELAY", "0"))

    class CountingModel(OracleModel):
        name = "counting"

        def generate(self, request):
            kinds = script.get(request.scene_id, ["oracle", "oracle"])
            kind = kinds[min(request.attempt, len(kinds)) - 1]
            if kind == "oracle":
                response = super().generate(request)
            elif kind == "broken":
                response = ModelResponse(text=BROKEN)
            else:
                response = ModelResponse(text="no code, sorry")
            time.sleep(delay)
            with open(os.environ["VISPHY_COUNTER"], "a") as fh:
                fh.write(f"{request.scene_id} {request.attempt}\n")
                fh.flush()
                os.fsync(fh.fileno())
            return response

    class Plugin:
        @hookimpl
        def visphy_register_models(self, register):
            register("counting", CountingModel)

    get_plugin_manager().register(Plugin(), name="counting")
    get_registry.cache_clear()
    return cli_main(argv)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
