"""What a person sees in the terminal: progress per stage while a run goes, then the summary
table, the report's path and the command that opens the run in MLflow."""

# size: everything a run prints for people (live progress, log lines, the summary tables and
# their legend) in one module, so one place decides what the terminal and a log show

from __future__ import annotations

import sys
import threading
import time
from collections import Counter
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator

from rich import box
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
from visphy_core.infra.numbers import number
from visphy_core.infra.progress import EVERY, PlainLines, duration, output_columns, rate_and_eta
from visphy_core.results.columns import (
    ALIGN_PREFIX,
    ALIGNED_SUFFIX,
    NORM_PREFIX,
    PAPER_PREFIX,
    SPEC_PREFIX,
)
from visphy_core.results.layout import RESULTS_JSONL

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
#: the default summary's width: it fits this many columns (and reads at 80)
SUMMARY_WIDTH = 100
#: the per-scene table's metric columns, by preference (every column is in the means table)
SCENE_COLUMNS = ("psnr", "ssim", "track_pos_err", "st_lpips", "flow_epe_dis")


class StageProgress(StageEvents):
    """One line per stage: scenes done / total, how many scenes are in that stage now (scenes
    of a run with several workers go through the stages side by side), the seconds spent in it
    (summed over scenes) and the time since the run started.

    Drawn live (rich, on stderr) when ``live``; else, when ``plain``, written as plain lines
    for a log (`stage_line` per stage at most every few seconds, `heartbeat_line` when nothing
    else was written for a while: see `visphy_core.infra.progress`). Either way `final_line`
    sums it up (wall time, then counts, skipped scenes and seconds per stage summed over
    scenes), printed at the end when nothing was drawn. Thread-safe: every scene's worker
    reports here.
    """

    def __init__(self, total: int, stages: tuple[str, ...] | list[str], live: bool,
                 out: Console | None = None, clock: Callable[[], float] = time.monotonic,
                 plain: bool = False):
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
        #: when each stage saw its first scene (its rate and ETA count from there)
        self.first_begin: dict[str, float] = {}
        #: plain lines for a log (`visphy_core.infra.progress.PlainLines`), when ``plain``
        self.lines: PlainLines | None = None
        if plain and not live:
            self.lines = PlainLines(heartbeat=self.heartbeat_line, clock=clock)
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
            self.first_begin.setdefault(stage, self.clock())
            now = self.in_flight(stage)
            self.most_in_flight[stage] = max(self.most_in_flight[stage], len(now))
            self._show(stage)
            if self.lines is not None:
                self.lines.emit(stage, self.stage_line(stage))

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
        if self.lines is not None and first:
            self.lines.emit(stage, self.stage_line(stage),
                            force=len(self.done[stage]) >= self.total)

    def stage_line(self, stage: str) -> str:
        """``render 3/8 · 2 in flight · 1.5/min · ETA 3 min 20 s · 25 s elapsed``: one stage
        for a log (rate and ETA from the scenes it finished since its first began)."""
        with self._lock:
            now = self.clock()
            n, flying = len(self.done[stage]), self.in_flight(stage)
            parts = [f"{stage} {n}/{self.total}"]
            if n >= self.total and not flying:
                parts.append("done")
            if flying:
                parts.append(f"{len(flying)} in flight")
            if self.skipped[stage]:
                parts.append(f"{self.skipped[stage]} skipped")
            pace = rate_and_eta(n, self.total, now - self.first_begin.get(stage, self.started))
            if pace and n < self.total:
                parts.append(pace)
            parts.append(f"{duration(now - self.started)} elapsed")
            return " · ".join(parts)

    def heartbeat_line(self) -> str:
        """Every stage not done yet, on one line, for a log that had nothing else to say:
        ``still working, 1 min 05 s elapsed: generate 3/8 (2 in flight), score 1/8``."""
        with self._lock:
            parts = []
            for stage in self.stages:
                flying = self.in_flight(stage)
                n = len(self.done[stage])
                if n >= self.total and not flying:
                    continue
                parts.append(f"{stage} {n}/{self.total}"
                             + (f" ({len(flying)} in flight)" if flying else ""))
            elapsed = duration(self.clock() - self.started)
            return f"still working, {elapsed} elapsed: " + (", ".join(parts) or "closing")

    def final_line(self) -> str:
        """``stages: wall 99.3 s · summed over scenes: generate 4/4 12.1 s, score 4/4
        187.7 s``: the run's wall time, then per stage the scenes done and the seconds spent
        in it added up over scenes (several scenes run side by side, so a stage's sum can
        exceed the wall time)."""
        parts = []
        for stage in self.stages:
            skipped = f" ({self.skipped[stage]} skipped)" if self.skipped[stage] else ""
            parts.append(f"{stage} {len(self.done[stage])}/{self.total}{skipped} "
                         f"{self.spent[stage]:.1f} s")
        return (f"stages: wall {self.clock() - self.started:.1f} s · summed over scenes: "
                + ", ".join(parts))


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
    terminal (``out`` forces them onto that console); otherwise, when ``enabled``, plain
    progress lines on stderr as the run goes (a first line at once, then per stage and a
    heartbeat: never silent for more than `visphy_core.infra.progress.QUIET` seconds); at the
    end the one `final_line` on stderr (also after an interruption: what was done so far)."""
    live = out is not None or (enabled and sys.stdout.isatty())
    stages_progress = StageProgress(total, stages, live=live, out=out, plain=enabled)
    lines = stages_progress.lines
    try:
        if stages_progress.progress is not None:
            with stages_progress.progress:
                yield stages_progress
        else:
            if lines is not None:
                lines.emit("run", f"{total} scene{'s' if total != 1 else ''} to run · stages "
                           f"{', '.join(stages_progress.stages)} · a progress line every "
                           f"{EVERY:.0f} s or so per stage", force=True)
                lines.start()
            yield stages_progress
    finally:
        if lines is not None:
            lines.stop()
        if stages_progress.progress is None:
            print(stages_progress.final_line(), file=sys.stderr, flush=True)


def print_where_to_look(report: Path | None, lines: list[str]) -> None:
    """After the summary table: the HTML report, then what the run's observers point to
    (`visphy_core.api.run_context.RunContext.where_to_look`: the command that opens the run in
    MLflow), one line each."""
    console = summary_console()
    if report is not None:
        console.print(f"report: {report}", markup=False, soft_wrap=True)
    for line in lines:
        console.print(line, markup=False, soft_wrap=True)


def _fmt(value) -> str:
    return number(value)


def split_column(name: str) -> tuple[str, str]:
    """A score column as (metric, view): ``psnr`` (visphy), ``psnr.aligned`` / ``align.err``
    (aligned), ``paper.psnr`` (paper), ``spec.psnr`` (the spec track, unaligned)."""
    if name.startswith(SPEC_PREFIX):
        base, view = split_column(name[len(SPEC_PREFIX):])
        return base, "spec" if view == "visphy" else f"{SPEC_PREFIX}{view}"
    if name.startswith(NORM_PREFIX):
        return name[len(NORM_PREFIX):], "norm"
    if name.startswith(PAPER_PREFIX):
        return name[len(PAPER_PREFIX):], "paper"
    if name.endswith(ALIGNED_SUFFIX):
        return name[:-len(ALIGNED_SUFFIX)], "aligned"
    if name.startswith(ALIGN_PREFIX):
        return name, "aligned"
    return name, "visphy"


#: what each pairing column of the full means table is (docs/metrics.md)
LEGEND = (
    ("visphy", "the generated clip against the ground truth frame by frame (unaligned)"),
    ("aligned", "the same after the best time offset (align.offset, align.err)"),
    ("paper", "the paper's protocol (its alignment and resampling)"),
    ("spec", "the clip visphy simulates from the model's scene spec S, unaligned"),
    ("norm", "variance-normalised, higher is better: 0 = the first frame held still, "
             "1 = as close as the ground truth's twin (re-simulated after an imperceptible "
             "nudge); below 0 and above 1 are kept"),
)


def shorten_ids(ids: list[str]) -> tuple[str, list[str]]:
    """The prefix every id shares (cut at a ``-`` or ``_``, kept only when it saves at least 4
    characters) and the ids without it; ``("", ids)`` when there is none worth cutting."""
    if len(ids) < 2:
        return "", list(ids)
    prefix = ids[0]
    for other in ids[1:]:
        while not other.startswith(prefix):
            prefix = prefix[:-1]
    cut = max(prefix.rfind("-"), prefix.rfind("_")) + 1
    prefix = prefix[:cut]
    if len(prefix) < 4 or any(len(i) == len(prefix) for i in ids):
        return "", list(ids)
    return prefix, [i[len(prefix):] for i in ids]


def _headline_lines(head: dict) -> list[str]:
    """The headline with its interval when there is one (else why not), then its meaning."""
    if not head.get("metric"):
        return []
    n = head.get("n", 0)
    ci = head.get("ci")
    small = " (under 10 scenes: a wide one)" if ci and head.get("small_sample") else ""
    mean = _fmt(head.get("mean")) if n else "—"
    if ci:
        interval = f", 95% bootstrap interval [{_fmt(ci[0])}, {_fmt(ci[1])}]{small}"
    elif n == 1:
        interval = " (no interval: a bootstrap needs at least 2 scored scenes)"
    elif n == 0:
        interval = " (no scene scored)"
    else:
        interval = " (no interval)"
    return [f"[bold]headline {head['metric']} ↑ {mean}[/bold] over {n} scored "
            f"scene{'s' if n != 1 else ''}{interval}",
            "  0 = no better than the first frame held still, "
            + ("1 ≈ the ground truth's twin" if head.get("ceiling") == "twin"
               else "1 = moves as the truth does")
            + "; a fallback scores 0"]


def summary_width(full: bool = False) -> int:
    """Columns of the summary: ``COLUMNS`` or the terminal's, at most `SUMMARY_WIDTH` for the
    default summary (a log gets `SUMMARY_WIDTH`); the full one on a pipe is not folded
    (`UNBOUNDED`)."""
    width = output_columns(UNBOUNDED if full else SUMMARY_WIDTH)
    return width if full else max(40, min(width, SUMMARY_WIDTH))


def success_label(summary: dict) -> str:
    """What a run's own successes are: a model's programs (or clips), or a baseline's clips,
    which are no model's success."""
    if summary.get("model_baseline"):
        return "baseline clips made"
    return "model success"


def _print_scene_table(console: Console, results: list, metrics: dict,
                       headline: str | None, keys: list[str]) -> None:
    """One row per scene: its outcome, the headline, the key metrics and its render time."""
    prefix, short_ids = shorten_ids([r.scene_id for r in results])
    table = Table(box=box.SIMPLE_HEAD, pad_edge=False, show_edge=False)
    table.add_column("scene", overflow="fold")
    table.add_column("outcome", overflow="fold")
    if headline:
        table.add_column("headline ↑", justify="right", no_wrap=True)
    for name in keys:
        arrow = "↑" if metrics[name]["direction"] == "higher" else "↓"
        table.add_column(f"{name} {arrow}", justify="right", overflow="fold")
    table.add_column("render", justify="right", no_wrap=True)
    for r, sid in zip(results, short_ids):
        render = "cached" if r.render_cached else (
            f"{r.render_wall_s:.1f} s" if r.render_wall_s is not None else "—")
        cells = [_fmt(r.scores.get(headline))] if headline else []
        table.add_row(sid, r.outcome, *cells, *[_fmt(r.scores.get(n)) for n in keys], render)
    console.print(table)
    if prefix:
        console.print(f"(scene ids without the prefix they share: {prefix})")


def _print_cache(console: Console, summary: dict) -> None:
    """The cache's hits, and the corrupt entries it dropped."""
    cache = summary["cache"]
    render = cache.get("render", {"hits": 0, "misses": 0})
    dropped = sum(v.get("dropped", 0) for v in cache.values())
    if dropped:
        console.print(f"cache: {dropped} corrupt entr{'y' if dropped == 1 else 'ies'} dropped "
                      "and recomputed (see the warnings above)")
    console.print(f"cache: renders {render['hits']} hit / {render['misses']} rendered · "
                  f"replies {cache.get('response', {}).get('hits', 0)} hit · "
                  f"scores {cache.get('score', {}).get('hits', 0)} hit")


def print_summary(summary: dict, results: list, calls_heading: str | None = None,
                  mode: str = "short", wall_s: float | None = None) -> None:
    """The end of a run for people, within `SUMMARY_WIDTH` columns: the title, the headline
    with its interval and what it means, one row per scene (outcome, headline, a few key
    metrics), the means per metric family; with ``mode="full"`` every metric under every
    pairing with a legend. Then failures, cache, calls, the time (``wall_s``: the run's wall
    clock; stage seconds summed over scenes) and, on stderr, the `provider_failures_line` when
    a provider failed some scenes. ``calls_heading``: a line before the model/judge call lines
    (a re-score says they are the run's, the original run's calls included). Cells fold onto
    more lines; nothing is cut with "…"."""
    full = mode == "full"
    console = Console(stderr=False, highlight=False, width=summary_width(full),
                      soft_wrap=False)
    metrics = summary["metrics"]
    primary = [n for n in metrics if "." not in n and not metrics[n]["unavailable"]]
    head = summary.get("headline") or {}
    headline = head.get("metric") if head.get("metric") in primary else None
    keys = [n for n in SCENE_COLUMNS if n in primary and n != headline]
    keys = (keys or [n for n in primary if n != headline])[:3 if headline else 4]
    console.print(f"[bold]visphy · {summary['model']} × {summary['engine']} · "
                  f"{summary['dataset']} ({summary['n_scenes']} scenes)[/bold]", soft_wrap=False)
    for line in _headline_lines(head):
        console.print(line, soft_wrap=False)

    _print_scene_table(console, results, metrics, headline, keys)

    rows: dict[str, dict[str, dict]] = {}
    unavailable: dict[str, str] = {}
    for name, m in metrics.items():
        base, view = split_column(name)
        if m["unavailable"]:
            unavailable.setdefault(base, m["unavailable"])
            continue
        rows.setdefault(base, {})[view] = m
    if full:
        _print_full_means(console, metrics, rows, unavailable)
    else:
        _print_family_means(console, summary, rows, headline)
    reasons = sorted(set(unavailable.values()))
    for why in reasons:
        names = ", ".join(b for b, w in unavailable.items() if w == why)
        console.print(f"unavailable: {names}: {why}", soft_wrap=False)
    n = summary["n_scenes"]
    n_eval = summary.get("n_evaluable", n)
    failures = summary.get("failures") or {}
    model_f, other_f = failures.get("model") or {}, failures.get("infra_or_data") or {}
    console.print(
        f"{success_label(summary)} {summary['model_success']}/{n}"
        + (f" ({summary['model_success']}/{n_eval} evaluable)" if n_eval != n else "")
        + f" · system success {summary['system_success']}/{n} · fallbacks "
        f"{summary['fallbacks']} · repaired {summary['repaired']}"
        + (f" · model failures {model_f}" if model_f else "")
        + (f" · not counted (infrastructure/data) {other_f}" if other_f else ""))
    _print_cache(console, summary)
    usage = summary.get("usage") or {}
    if calls_heading and any(t["calls"] or t["cache_hits"] for stage, t in usage.items()
                             if stage != "all"):
        console.print(calls_heading, soft_wrap=False)
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
    time_line = _time_line(summary.get("stage_seconds") or {}, wall_s,
                           summary.get("ground_truth"))
    if time_line:
        console.print(time_line, soft_wrap=False)
    console.print(f"run directory: {summary['run_dir']}", soft_wrap=True)
    line = provider_failures_line(summary, results)
    if line:
        print(line, file=sys.stderr, flush=True)


#: the seconds of `summary.json`'s ``stage_seconds``, as the time line names them
STAGE_SECONDS = (("model_latency_s", "model calls"), ("render_wall_s", "render"),
                 ("reference_render_wall_s", "reference renders"),
                 ("scoring_wall_s", "score"), ("judge_wall_s", "judge"))


def _time_line(stage_seconds: dict, wall_s: float | None,
               ground_truth: dict | None = None) -> str | None:
    """``time: wall 99.3 s (ground truth 40.2 s of it) · summed over scenes: render 12.1 s,
    score 187.7 s`` (scenes run side by side, so a stage's sum can exceed the wall time; the
    ground-truth stage is named when it computed anything)."""
    parts = [f"{label} {stage_seconds[key]['total']:.1f} s" for key, label in STAGE_SECONDS
             if ((stage_seconds.get(key) or {}).get("total") or 0) >= 0.05]
    if not parts and wall_s is None:
        return None
    gt = ground_truth or {}
    first = (f" (ground truth {gt['wall_s']:.1f} s of it)"
             if gt.get("computed_now") and gt.get("wall_s") else "")
    wall = f"wall {wall_s:.1f} s{first}" if wall_s is not None else ""
    summed = f"summed over scenes: {', '.join(parts)}" if parts else ""
    return "time: " + " · ".join(p for p in (wall, summed) if p)


def _print_family_means(console: Console, summary: dict, rows: dict, headline: str | None
                        ) -> None:
    """One row per metric family: the mean variance-normalised score of its metrics (0 = the
    still clip, 1 = the twin) when the run has them, and each metric's mean over the model's
    successes (the visphy pairing)."""
    info = summary.get("metric_info") or {}
    families: dict[str, list[str]] = {}
    for base, by_view in rows.items():
        if base == headline or "visphy" not in by_view or base.startswith(ALIGN_PREFIX):
            continue
        family = (info.get(base) or {}).get("family") or "other"
        families.setdefault(family, []).append(base)
    if not families:
        return
    has_norm = any("norm" in by_view for by_view in rows.values())
    n = max((by_view["visphy"]["n_model_success"] for by_view in rows.values()
             if "visphy" in by_view), default=0)
    console.print(f"means per family (model successes, n = {n}, visphy pairing)"
                  + ("; norm: 0 = still clip, 1 = twin" if has_norm else ""),
                  soft_wrap=False)
    table = Table(box=box.SIMPLE_HEAD, pad_edge=False, show_edge=False)
    table.add_column("family", no_wrap=True)
    if has_norm:
        table.add_column("norm ↑", justify="right", no_wrap=True)
    table.add_column("metric means (↓: lower is better)", overflow="fold")
    for family, names in families.items():
        means = []
        for base in names:
            m = rows[base]["visphy"]
            arrow = "" if m["direction"] == "higher" else "↓"
            means.append(f"{base}{arrow} {_fmt(m['mean_model_success'])}")
        cells = [family]
        if has_norm:
            normed = [rows[b]["norm"]["mean_model_success"] for b in names
                      if "norm" in rows[b] and rows[b]["norm"]["mean_model_success"] is not None]
            cells.append(_fmt(sum(normed) / len(normed)) if normed else "—")
        table.add_row(*cells, ", ".join(means))
    console.print(table)
    console.print("every metric under every pairing: run.summary=full; per scene: "
                  f"{RESULTS_JSONL} and the report", soft_wrap=False)


def _print_full_means(console: Console, metrics: dict, rows: dict, unavailable: dict) -> None:
    """Every metric's mean under every pairing, its n and its mean over all scenes (fallback
    clips included), with the legend of the pairings."""
    means = Table(title="means over the model's successes · n · over all scenes (fallbacks "
                        "included)", title_justify="left")
    means.add_column("metric", overflow="fold")
    views = [v for v in ("visphy", "aligned", "paper", "spec", "norm")
             if any(split_column(c)[1] == v for c in metrics)]
    for v in views:
        means.add_column(v, justify="right", overflow="fold")
    means.add_column("n", justify="right", overflow="fold")
    means.add_column("all scenes", justify="right", overflow="fold")
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
    for base in unavailable:
        means.add_row(base, "unavailable", *[""] * (len(views) + 1))
    console.print(means)
    for view, meaning in LEGEND:
        if view in views:
            console.print(f"  {view}: {meaning}", soft_wrap=False)


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
