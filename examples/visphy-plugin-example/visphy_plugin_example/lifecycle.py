"""Run-lifecycle hooks: an observer that logs a run to ``example_log.jsonl`` in its directory.

The lifecycle hooks are for observers (tracking, progress, custom reports): they see the run,
they do not change its rows. `visphy_run_start` is called once the run directory exists (again
when a run is resumed), `visphy_scene_done` once per scene as it finishes (failures included),
`visphy_run_end` once after ``results.parquet`` and ``summary.json`` are written; what it adds to
``summary`` is written to ``summary.json`` too. An exception in a hook fails the run, so an
observer that may fail (a server down) catches its own errors and logs them.
"""

from __future__ import annotations

import json

from visphy_core.api.hookspecs import hookimpl

LOG = "example_log.jsonl"


def _log(run, **record) -> None:
    with open(run.run_dir / LOG, "a", encoding="utf-8") as f:
        f.write(json.dumps(record) + "\n")


@hookimpl
def visphy_run_start(run):
    # run: visphy_core.api.run_context.RunContext (cfg, run_dir, scenes, model and engine names…)
    _log(run, event="run_start", model=run.model_name, engine=run.engine_name,
         scenes=len(run.scenes))


@hookimpl
def visphy_scene_done(run, scene, result):
    # result: the scene's row (visphy_core.results.row.SceneResult), as results.jsonl has it
    _log(run, event="scene_done", scene=scene.scene_id, model_success=result.model_success,
         failure=result.failure_class, scores=len(result.scores))


@hookimpl
def visphy_run_end(run, summary):
    _log(run, event="run_end", status=summary.get("status"), rows=len(run.results))
    summary["example_log"] = LOG  # written to summary.json after the hooks
