"""Repair and fallback (MISSION §2): one repair call with the error and the failing program,
then the fallback clip; model-success and system-success are counted apart."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from conftest import with_fast_metrics
from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.model import Model, ModelResponse

pytestmark = pytest.mark.browser

BROKEN = "```html\n<html><body><canvas id='c'></canvas><script>undefinedFunction();</script>" \
         "</body></html>\n```"


class ScriptedModel(Model):
    """Replies from a script: one reply per call, and remembers every prompt it was sent."""

    name = "scripted"
    prompts: list[str] = []
    replies: list[str] = []

    def generate(self, request):
        type(self).prompts.append(request.prompt)
        reply = type(self).replies[min(request.attempt, len(type(self).replies)) - 1]
        return ModelResponse(text=reply)



@pytest.fixture
def run_with(mini_root, tmp_path):
    """Run the pipeline on one mini scene with an inline model whose replies are scripted."""
    from visphy_core.api.registry import get_plugin_manager, get_registry
    from visphy_core.config.check import compose
    from visphy_core.execute.run import run_experiment

    class Plugin:
        @hookimpl
        def visphy_register_models(self, register):
            register("scripted", ScriptedModel)

    def run(replies: list[str], *overrides: str) -> tuple[dict, Path]:
        ScriptedModel.prompts, ScriptedModel.replies = [], replies
        home = tmp_path / f"home{len(list(tmp_path.iterdir()))}"
        shutil.copytree(mini_root, home / "data" / mini_root.name)
        pm = get_plugin_manager()
        pm.register(Plugin(), name="scripted")
        get_registry.cache_clear()
        try:
            cfg = compose(list(with_fast_metrics((f"paths.root={home}", "dataset.limit=1",
                                                  "tracking=none", "run.progress=false",
                                                  "model.name=scripted", *overrides))))
            summary = run_experiment(cfg)
        finally:
            pm.unregister(name="scripted")
            get_registry.cache_clear()
        run_dir = Path(summary["run_dir"])
        row = json.loads((run_dir / "results.jsonl").read_text().splitlines()[0])
        return summary, row

    return run


def _good_reply(mini_scenes) -> str:
    from visphy_plugins.engines.threejs import ThreeJsEngine

    program = ThreeJsEngine().program_from_spec(mini_scenes[0])
    return f"The ball falls.\n\n```html\n{program.source}\n```\n"


def test_a_failed_program_is_repaired_with_the_error_and_the_program(run_with, mini_scenes):
    summary, row = run_with([BROKEN, _good_reply(mini_scenes)])
    assert row["model_success"] and row["attempts"] == 2 and not row["fallback"]
    assert row["first_failure_class"] == "runtime_error" and row["failure_class"] is None
    repair_prompt = ScriptedModel.prompts[1]
    assert "undefinedFunction();" in repair_prompt           # the failing program
    assert "undefinedFunction is not defined" in repair_prompt  # the console error
    assert repair_prompt.startswith(ScriptedModel.prompts[0])  # same inputs as the first call
    assert summary["repaired"] == 1 and summary["model_success"] == 1


def test_two_failures_give_a_fallback_that_is_not_a_model_success(run_with):
    summary, row = run_with([BROKEN, "no code at all, sorry"])
    assert not row["model_success"] and row["system_success"] and row["fallback"]
    assert row["failure_class"] == "no_code" and row["first_failure_class"] == "runtime_error"
    assert summary["model_success"] == 0 and summary["fallbacks"] == 1
    assert summary["failures"] == {"model": {"no_code": 1}, "infra_or_data": {}}
    psnr = summary["metrics"]["psnr"]
    assert psnr["n_model_success"] == 0 and psnr["mean_model_success"] is None
    assert psnr["n_with_fallbacks"] == 1 and psnr["mean_with_fallbacks"] > 0


def test_without_retry_and_fallback_a_failure_is_a_counted_row(run_with):
    summary, row = run_with([BROKEN], "run.retry=false", "run.fallback=false")
    assert len(ScriptedModel.prompts) == 1
    assert summary["n_scenes"] == 1 and summary["system_success"] == 0
    assert row["failure_class"] == "runtime_error" and row["score_psnr"] is None
