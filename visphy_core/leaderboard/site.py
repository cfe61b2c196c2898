"""`build_site`: finished runs (and study folders holding runs) to a static leaderboard site.

Layout of the output folder::

    index.html            the leaderboard: measured rows (rank = tie label), reference rows
    breakdowns.html       model × engine matrices, difficulty, template, label, 2D/3D
    entries/<row>.html    one row: headline, best and worst scenes side by side, families
    runs/<row>/index.html that run's report, media capped (`visphy_core.leaderboard.clips`)
    clips/<row>/media/    the best and worst scenes' clips
    metrics/<name>.html   one page per registered metric, and the headline's
    leaderboard.json      the rows, ranks, ties and warnings as data
    scores.parquet        every row's per-scene scores, the tidy table of ``visphy export``
                          (`visphy_core.results.tidy.tidy_scores`) with the row's label

Rebuilding into the same folder rewrites the pages and copies only the media that changed.
"""

from __future__ import annotations

import datetime as dt
import json
import shutil
from dataclasses import dataclass, field
from pathlib import Path

from visphy_core.analysis.load import label_runs
from visphy_core.analysis.load import load_run as load_run_with_ratings
from visphy_core.infra.errors import UserError
from visphy_core.infra.files import atomic_write
from visphy_core.infra.progress import track
from visphy_core.leaderboard.breakdowns import breakdown, engine_matrix
from visphy_core.leaderboard.clips import (
    MAX_CLIP_MB,
    MAX_REPORT_MB,
    best_and_worst,
    copy_report,
)
from visphy_core.leaderboard.entries import Entry, make_entry
from visphy_core.leaderboard.metric_pages import write_metric_pages
from visphy_core.leaderboard.pages import breakdowns_page, entry_page, index_page
from visphy_core.leaderboard.references import Reference
from visphy_core.leaderboard.ties import Standing, standings

#: Files of a folder that mark it as a leaderboard site (safe to write over).
MARKER = "leaderboard.json"
#: The per-scene scores of every row (the tidy table of `visphy export`).
SCORES = "scores.parquet"


@dataclass
class SiteOptions:
    title: str = "visphy leaderboard"
    references: list[Reference] = field(default_factory=list)
    labels: dict[str, str] | None = None
    clips_per_side: int = 2
    max_clip_mb: float = MAX_CLIP_MB
    max_report_mb: float = MAX_REPORT_MB
    with_reports: bool = True
    progress: bool = True


@dataclass
class Site:
    """What `build_site` made."""

    index: Path
    entries: list[Entry]
    standings: dict[str, Standing]
    warnings: list[str]


def _check_output(out: Path) -> None:
    if out.exists() and not out.is_dir():
        raise UserError(f"{out}: exists and is not a folder; name a folder for the site")
    if out.is_dir() and any(out.iterdir()) and not (out / MARKER).is_file():
        raise UserError(f"{out}: a folder that is not a leaderboard site and not empty; name "
                        "an empty or new folder (or an earlier site to rebuild)")


def build_site(run_dirs: list[Path], out: Path, options: SiteOptions | None = None) -> Site:
    """Write the site for the finished runs in ``run_dirs`` (found by
    `visphy_core.analysis.load.find_runs`) into ``out``."""
    from visphy_core.analysis.load import find_runs

    options = options or SiteOptions()
    out = Path(out).expanduser()
    found = find_runs(*run_dirs)
    out_resolved = out.resolve()
    found = [p for p in found if out_resolved not in (p, *p.parents)]
    if not found:
        raise UserError("no finished run to put on the leaderboard")
    _check_output(out)
    out.mkdir(parents=True, exist_ok=True)
    runs = [load_run_with_ratings(p) for p in track(found, len(found), "leaderboard: reading "
                                                    "runs", options.progress)]
    entries = [make_entry(run, label, i)
               for i, (run, label) in enumerate(zip(runs, label_runs(runs)))]
    ranks, comparisons, warn = standings(entries)
    for e in entries:
        if e.mean is None:
            warn.append(f"{e.label}: no headline value ({e.metric}): not ranked")
    reports: dict[str, str] = {}
    dropped: dict[str, list[str]] = {}
    clips: dict[str, tuple] = {}
    live = {e.slug for e in entries}
    for folder in ("runs", "clips"):
        if (out / folder).is_dir():
            for old in (out / folder).iterdir():
                if old.name not in live:
                    shutil.rmtree(old, ignore_errors=True)
    for e in track(entries, len(entries), "leaderboard: copying reports and clips",
                   options.progress):
        if options.with_reports:
            index, dropped[e.slug] = copy_report(e, out, options.max_clip_mb,
                                                       options.max_report_mb)
            reports[e.slug] = index.relative_to(out).as_posix()
        clips[e.slug] = best_and_worst(e, out, options.clips_per_side,
                                             options.max_clip_mb)
    for e in entries:
        atomic_write(out / "entries" / f"{e.slug}.html",
                     entry_page(e, ranks[e.slug], reports.get(e.slug), *clips[e.slug],
                                dropped.get(e.slug, [])))
    tables = [b for b in (breakdown(entries, "difficulty", "By difficulty"),
                          breakdown(entries, "template", "By template (from the scene id)"),
                          breakdown(entries, "label", "By dataset label",
                                       options.labels) if options.labels else None,
                          breakdown(entries, "dim", "2D / 3D")) if b is not None]
    atomic_write(out / "breakdowns.html",
                 breakdowns_page(options.title, entries, tables, engine_matrix(entries)))
    write_metric_pages(out)
    _write_scores(entries, out / SCORES)
    notes = [f"{len(entries)} run(s), built {dt.date.today().isoformat()}. The headline is the "
             "run's own (every scored scene; a fallback clip scores as the fallback), with its "
             "95 % bootstrap interval. Rank = 1 + the rows of the same dataset that a paired "
             "bootstrap over shared scenes separates above it (interval excluding 0 and a "
             "difference at least the validity study's discriminative power): rows sharing a "
             "rank are tied. Click a header to sort.",
             f"Run reports are copied with clips over {options.max_clip_mb:g} MB, or beyond "
             f"{options.max_report_mb:g} MB a report, left out.",
             f"Every row's per-scene scores, as `visphy export` writes them: {SCORES}."]
    index = atomic_write(out / "index.html", index_page(options.title, entries, ranks, reports,
                                                        options.references, notes, warn))
    atomic_write(out / MARKER, json.dumps(_as_data(entries, ranks, comparisons, warn,
                                                   options.references), indent=1))
    return Site(index=index, entries=entries, standings=ranks, warnings=warn)


def _write_scores(entries: list[Entry], path: Path) -> None:
    """The rows' tidy score tables in one Parquet file, a ``row`` column naming the row."""
    import pandas as pd

    from visphy_core.results.tidy import tidy_scores

    frames = [tidy_scores(e.run).assign(row=e.label) for e in entries]
    tmp = path.with_name(path.name + ".tmp")
    pd.concat(frames, ignore_index=True).to_parquet(tmp, index=False)
    tmp.replace(path)


def _as_data(entries, ranks, comparisons, warn, references) -> dict:
    return {
        "rows": [{"label": e.label, "slug": e.slug, "model": e.model, "engine": e.engine,
                  "dataset": e.dataset, "metric": e.metric, "mean": e.mean,
                  "ci": list(e.ci) if e.ci else None, "n": e.n, "families": e.families,
                  "rank": ranks[e.slug].rank, "tied_with": ranks[e.slug].tied_with,
                  "run_dir": str(e.run.run_dir)} for e in entries],
        "comparisons": [{"a": c.a, "b": c.b, "shared": c.shared, "separated": c.separated,
                         "better": c.better, "power": c.power,
                         "diff": c.result.diff if c.result else None,
                         "ci": [c.result.ci_low, c.result.ci_high] if c.result else None}
                        for c in comparisons],
        "warnings": warn,
        "references": [{"model": r.model, "engine": r.engine, "dataset": r.dataset,
                        "physics_score": r.score, "ci": list(r.ci) if r.ci else None,
                        "source": r.source, "reference": True} for r in references],
    }
