"""One run: a dataset split × model × engine × prompt mode × metric set, end to end.

The run directory is written as the run goes (``results.jsonl`` grows one row per scene), so a
crash loses nothing; the content-addressed cache makes a re-run resume without re-querying or
re-rendering.
"""

from __future__ import annotations

import datetime as dt
import json
import platform
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from omegaconf import DictConfig, OmegaConf

from visphy_core.cache import Cache, content_key
from visphy_core.console import print_summary, scene_progress
from visphy_core.dataset import load_dataset
from visphy_core.metrics import Metric
from visphy_core.pipeline import PipelineSettings, SceneResult, process_scene
from visphy_core.plugins import get_plugin_manager, get_registry
from visphy_core.prompts.build import PromptSettings
from visphy_core.scene import Scene


@dataclass
class RunContext:
    """What lifecycle hooks receive: the config, where things go, and what runs."""

    cfg: DictConfig
    run_dir: Path
    root: Path
    scenes: list[Scene]
    model_name: str
    engine_name: str
    metrics: list[Metric]
    results: list[SceneResult] = field(default_factory=list)
    cache: Cache | None = None
    extra: dict[str, Any] = field(default_factory=dict)


def _run_dir(cfg: DictConfig, runs_dir: Path) -> Path:
    resolved = OmegaConf.to_container(cfg, resolve=True)
    for key in ("paths", "run"):
        resolved.pop(key, None)
    digest = content_key(resolved)[:8]
    stamp = dt.datetime.now().strftime("%Y-%m-%d_%H-%M-%S")
    return runs_dir / f"{stamp}_{cfg.model.name}_{cfg.engine.name}_{digest}"


def _manifest(ctx: RunContext) -> dict:
    pm = get_plugin_manager()
    from visphy_core.plugins import describe_plugins

    return {
        "visphy_version": _version(),
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "argv": sys.argv,
        "started": dt.datetime.now().isoformat(timespec="seconds"),
        "plugins": {p.name: {"distribution": p.distribution, "version": p.version}
                    for p in describe_plugins(pm)},
        "scenes": [s.scene_id for s in ctx.scenes],
        "metrics": [m.describe() for m in ctx.metrics],
    }


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("visphy")
    except PackageNotFoundError:
        return "source"


def summarise(results: list[SceneResult], metrics: list[Metric], cache: Cache) -> dict:
    """Means with honest denominators: model successes only, and all scenes with fallbacks."""
    n = len(results)
    ok = [r for r in results if r.model_success]
    scored = [r for r in results if r.system_success]
    failures: dict[str, int] = {}
    for r in results:
        if not r.model_success and r.failure_class:
            failures[r.failure_class] = failures.get(r.failure_class, 0) + 1
    per_metric = {}
    for m in metrics:
        def mean(rows):
            vals = [r.scores.get(m.name) for r in rows if r.scores.get(m.name) is not None]
            return (float(np.mean(vals)) if vals else None), len(vals)

        ok_mean, ok_n = mean(ok)
        all_mean, all_n = mean(scored)
        reasons = {r.unavailable[m.name] for r in results if m.name in r.unavailable}
        per_metric[m.name] = {
            "direction": m.direction, "mean_model_success": ok_mean, "n_model_success": ok_n,
            "mean_with_fallbacks": all_mean, "n_with_fallbacks": all_n,
            "unavailable": sorted(reasons)[0] if reasons else None,
        }
    return {
        "n_scenes": n,
        "model_success": len(ok), "model_success_rate": len(ok) / n if n else None,
        "system_success": len(scored), "system_success_rate": len(scored) / n if n else None,
        "fallbacks": sum(r.fallback for r in results),
        "repaired": sum(r.model_success and r.attempts > 1 for r in results),
        "failures": failures,
        "flags": {f: sum(f in r.flags for r in results) for r in results for f in r.flags},
        "metrics": per_metric,
        "cache": cache.stats(),
        "renders_done": sum(1 for r in results if r.render_wall_s is not None
                            and not r.render_cached),
    }


def _write_json(path: Path, data: Any) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(data, indent=1, default=str))
    tmp.replace(path)


def run_experiment(cfg: DictConfig) -> dict:
    """Evaluate every selected scene; returns the summary (also in ``summary.json``)."""
    import pandas as pd

    registry = get_registry()
    pm = get_plugin_manager()
    root = Path(cfg.paths.root).resolve()
    data_dir, runs_dir = Path(cfg.paths.data_dir).resolve(), Path(cfg.paths.runs_dir).resolve()
    cache = Cache(Path(cfg.paths.cache_dir).resolve(), enabled=bool(cfg.run.cache))
    scenes = load_dataset(cfg.dataset, data_dir, progress=bool(cfg.run.progress))
    model = registry.get("models", cfg.model.name)(cfg.model)
    engine = registry.get("engines", cfg.engine.name)(cfg.engine)
    metrics = [registry.get("metrics", name) for name in cfg.metrics.names]
    run_dir = _run_dir(cfg, runs_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))
    ctx = RunContext(cfg=cfg, run_dir=run_dir, root=root, scenes=scenes,
                     model_name=cfg.model.name, engine_name=cfg.engine.name, metrics=metrics,
                     cache=cache)
    _write_json(run_dir / "manifest.json", _manifest(ctx))
    settings = PipelineSettings(prompt=PromptSettings.from_cfg(cfg.prompt), retry=cfg.run.retry,
                                fallback=cfg.run.fallback, timeout_s=cfg.engine.timeout_s,
                                seed=cfg.run.seed)
    pm.hook.visphy_run_start(run=ctx)
    rows_path = run_dir / "results.jsonl"
    try:
        with scene_progress(len(scenes), enabled=bool(cfg.run.progress)) as advance:
            for scene in scenes:
                advance(scene.scene_id)
                result = process_scene(scene, model, engine, metrics, settings, cache,
                                       run_dir / "scenes" / scene.scene_id)
                ctx.results.append(result)
                with rows_path.open("a") as fh:
                    fh.write(json.dumps(result.row(), default=str) + "\n")
                pm.hook.visphy_scene_done(run=ctx, scene=scene, result=result)
    finally:
        engine.close()
    pd.DataFrame([r.row() for r in ctx.results]).to_parquet(run_dir / "results.parquet",
                                                           index=False)
    summary = summarise(ctx.results, metrics, cache)
    summary.update({"run_dir": str(run_dir), "model": cfg.model.name, "engine": cfg.engine.name,
                    "dataset": cfg.dataset.name})
    _write_json(run_dir / "summary.json", summary)
    pm.hook.visphy_run_end(run=ctx, summary=summary)
    print_summary(summary, ctx.results)
    return summary
