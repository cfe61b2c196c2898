"""MLflow tracking as a lifecycle-hook plugin: one MLflow run per visphy run, and one parent run
per study (a multirun) with the jobs' runs as its children.

Default store: ``sqlite:///<paths.root>/mlflow.db`` with the explicit artifact root
``<paths.root>/mlartifacts`` (MLflow 3 refuses the plain file store); ``tracking.uri`` may name
a tracking server (``http://host:port``), which then decides where artifacts go unless
``tracking.artifact_root`` says. See the runs with
``mlflow ui --backend-store-uri sqlite:///visphy-out/mlflow.db`` (docs/results/mlflow.md).

A run logs, at its end:

* metrics, the ones to look at first: ``headline`` (the summary's headline mean over every
  scored scene) with ``headline.lo``/``headline.hi`` (its 95% bootstrap interval) and
  ``headline.n``; ``family.<family>`` per metric family (`family_means`); success rates and
  counts; then each score column's mean over model successes (``<column>``) and over every
  scored scene (``<column>_with_fallbacks``, for the metrics' own and normalised columns);
  usage, judge counts and stage seconds. No per-scene steps: the per-scene values are the
  table artifact ``scenes.json``;
* params: only those that tell runs apart (`KEY_PARAMS`, the swept keys of a study); the whole
  resolved config is the artifact ``config.yaml``;
* artifacts: ``scenes.json`` (`MlflowClient.log_table`: one row per scene, a column per score
  named as the score with ``_`` for ``.``, shown as a table by the UI), the run's files
  (config, manifest, summary, the per-scene table as Parquet and JSONL, the call ledger), the
  HTML report under ``report/`` when one was written, the clips under ``videos/`` with
  ``tracking.log_videos=true``.

System tags: ``visphy.run_dir``, ``visphy.model``, ``visphy.engine``, ``visphy.dataset``,
``visphy.prompt_version``, ``visphy.benchmark_version``, ``visphy.study``,
``mlflow.source.git.commit`` and ``visphy.git_commit`` (when visphy runs from a git checkout).
A study's parent run gets the comparison table ``comparison.json`` (`study_row` per job) from
`visphy_core.study.finish`.
"""

from visphy_core.tracking.hooks import (
    FinishedRun,
    end_study_run,
    log_finished_run,
    run_display_name,
    start_study_run,
    track_command,
    visphy_run_end,
    visphy_run_start,
)
from visphy_core.tracking.store import mlflow_command, open_store, store_lock, tracking_uris
from visphy_core.tracking.values import (
    family_means,
    headline_clip,
    headline_metrics,
    run_params,
    scene_table,
    study_row,
    summary_metrics,
    table_column,
)

__all__ = [
    "FinishedRun", "end_study_run", "family_means", "headline_clip",
    "headline_metrics", "log_finished_run", "mlflow_command", "open_store", "run_display_name",
    "run_params", "scene_table", "start_study_run", "store_lock", "study_row",
    "summary_metrics", "table_column", "track_command", "tracking_uris", "visphy_run_end",
    "visphy_run_start",
]
