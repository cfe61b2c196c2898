"""What the run-lifecycle hooks receive as ``run`` (`visphy_core.api.hookspecs`): a run, re-scoring
(``visphy score``) and a merge of shards (``visphy merge``) each make one `RunContext`.

An observer reads the run from it and records where it logged the run in `tracking` (by plugin
name: the run writes it to its manifest, so a resumed run can close what a killed process left
open) and what the person should look at in `where_to_look` (one line each, printed after the
report's line at the end of the run). Anything else a plugin keeps between calls is its own.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from omegaconf import DictConfig

from visphy_core.api.metrics import Metric
from visphy_core.api.scene import Scene
from visphy_core.infra.cache import Cache


@dataclass
class RunContext:
    """One run, as the lifecycle hooks see it."""

    #: The composed config (credentials included: never write it out as it is).
    cfg: DictConfig
    #: The run directory (read its files through `visphy_core.results.run_dir.RunDir`).
    run_dir: Path
    #: ``paths.root``: where the run's shared stores (cache, tracking) live.
    root: Path
    #: The selected scenes (empty for a merge of shards).
    scenes: list[Scene]
    model_name: str
    engine_name: str
    #: The run's metric objects.
    metrics: list[Metric]
    #: The rows so far (`visphy_core.results.row.SceneResult`), in scene order at the end.
    results: list[Any] = field(default_factory=list)
    cache: Cache | None = None
    #: The selected judges' keys.
    judges: list[str] = field(default_factory=list)
    #: The config hash a resumed run is matched by (`visphy_core.results.run_dir.config_hash`).
    config_hash: str | None = None
    #: Where each tracking plugin recorded the run, by plugin name (``mlflow``: its tracking
    #: URI, run id and experiment id), set in `visphy_run_start`.
    tracking: dict[str, dict[str, Any]] = field(default_factory=dict)
    #: A resumed run: where the killed process's run was recorded (its manifest's
    #: ``tracking``), so a plugin can close it.
    resumed_from: dict[str, dict[str, Any]] = field(default_factory=dict)
    #: ``visphy score``: the run re-scored (``run_dir``, its ``mlflow_run_id``, ``at``).
    rescored_from: dict[str, Any] | None = None
    #: ``visphy merge``: the shards merged (``run_dir``, ``shard``, ``mlflow_run_id``, …).
    merged_from: list[dict[str, Any]] = field(default_factory=list)
    #: Lines printed after the report's line when the run ends (``MLflow: mlflow ui …``).
    where_to_look: list[str] = field(default_factory=list)

    @property
    def datasets(self) -> list[str]:
        """The dataset builds the scenes come from."""
        return sorted({s.dataset for s in self.scenes if s.dataset})
