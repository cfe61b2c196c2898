"""What a person sees in the terminal: a progress bar over scenes and the final summary table."""

from __future__ import annotations

import sys
from contextlib import contextmanager
from typing import Callable, Iterator

from rich.console import Console
from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn,
                           TimeElapsedColumn, TimeRemainingColumn)
from rich.table import Table

# A pipe or a log file gets 120 columns (rich's 80 would truncate the means table); a terminal
# keeps its own width.
console = Console(stderr=False, highlight=False,
                  width=None if sys.stdout.isatty() else 120)
#: the per-scene table's metric columns, by preference (every column is in the means table)
SCENE_COLUMNS = ("psnr", "ssim", "st_lpips", "track_pos_err", "flow_epe_dis")


@contextmanager
def scene_progress(total: int, enabled: bool = True) -> Iterator[Callable[[str], None]]:
    """Yields ``advance(scene_id)``: call it when a scene starts."""
    if not enabled:
        yield lambda _scene_id: None
        return
    progress = Progress(TextColumn("[bold]scenes"), BarColumn(), MofNCompleteColumn(),
                        TextColumn("{task.description}"), TimeElapsedColumn(),
                        TimeRemainingColumn(), console=Console(file=sys.stderr),
                        transient=False)
    started = {"n": 0}
    with progress:
        task = progress.add_task("", total=total)

        def advance(scene_id: str) -> None:
            if started["n"]:
                progress.advance(task)
            started["n"] += 1
            progress.update(task, description=scene_id)

        yield advance
        if started["n"]:
            progress.advance(task)
        progress.update(task, description="done")


def _fmt(value) -> str:
    if value is None:
        return "—"
    return f"{value:.4f}" if abs(value) < 10 else f"{value:.2f}"


def split_column(name: str) -> tuple[str, str]:
    """A score column as (metric, view): ``psnr`` (visphy), ``psnr.aligned`` / ``align.err``
    (aligned), ``paper.psnr`` (paper), ``spec.psnr`` (the spec track, unaligned)."""
    if name.startswith("spec."):
        base, view = split_column(name[len("spec."):])
        return base, "spec" if view == "visphy" else f"spec.{view}"
    if name.startswith("norm."):
        return name[len("norm."):], "norm"
    if name.startswith("paper."):
        return name[len("paper."):], "paper"
    if name.endswith(".aligned"):
        return name[:-len(".aligned")], "aligned"
    if name.startswith("align."):
        return name, "aligned"
    return name, "visphy"


def print_summary(summary: dict, results: list) -> None:
    """Per-scene table, then metric means with their denominators, then failures and cache."""
    # per scene: the primary columns only (visphy, unaligned); every column is in the means
    primary = [n for n in summary["metrics"] if "." not in n
               and not summary["metrics"][n]["unavailable"]]
    metric_names = ([n for n in SCENE_COLUMNS if n in primary]
                    or primary)[:5]
    table = Table(title=f"visphy · {summary['model']} × {summary['engine']} · "
                        f"{summary['dataset']} ({summary['n_scenes']} scenes)")
    table.add_column("scene")
    table.add_column("status")
    for name in metric_names:
        arrow = "↑" if summary["metrics"][name]["direction"] == "higher" else "↓"
        table.add_column(f"{name} {arrow}", justify="right")
    table.add_column("render", justify="right")
    for r in results:
        status = ("ok" if r.model_success and r.attempts == 1 else
                  "repaired" if r.model_success else
                  f"fallback ({r.failure_class})" if r.fallback else f"failed ({r.failure_class})")
        render = "cached" if r.render_cached else (
            f"{r.render_wall_s:.2f}s" if r.render_wall_s is not None else "—")
        table.add_row(r.scene_id, status, *[_fmt(r.scores.get(n)) for n in metric_names], render)
    console.print(table)

    means = Table(title="means over model successes · n · with fallbacks (all scenes)")
    means.add_column("metric", no_wrap=True)
    views = [v for v in ("visphy", "aligned", "paper", "spec", "norm")
             if any(split_column(c)[1] == v for c in summary["metrics"])]
    for v in views:
        means.add_column(v, justify="right", no_wrap=True)
    means.add_column("n", justify="right", no_wrap=True)
    means.add_column("with fallbacks", justify="right", no_wrap=True)
    rows: dict[str, dict[str, dict]] = {}
    unavailable: dict[str, str] = {}
    for name, m in summary["metrics"].items():
        base, view = split_column(name)
        if m["unavailable"]:
            unavailable.setdefault(base, m["unavailable"])
            continue
        rows.setdefault(base, {})[view] = m
    for base, by_view in rows.items():
        first = by_view.get("visphy") or by_view.get("aligned") or next(iter(by_view.values()))
        n = first["n_model_success"]
        arrow = "↑" if first["direction"] == "higher" else "↓"
        cells = []
        for v in views:
            m = by_view.get(v)
            cell = "" if m is None else _fmt(m["mean_model_success"])
            if m is not None and m["n_model_success"] != n:
                cell += f" (n={m['n_model_success']})"
            cells.append(cell)
        means.add_row(f"{base} {arrow}", *cells, str(n),
                      f"{_fmt(first['mean_with_fallbacks'])} (n={first['n_with_fallbacks']})")
    for base, why in unavailable.items():
        means.add_row(base, "unavailable", *[""] * (len(views) + 1))
    reasons = sorted(set(unavailable.values()))
    console.print(means)
    for why in reasons:
        names = ", ".join(b for b, w in unavailable.items() if w == why)
        console.print(f"unavailable: {names}: {why}", soft_wrap=True)
    n = summary["n_scenes"]
    n_eval = summary.get("n_evaluable", n)
    failures = summary.get("failures") or {}
    model_f, other_f = failures.get("model") or {}, failures.get("infra_or_data") or {}
    console.print(
        f"model success {summary['model_success']}/{n}"
        + (f" ({summary['model_success']}/{n_eval} evaluable)" if n_eval != n else "")
        + f" · system success {summary['system_success']}/{n} · fallbacks "
        f"{summary['fallbacks']} · repaired {summary['repaired']}"
        + (f" · model failures {model_f}" if model_f else "")
        + (f" · not counted (infrastructure/data) {other_f}" if other_f else ""))
    cache = summary["cache"]
    render = cache.get("render", {"hits": 0, "misses": 0})
    dropped = sum(v.get("dropped", 0) for v in cache.values())
    if dropped:
        console.print(f"cache: {dropped} corrupt entr{'y' if dropped == 1 else 'ies'} dropped "
                      "and recomputed (see the warnings above)")
    console.print(f"cache: renders {render['hits']} hit / {render['misses']} rendered · "
                  f"replies {cache.get('response', {}).get('hits', 0)} hit · "
                  f"scores {cache.get('score', {}).get('hits', 0)} hit")
    usage = summary.get("usage") or {}
    for stage, t in usage.items():
        if stage == "all" or not (t["calls"] or t["cache_hits"]):
            continue
        cost = f"${t['cost_usd']:.4f}" + (f" (${t['cost_usd_incl_cached']:.4f} incl. cached)"
                                           if t["cache_hits"] else "")
        console.print(f"{stage}: {t['calls']} call(s), {t['cache_hits']} cached, "
                      f"{t['errors']} failed · tokens in {t['input_tokens']:,} / out "
                      f"{t['output_tokens']:,} · {cost}")
    spec = summary.get("spec") or {}
    if spec.get("valid") or spec.get("invalid"):
        console.print(f"scene spec S: {spec['valid']} valid, {spec['invalid']} invalid, "
                      f"{spec['absent']} absent")
    track = summary.get("spec_track") or {}
    if track:
        console.print("spec track (S simulated and replayed): " + ", ".join(
            f"{n} {state.replace('_', ' ')}" for state, n in sorted(track.items())))
    for key, j in (summary.get("judges") or {}).items():
        console.print(f"judge {key}: {j['n_valid']} valid verdict(s), {j['n_invalid']} invalid"
                      + (f" {j['invalid']}" if j["invalid"] else ""))
    console.print(f"run directory: {summary['run_dir']}", soft_wrap=True)
