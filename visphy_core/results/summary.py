"""A run's summary from its rows: counts with honest denominators and each score column's means.

`summarise` makes ``summary.json``'s counts and means plus what only the live run knows (cache
statistics, usage, metric descriptions); a report of a run
that never wrote its summary (killed, or still going) recomputes the same counts and means here
from ``results.jsonl`` (`summarise_rows`). Both use one rule:

* success rates over all scenes and over the evaluable ones (``infra_error`` and
  ``data_error`` rows say nothing about the model), failures split between the model's and
  ours;
* each column's mean over the model's successes, and over every scene with a clip (fallbacks
  included) — or, for the spec track's columns, over every evaluable scene (S is scored whether
  or not the program ran).
"""

from __future__ import annotations

from typing import Any, Callable, Iterable, NamedTuple

import numpy as np

from visphy_core.api.metrics import Metric
from visphy_core.results.columns import JUDGE_PREFIX, SPEC_PREFIX, column_direction
from visphy_core.results.row import NOT_EVALUABLE, SceneResult

#: Per-stage wall seconds of a row, summed in the summary (``stage_seconds``).
STAGE_FIELDS = ("model_latency_s", "render_wall_s", "reference_render_wall_s",
                "scoring_wall_s", "judge_wall_s")


def counts(results: list[SceneResult]) -> dict[str, Any]:
    """Scenes, successes, fallbacks, repairs, failures by side and class, flags."""
    n = len(results)
    ok = [r for r in results if r.model_success]
    scored = [r for r in results if r.system_success]
    evaluable = [r for r in results if r.evaluable]
    failures: dict[str, dict[str, int]] = {"model": {}, "infra_or_data": {}}
    for r in results:
        if not r.model_success and r.failure_class:
            side = "infra_or_data" if r.failure_class in NOT_EVALUABLE else "model"
            failures[side][r.failure_class] = failures[side].get(r.failure_class, 0) + 1
    return {
        "n_scenes": n,
        "n_evaluable": len(evaluable),
        "model_success": len(ok), "model_success_rate": len(ok) / n if n else None,
        "model_success_rate_evaluable": len(ok) / len(evaluable) if evaluable else None,
        "system_success": len(scored), "system_success_rate": len(scored) / n if n else None,
        "fallbacks": sum(r.fallback for r in results),
        "repaired": sum(r.model_success and r.attempts > 1 for r in results),
        "failures": failures,
        "infra_retries": sum(r.infra_retries for r in results),
        "flags": {f: sum(f in r.flags for r in results) for r in results for f in r.flags},
    }


def metric_means(results: list[SceneResult], columns: Iterable[tuple[str, str]]
                 ) -> dict[str, dict[str, Any]]:
    """Per (column, direction): its mean and count over the model's successes and with
    fallbacks, and the first reason it was unavailable."""
    ok = [r for r in results if r.model_success]
    scored = [r for r in results if r.system_success]
    evaluable = [r for r in results if r.evaluable]
    out = {}
    for name, direction in columns:
        def mean(rows: list[SceneResult]) -> tuple[float | None, int]:
            vals = [r.scores.get(name) for r in rows if r.scores.get(name) is not None]
            return (float(np.mean(vals)) if vals else None), len(vals)

        ok_mean, ok_n = mean(ok)
        all_mean, all_n = mean(evaluable if name.startswith(SPEC_PREFIX) else scored)
        reasons = {r.unavailable[name] for r in results if name in r.unavailable}
        out[name] = {
            "direction": direction, "mean_model_success": ok_mean, "n_model_success": ok_n,
            "mean_with_fallbacks": all_mean, "n_with_fallbacks": all_n,
            "unavailable": sorted(reasons)[0] if reasons else None,
        }
    return out


def spec_counts(results: list[SceneResult]) -> dict[str, int]:
    return {"valid": sum(r.spec_valid is True for r in results),
            "invalid": sum(r.spec_valid is False for r in results),
            "absent": sum(r.spec_valid is None for r in results)}


def prompt_versions(results: list[SceneResult]) -> list[str]:
    return sorted({r.prompt_version for r in results if r.prompt_version})


def stage_seconds(results: list[SceneResult]) -> dict[str, dict[str, float | int]]:
    """Each stage's wall seconds summed over the scenes where it ran this time (a cached
    render's recorded time is not counted), with the count and the mean per such scene. With
    several workers the stages of different scenes overlap: the sums exceed the run's wall."""
    out: dict[str, dict[str, float | int]] = {}
    for name in STAGE_FIELDS:
        values = [float(getattr(r, name)) for r in results if getattr(r, name) is not None
                  and not (name == "render_wall_s" and r.render_cached)
                  and not (name == "model_latency_s" and r.model_calls == 0)]
        out[name] = {"total": round(sum(values), 3), "n": len(values),
                     "mean": round(sum(values) / len(values), 4) if values else None}
    return out


def summarise_rows(results: list[SceneResult], manifest: dict[str, Any]) -> dict[str, Any]:
    """The counts and means of a run that never wrote its summary: every score column the
    rows hold, directions from the manifest's metric list."""
    base = {str(m.get("name")): str(m.get("direction", "higher"))
            for m in manifest.get("metrics") or [] if isinstance(m, dict)}
    columns: list[str] = []
    for r in results:
        columns += [c for c in r.scores if c not in columns]
    return {**counts(results),
            "metrics": metric_means(results, [(c, column_direction(c, base)) for c in columns]),
            "prompt_versions": prompt_versions(results), "spec": spec_counts(results)}


class HeadlineColumn(NamedTuple):
    """The run's headline column and how its summary entry is made from its values over the
    model's successes and over every scored scene
    (`visphy_core.scoring.headline.summary_entry`)."""

    name: str
    entry: Callable[[list[float], list[float]], dict]


def judge_columns(results: list[SceneResult], judges: list[str]) -> dict[str, dict]:
    """Per judge: mean score over valid verdicts, and the invalid ones counted by reason."""
    out = {}
    for key in judges:
        column = JUDGE_PREFIX + key
        valid = [r.scores[column] for r in results if r.scores.get(column) is not None]
        invalid: dict[str, int] = {}
        for r in results:
            if key in r.judge_errors:
                reason = r.judge_errors[key].split(":")[0][:80]
                invalid[reason] = invalid.get(reason, 0) + 1
        out[key] = {"mean": float(np.mean(valid)) if valid else None, "n_valid": len(valid),
                    "n_invalid": sum(invalid.values()), "invalid": invalid}
    return out


def _count_states(states: Iterable[str | None]) -> dict[str, int]:
    out: dict[str, int] = {}
    for state in states:
        if state is not None:
            out[state] = out.get(state, 0) + 1
    return out


def summarise(results: list[SceneResult], metrics: list[Metric],
              columns: list[tuple[str, str]], *, cache_stats: dict[str, Any],
              judges: list[str] | None = None, usage: dict[str, Any] | None = None,
              headline: HeadlineColumn | None = None) -> dict[str, Any]:
    """A run's summary (``summary.json`` before the run adds its status and identity): means
    with honest denominators, model successes only and all scenes with fallbacks, over the
    run's score ``columns`` (name, direction: `visphy_core.scoring.score.score_columns`), the
    headline's and the judges' first and last.

    Success rates are given over all scenes and over the evaluable ones (scenes that ended in
    ``infra_error`` or ``data_error`` say nothing about the model); ``failures`` splits the
    model's failures from infrastructure/data failures.
    """
    ok = [r for r in results if r.model_success]
    scored = [r for r in results if r.system_success]
    columns = ([(headline.name, "higher")] if headline is not None else []) + list(columns)
    columns += [(JUDGE_PREFIX + key, "higher") for key in judges or []]
    head = None
    if headline is not None:
        def values(rows: list[SceneResult]) -> list[float]:
            return [r.scores[headline.name] for r in rows
                    if r.scores.get(headline.name) is not None]

        head = headline.entry(values(ok), values(scored))
    return {
        "headline": head,
        **counts(results),
        "isolation": sorted({r.isolation for r in results if r.isolation}),
        "metrics": metric_means(results, columns),
        # what each metric is and loads (weights, the BERTScore model…), as declared
        "metric_info": {m.name: m.describe() for m in metrics},
        "cache": cache_stats,
        "model_calls": sum(r.model_calls for r in results),
        "renders_done": sum(1 for r in results if r.render_wall_s is not None
                            and not r.render_cached),
        "spec": spec_counts(results),
        "prompt_versions": prompt_versions(results),
        "spec_track": _count_states(r.spec_track for r in results),
        "judges": judge_columns(results, judges or []),
        "usage": usage if usage is not None else {},
        "stage_seconds": stage_seconds(results),
    }
