"""What a person sees in the terminal: progress per stage while a run goes, then the summary
table, the report's path and the command that opens the run in MLflow."""

from __future__ import annotations

import sys
import threading
import time
from collections import Counter
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    ProgressColumn,
    TextColumn,
    TimeElapsedColumn,
)
from rich.table import Table
from rich.text import Text

from visphy_core.calls.retry import RETRYABLE, kind_of_description
from visphy_core.infra.events import STAGES, StageEvents
from visphy_core.tracking import mlflow_command

#: A pipe or a log file has no width: lines and tables are written whole, however wide (rich
#: would cut them at 80 columns).
UNBOUNDED = 100_000


def summary_console() -> Console:
    """Where the end-of-run summary goes: stdout as it is now (a test's capture included). A
    terminal keeps its width (table cells fold onto more lines, never cut with "…"); anything
    else gets `UNBOUNDED` columns."""
    tty = sys.stdout.isatty()
    return Console(stderr=False, highlight=False, width=None if tty else UNBOUNDED,
                   soft_wrap=not tty)
#: the per-scene table's metric columns, by preference (every column is in the means table)
SCENE_COLUMNS = ("psnr", "ssim", "st_lpips", "track_pos_err", "flow_epe_dis")


class StageProgress(StageEvents):
    """One line per stage: scenes done / total, how many scenes are in that stage now (scenes
    of a run with several workers go through the stages side by side), the seconds spent in it
    (summed over scenes) and the time since the run started.

    Drawn live (rich, on stderr) when ``live``; either way `final_line` sums it up (counts,
    skipped scenes and seconds per stage), printed at the end when nothing was drawn.
    Thread-safe: every scene's worker reports here.
    """

    def __init__(self, total: int, stages: tuple[str, ...] | list[str], live: bool,
                 out: Console | None = None, clock: Callable[[], float] = time.monotonic):
        self.clock = clock
        self.total = total
        self.stages = [s for s in STAGES if s in stages] + [s for s in stages
                                                             if s not in STAGES]
        self.done: dict[str, set[str]] = {s: set() for s in self.stages}
        self.skipped = dict.fromkeys(self.stages, 0)
        self.spent = dict.fromkeys(self.stages, 0.0)
        #: (stage, scene id) -> when the scene entered the stage
        self._since: dict[tuple[str, str], float] = {}
        #: the same for a scene back in a stage it is done with (a repair call, the reference
        #: renders of its score stage): its time adds up, it is no new work on the bar
        self._again: dict[tuple[str, str], float] = {}
        #: the most scenes that were in each stage at once
        self.most_in_flight = dict.fromkeys(self.stages, 0)
        self._lock = threading.RLock()
        self.started = clock()
        self.progress = None
        self.tasks: dict[str, int] = {}
        if live:
            self.progress = Progress(
                TextColumn("[bold]{task.fields[stage]:<8}"), BarColumn(bar_width=24),
                MofNCompleteColumn(), TextColumn("{task.fields[in_flight]:>11}"),
                SpentColumn(self), TimeElapsedColumn(),
                TextColumn("{task.description}"),
                console=out or Console(file=sys.stderr), transient=False)
            for stage in self.stages:
                self.tasks[stage] = self.progress.add_task("", total=total, stage=stage,
                                                           in_flight="")

    def in_flight(self, stage: str) -> list[str]:
        """The scenes in ``stage`` now, in the order they entered it."""
        with self._lock:
            return [sid for (st, sid) in self._since if st == stage]

    def spent_now(self, stage: str) -> float:
        """Seconds spent in ``stage`` so far, summed over scenes, the scenes in it now
        included (so a running stage's time advances while it runs)."""
        with self._lock:
            now = self.clock()
            return self.spent[stage] + sum(now - since for since_of in (self._since, self._again)
                                           for (st, _), since in since_of.items()
                                           if st == stage)

    def begin(self, stage: str, scene_id: str) -> None:
        if stage not in self.done:
            return
        with self._lock:
            if scene_id in self.done[stage]:  # back in a stage it is done with: not new work
                self._again.setdefault((stage, scene_id), self.clock())
                return
            self._since[(stage, scene_id)] = self.clock()
            now = self.in_flight(stage)
            self.most_in_flight[stage] = max(self.most_in_flight[stage], len(now))
            self._show(stage)

    def end(self, stage: str, scene_id: str) -> None:
        if stage not in self.done:
            return
        with self._lock:
            since = self._since.pop((stage, scene_id), None)
            if since is None:
                since = self._again.pop((stage, scene_id), None)
            if since is not None:
                self.spent[stage] += self.clock() - since
            self._count(stage, scene_id)

    def scene_finished(self, scene_id: str) -> None:
        with self._lock:
            for stage in self.stages:
                self._since.pop((stage, scene_id), None)
                self._again.pop((stage, scene_id), None)
                if scene_id not in self.done[stage]:
                    self.skipped[stage] += 1
                    self._count(stage, scene_id)
                else:
                    self._show(stage)

    def _show(self, stage: str, advance: int = 0) -> None:
        """Redraw ``stage``'s line: in flight now, seconds, the scene(s) in it."""
        if self.progress is None:
            return
        now = self.in_flight(stage)
        finished = len(self.done[stage]) >= self.total and not now
        description = ("done" if finished else
                       now[0] + (f" +{len(now) - 1}" if len(now) > 1 else "") if now else "")
        self.progress.update(self.tasks[stage], advance=advance,
                             in_flight=f"{len(now)} in flight" if now else "",
                             description=description)

    def _count(self, stage: str, scene_id: str) -> None:
        first = scene_id not in self.done[stage]
        self.done[stage].add(scene_id)
        self._show(stage, advance=1 if first else 0)

    def final_line(self) -> str:
        parts = []
        for stage in self.stages:
            skipped = f", {self.skipped[stage]} skipped" if self.skipped[stage] else ""
            parts.append(f"{stage} {len(self.done[stage])}/{self.total} "
                         f"({self.spent[stage]:.1f} s{skipped})")
        return (f"stages: {' · '.join(parts)} · {self.clock() - self.started:.1f} s "
                "in all")


class SpentColumn(ProgressColumn):
    """A stage's seconds so far (`StageProgress.spent_now`), read at each refresh: a stage with
    scenes in it shows its time advancing, not the seconds of the scenes that left it."""

    def __init__(self, stages: StageProgress):
        super().__init__()
        self.stages = stages

    def render(self, task) -> Text:
        return Text(f"{self.stages.spent_now(task.fields['stage']):.1f}s".rjust(7))


@contextmanager
def stage_progress(total: int, stages: tuple[str, ...] | list[str], enabled: bool = True,
                   out: Console | None = None) -> Iterator[StageProgress]:
    """Yields the `StageProgress` to feed. Live bars when ``enabled`` and stdout is a
    terminal (``out`` forces them onto that console); otherwise nothing until the end, then the
    one `final_line` on stderr (also after an interruption: what was done so far)."""
    live = out is not None or (enabled and sys.stdout.isatty())
    stages_progress = StageProgress(total, stages, live=live, out=out)
    try:
        if stages_progress.progress is not None:
            with stages_progress.progress:
                yield stages_progress
        else:
            yield stages_progress
    finally:
        if stages_progress.progress is None:
            print(stages_progress.final_line(), file=sys.stderr, flush=True)


def print_where_to_look(report: Path | None, tracking_uri: str | None) -> None:
    """After the summary table: the HTML report and the command that opens the run in MLflow
    (one line each; each only when there is one)."""
    console = summary_console()
    if report is not None:
        console.print(f"report: {report}", markup=False, soft_wrap=True)
    if tracking_uri:
        console.print(f"MLflow: {mlflow_command(tracking_uri)}", markup=False,
                      soft_wrap=True)


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


def print_summary(summary: dict, results: list, calls_heading: str | None = None) -> None:
    """Per-scene table, then metric means with their denominators, then failures and cache;
    last, on stderr, the `provider_failures_line` when a provider failed some scenes.
    ``calls_heading``: a line before the model/judge call lines (a re-score says they are the
    run's, the original run's calls included). Nothing is cut: see `summary_console`."""
    console = summary_console()
    # per scene: the primary columns only (visphy, unaligned); every column is in the means
    primary = [n for n in summary["metrics"] if "." not in n
               and not summary["metrics"][n]["unavailable"]]
    head = summary.get("headline") or {}
    first = [head["metric"]] if head.get("metric") in primary else []
    metric_names = first + ([n for n in SCENE_COLUMNS if n in primary]
                            or [n for n in primary if n not in first])[:5 - len(first)]
    table = Table(title=f"visphy · {summary['model']} × {summary['engine']} · "
                        f"{summary['dataset']} ({summary['n_scenes']} scenes)")
    table.add_column("scene", overflow="fold")
    table.add_column("status", overflow="fold")
    for name in metric_names:
        arrow = "↑" if summary["metrics"][name]["direction"] == "higher" else "↓"
        table.add_column(f"{name} {arrow}", justify="right", overflow="fold")
    table.add_column("render", justify="right", overflow="fold")
    for r in results:
        render = "cached" if r.render_cached else (
            f"{r.render_wall_s:.2f}s" if r.render_wall_s is not None else "—")
        table.add_row(r.scene_id, r.outcome, *[_fmt(r.scores.get(n)) for n in metric_names], render)
    console.print(table)
    if head.get("metric"):
        ci = head.get("ci")
        interval = f" [{_fmt(ci[0])}, {_fmt(ci[1])}]" if ci else ""
        small = " (fewer than 10 scenes: a wide interval)" if head.get("small_sample") else ""
        console.print(f"[bold]headline {head['metric']} ↑[/bold] {_fmt(head.get('mean'))}"
                      f"{interval} over {head.get('n', 0)} scored scene(s), 95% bootstrap "
                      f"interval; a still clip scores 0, the ground truth about 1{small}",
                      soft_wrap=True)

    means = Table(title="means over model successes · n · with fallbacks (all scenes)")
    means.add_column("metric", overflow="fold")
    views = [v for v in ("visphy", "aligned", "paper", "spec", "norm")
             if any(split_column(c)[1] == v for c in summary["metrics"])]
    for v in views:
        means.add_column(v, justify="right", overflow="fold")
    means.add_column("n", justify="right", overflow="fold")
    means.add_column("with fallbacks", justify="right", overflow="fold")
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
    if calls_heading and any(t["calls"] or t["cache_hits"] for stage, t in usage.items()
                             if stage != "all"):
        console.print(calls_heading, soft_wrap=True)
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
    line = provider_failures_line(summary, results)
    if line:
        print(line, file=sys.stderr, flush=True)


def provider_failures_line(summary: dict, results: list) -> str | None:
    """One line for the scenes a provider failed after its retries (``model_error`` rows), by
    error kind, and what to do: the transient kinds (`RETRYABLE`) may go away on a rerun, which
    calls the provider again for those scenes only (every reply already received is answered by
    the cache); a rerun sends the others' requests as they were. ``other``: a detail that names
    no kind (a model that is no provider API). None when no scene failed so.

    A re-score or a merge (``rescored_from`` / ``merged_from`` in ``summary``) shows the rows of
    earlier runs: it is the command of the run they come from that retries them."""
    kinds = Counter((kind_of_description(r.failure_detail) or "other")
                    for r in results if r.failure_class == "model_error")
    if not kinds:
        return None
    n = sum(kinds.values())
    named = ", ".join(f"{kind} ×{count}" for kind, count in sorted(kinds.items()))
    command = ("command of the run these rows come from"
               if summary.get("rescored_from") or summary.get("merged_from")
               else "same command")
    transient = sum(c for k, c in kinds.items() if k in RETRYABLE)
    advice = []
    if transient:
        which = "them" if transient == n else f"the {transient} transient one(s)"
        advice.append(f"rerun the {command} to retry {which}; replies already received are "
                      "cached")
    if transient < n:
        lasting = ", ".join(k for k in sorted(kinds) if k not in RETRYABLE)
        advice.append(f"{lasting}: not a transient kind, see each row's failure_detail")
    return (f"{n} scene{'s' if n != 1 else ''} failed on provider errors ({named}): "
            + "; ".join(advice))
