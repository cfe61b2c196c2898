"""What a run logs to MLflow, computed from its config and summary: the params that tell
runs apart, the headline and family means, every metric, the per-scene table."""

from __future__ import annotations

import math
from enum import Enum
from typing import Any

from omegaconf import OmegaConf

from visphy_core.results.columns import NORM_PREFIX


#: The config values logged as params (when set): what tells runs apart. The whole resolved
#: config is the artifact config.yaml; a study's swept keys are params too.
KEY_PARAMS = ("model.name", "model.model_id", "model.style", "model.reasoning_effort",
              "model.thinking_budget", "model.temperature", "engine.name", "dataset.name",
              "dataset.split", "dataset.limit", "dataset.seed", "metrics.variance_norm",
              "metrics.spec_track", "prompt.frames", "prompt.detection",
              "prompt.forecast_only", "prompt.timed", "run.seed", "run.retry", "run.fallback",
              "reference.source")
#: Summary counts logged as metrics.
SUMMARY_COUNTS = ("model_success_rate", "model_success_rate_evaluable", "system_success_rate",
                  "model_success", "system_success", "repaired", "fallbacks", "n_scenes",
                  "n_evaluable")
USAGE_FIELDS = ("calls", "cache_hits", "errors", "input_tokens", "output_tokens",
                "cached_input_tokens", "reasoning_tokens", "cost_usd", "cost_usd_incl_cached")


#: A study's comparison table: of `headline_metrics`, these (and every ``family.*``).
STUDY_COLUMNS = ("headline", "headline.lo", "headline.hi", "model_success_rate",
                 "system_success_rate", "n_scenes", "fallbacks")


def study_row(summary: dict, clip: tuple[float, float] = (-1.0, 1.0)) -> dict[str, float]:
    """A job's numbers in its study's comparison table: the headline with its interval, the
    family means, success rates and counts (as its own run logs them)."""
    values = headline_metrics(summary, clip)
    return {k: v for k, v in values.items() if k in STUDY_COLUMNS or k.startswith("family.")}


def run_params(cfg, swept=()) -> dict[str, Any]:
    """The params of a run: `KEY_PARAMS` and a study's swept keys (those with a value, a group
    such as ``model`` by its ``.name``), the judges (``judge``, ``none`` without one) and the
    metric suite chosen (``metrics.suite``: ``default``, ``fast``… when Hydra composed it)."""
    out: dict[str, Any] = {}
    for key in (*KEY_PARAMS, *(k.lstrip("+~") for k in swept if "/" not in k)):
        value = OmegaConf.select(cfg, key, default=None)
        if OmegaConf.is_list(value):
            value = ",".join(str(v) for v in value)
        elif OmegaConf.is_dict(value):
            value = value.get("name")
        if isinstance(value, Enum):  # a structured config's choice: its name, as written
            value = value.name
        if value is not None:
            out[key] = value
    out["judge"] = ",".join(sorted(OmegaConf.select(cfg, "judge", default=None) or {})) or "none"
    try:
        from hydra.core.hydra_config import HydraConfig

        out["metrics.suite"] = str(HydraConfig.get().runtime.choices["metrics"])
    except Exception:  # noqa: BLE001 - not composed by Hydra (merge, score): no suite name
        pass
    return out


def headline_clip(cfg) -> tuple[float, float]:
    """``metrics.headline.clip``: the range each normalised component is clipped to."""
    clip = OmegaConf.select(cfg, "metrics.headline.clip", default=None) or (-1.0, 1.0)
    return float(clip[0]), float(clip[1])


def family_means(summary: dict, clip: tuple[float, float] = (-1.0, 1.0)) -> dict[str, float]:
    """``family.<family>``: per metric family (``metric_info``), the mean of its metrics'
    variance-normalised means over every scored scene (``norm.<metric>``: the still clip 0, the
    ground truth's twin 1, higher is better for every metric and direction), each clipped to
    the headline's ``clip`` first, as the headline clips its components. A family none of
    whose metrics has a normalised mean (text metrics, a dataset without specs,
    ``metrics.variance_norm=false``) has no entry: raw means in different units do not
    average."""
    info = summary.get("metric_info") or {}
    groups: dict[str, list[float]] = {}
    for name, m in (summary.get("metrics") or {}).items():
        family = (info.get(name[len(NORM_PREFIX):]) or {}).get("family")
        mean = m.get("mean_with_fallbacks")
        if name.startswith(NORM_PREFIX) and family and mean is not None and math.isfinite(mean):
            groups.setdefault(str(family), []).append(min(max(float(mean), clip[0]), clip[1]))
    return {f"family.{f}": sum(v) / len(v) for f, v in sorted(groups.items())}


def headline_metrics(summary: dict, clip: tuple[float, float] = (-1.0, 1.0)
                     ) -> dict[str, float]:
    """The few metrics to look at first: ``headline`` (+ ``.lo``, ``.hi``, ``.n``), the
    family means, success rates and counts."""
    out: dict[str, float] = {}
    head = summary.get("headline") or {}
    if head.get("mean") is not None:
        out["headline"] = float(head["mean"])
        out["headline.n"] = float(head.get("n") or 0)
        if head.get("ci"):
            out["headline.lo"], out["headline.hi"] = (float(v) for v in head["ci"])
    out.update(family_means(summary, clip))
    for key in SUMMARY_COUNTS:
        if summary.get(key) is not None:
            out[key] = float(summary[key])
    return out


def summary_metrics(summary: dict, clip: tuple[float, float] = (-1.0, 1.0)
                    ) -> dict[str, float]:
    """Every metric of a run: `headline_metrics`; each score column's mean over model
    successes (``<name>``) and, for the metrics' own columns (``psnr``, the headline's, a
    judge's) and their normalised ones (``norm.psnr``), over all scenes with fallbacks scored
    (``<name>_with_fallbacks``; the counts are in ``scenes.json`` and ``summary.json``); usage
    per stage; judge verdict counts; stage seconds."""
    out = headline_metrics(summary, clip)
    for name, m in summary["metrics"].items():
        if m.get("mean_model_success") is not None:
            out[name] = m["mean_model_success"]
        own = "." not in name.removeprefix(NORM_PREFIX)
        if own and m.get("mean_with_fallbacks") is not None:
            out[f"{name}_with_fallbacks"] = m["mean_with_fallbacks"]
    for stage, totals in (summary.get("usage") or {}).items():
        for name in USAGE_FIELDS:
            out[f"usage.{stage}.{name}"] = float(totals.get(name) or 0)
    for key, judge in (summary.get("judges") or {}).items():
        out[f"judge.{key}.n_valid"] = float(judge["n_valid"])
        out[f"judge.{key}.n_invalid"] = float(judge["n_invalid"])
    for stage, totals in (summary.get("stage_seconds") or {}).items():
        out[f"seconds.{stage}"] = float(totals.get("total") or 0)
        if totals.get("mean") is not None:
            out[f"seconds.{stage}.per_scene"] = float(totals["mean"])
    return out


def table_column(name: str) -> str:
    """A column name of a logged table: dots become underscores (``psnr.aligned`` →
    ``psnr_aligned``, ``family.pixel`` → ``family_pixel``): MLflow's table view reads a dot as
    a nested field and shows such a column empty."""
    return name.replace(".", "_")


def scene_table(results: list, columns: list[str]):
    """The per-scene table: ``scene_id``, ``outcome``, then a column per score (in the
    summary's order, the headline first; `table_column` names); an undefined score is
    empty."""
    import pandas as pd

    rows = [{"scene_id": r.scene_id, "outcome": r.outcome,
             **{table_column(c): r.scores.get(c) for c in columns}} for r in results]
    return pd.DataFrame(rows, columns=["scene_id", "outcome", *map(table_column, columns)])
