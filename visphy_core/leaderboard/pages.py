"""The site's pages: the leaderboard (``index.html``), the breakdowns, one page per row."""

from __future__ import annotations

from collections import Counter

from visphy_core.leaderboard.breakdowns import Breakdown
from visphy_core.leaderboard.clips import SceneClips
from visphy_core.leaderboard.entries import Entry
from visphy_core.leaderboard.html import (
    Cell,
    headline_cell,
    num,
    page,
    percent,
    seconds,
    sortable,
    text,
    warnings,
)
from visphy_core.leaderboard.plots import family_chart, headline_chart
from visphy_core.leaderboard.references import Reference
from visphy_core.leaderboard.ties import Standing
from visphy_core.report.markup import attr, esc, fmt, url
from visphy_core.report.plots import family_bars, headline_plot
from visphy_core.report.scene_section import clip_figure


def _link(href: str, label: str) -> str:
    return f"<a href={attr(url(href))}>{esc(label)}</a>"


def rank_cell(standing: Standing, shared: Counter) -> Cell:
    if standing.rank is None:
        return Cell('<span class="small" title="shares no scenes with another row">n/c</span>',
                    None, "rank")
    tie = (f' <span class="tie" title="rows sharing a rank are not separated">='
           f"{shared[standing.rank]}</span>" if shared[standing.rank] > 1 else "")
    return Cell(f"{standing.rank}{tie}", standing.rank, "rank")


def measured_table(entries: list[Entry], ranks: dict[str, Standing],
                   reports: dict[str, str]) -> str:
    families = sorted({f for e in entries for f in e.families})
    metric = next((e.metric for e in entries), "physics_score")
    headers = [("rank", "1 + rows separated above it; a shared rank is a tie"),
               ("run", "the row's page: clips of its best and worst scenes"), ("model", ""),
               ("engine", ""), ("dataset", ""), ("dims", "2D / 3D"),
               (f'<a href="metrics/headline.html">{esc(metric)}</a> ↑',
                "headline mean [95 % interval] over n scenes"),
               ("tied with", "rows the paired bootstrap over shared scenes cannot separate")]
    headers += [(f"{esc(f)} ↑", f"family {f}: mean place of its metrics") for f in families]
    headers += [("model ok", "model success rate"), ("system ok", "system success rate"),
                ("cost $", ""), ("tokens", "input + output"), ("render", "render time, total"),
                ("score", "score time, total"), ("date", ""), ("version", "visphy version"),
                ("report", "")]
    by_rank = Counter(s.rank for s in ranks.values() if s.rank is not None)
    rows = []
    for e in entries:
        s = ranks.get(e.slug, Standing())
        row = [rank_cell(s, by_rank), Cell(_link(f"entries/{e.slug}.html", e.label), e.label),
               text(e.model), text(e.engine), text(e.dataset), text(e.dims),
               headline_cell(e.mean, e.ci, e.n),
               Cell(esc(", ".join(s.tied_with)) or "—", len(s.tied_with))]
        row += [num(e.families.get(f)) for f in families]
        row += [percent(e.model_success_rate), percent(e.system_success_rate),
                num(e.cost_usd, 3), Cell(str(e.tokens) if e.tokens is not None else "—",
                                         e.tokens, "num"),
                seconds(e.seconds("render_wall_s")), seconds(e.seconds("scoring_wall_s")),
                text(e.date), text(e.version),
                Cell(_link(reports[e.slug], "report") if e.slug in reports else "—")]
        rows.append(row)
    return sortable(headers, rows, ident="leaderboard")


def reference_table(references: list[Reference]) -> str:
    others = sorted({k for r in references for k in r.others})
    headers = [("model", ""), ("engine", ""), ("dataset", ""),
               ("physics_score ↑", "as published [interval] (n)")]
    headers += [(esc(k), "as published") for k in others]
    headers += [("date", ""), ("source", "where the number comes from"), ("note", "")]
    rows = []
    for r in references:
        row = [Cell(esc(r.model) + '<span class="badge-ref">reference</span>', r.model),
               text(r.engine), text(r.dataset), headline_cell(r.score, r.ci, r.n)]
        row += [num(r.others.get(k)) for k in others]
        row += [text(r.date), Cell(esc(r.source), r.source, "source"), text(r.note)]
        rows.append(row)
    return sortable(headers, rows, ident="references", cls="reference")


def index_page(title: str, entries: list[Entry], ranks: dict[str, Standing],
               reports: dict[str, str], references: list[Reference], notes: list[str],
               warn: list[str]) -> str:
    ordered = sorted(entries, key=lambda e: (e.dataset, -(e.mean if e.mean is not None
                                                           else float("-inf"))))
    body = [f'<p class="note">{esc(n)}</p>' for n in notes]
    body.append(warnings(warn))
    body.append("<h2>Measured</h2>" + headline_chart(ordered, ranks, references)
                + measured_table(ordered, ranks, reports))
    if references:
        body.append("<h2>Reference numbers (not measured here)</h2>"
                    '<p class="note">Added by hand from the file given to <code>--reference'
                    "</code>, each with its source. They are not ranked and never in a tie: "
                    "no scene of theirs is here to compare.</p>" + reference_table(references))
    body.append("<h2>Metric families</h2>" + family_chart(ordered))
    return page(title, "".join(body))


def breakdown_table(b: Breakdown, entries: list[Entry]) -> str:
    headers = [("run", ""), ("dataset", "")] + [(esc(g), "mean headline (n scenes)")
                                                for g in b.groups]
    rows = []
    for e in entries:
        cells = b.cells.get(e.slug) or {}
        if not cells:
            continue
        row = [Cell(_link(f"entries/{e.slug}.html", e.label), e.label), text(e.dataset)]
        for g in b.groups:
            value = cells.get(g)
            row.append(Cell(f"{esc(fmt(value[0], 3))} <span class=\"small\">n={value[1]}"
                            "</span>", value[0], "num") if value else Cell("—", None, "num"))
        rows.append(row)
    return f"<h2>{esc(b.title)}</h2>" + sortable(headers, rows, ident=f"by-{b.key}")


def matrix_table(dataset: str, models: list[str], engines: list[str],
                 cells: dict[tuple[str, str], list[Entry]]) -> str:
    headers = [("model", "")] + [(esc(e), "headline [95 % interval]") for e in engines]
    rows = []
    for m in models:
        row = [text(m)]
        for eng in engines:
            members = cells.get((m, eng)) or []
            if not members:
                row.append(Cell("—", None, "num"))
                continue
            best = max(members, key=lambda e: e.mean if e.mean is not None else -1e9)
            cell = headline_cell(best.mean, best.ci, best.n)
            more = (f' <span class="small">(best of {len(members)})</span>'
                    if len(members) > 1 else "")
            href = attr(url(f"entries/{best.slug}.html"))
            row.append(Cell(f"<a href={href}>{cell.html}</a>{more}", cell.sort, "num"))
        rows.append(row)
    return (f"<h2>Model × engine on {esc(dataset)}</h2>"
            + sortable(headers, rows, ident=f"matrix-{dataset}"))


def breakdowns_page(title: str, entries: list[Entry], tables: list[Breakdown],
                    matrices: dict) -> str:
    body = ['<p class="note">The headline per row split by what a scene is; each cell is the '
            "mean over the row's scenes in that group, with their number. Click a header to "
            "sort.</p>"]
    for dataset, (models, engines, cells) in matrices.items():
        body.append(matrix_table(dataset, models, engines, cells))
    body += [breakdown_table(b, entries) for b in tables]
    if len(body) == 1:
        body.append('<p class="note">No breakdown: the runs have one group of each kind.</p>')
    return page(f"{title}: breakdowns", "".join(body))


def _pair(c: SceneClips, slug: str) -> str:
    return (f'<div class="pair"><h4>{esc(c.scene_id)} · {esc(fmt(c.value, 3))}</h4>'
            '<div class="row">'
            + clip_figure("generated", c.generated, "no generated clip",
                          prefix=f"../clips/{slug}/", controls=True)
            + clip_figure("ground truth", c.truth, "no ground truth",
                          prefix=f"../clips/{slug}/", controls=True)
            + "</div></div>")


def entry_page(e: Entry, standing: Standing, report: str | None, best: list[SceneClips],
               worst: list[SceneClips], dropped: list[str]) -> str:
    facts = [("model", e.model), ("engine", e.engine), ("dataset", e.dataset),
             ("rank", standing.rank if standing.rank is not None else "not compared"),
             ("tied with", ", ".join(standing.tied_with) or "—"),
             ("run directory", e.run.run_dir.name), ("date", e.date), ("visphy", e.version)]
    body = ['<dl class="facts">' + "".join(f"<dt>{esc(k)}</dt><dd>{esc(v)}</dd>"
                                          for k, v in facts) + "</dl>"]
    if report:
        body.append(f'<p>{_link("../" + report, "the full run report")}'
                    + (f' <span class="small">({len(dropped)} clip(s) over the media cap left '
                       "out of this copy)</span>" if dropped else "") + "</p>")
    body.append("<h2>Headline</h2>" + headline_plot(e.run.summary))
    for name, clips in (("Best scenes", best), ("Worst scenes", worst)):
        if clips:
            body.append(f"<h2>{name}</h2><div class=\"clips\">"
                        + "".join(_pair(c, e.slug) for c in clips) + "</div>")
    body.append("<h2>Metric families</h2>" + family_bars(e.run.summary))
    return page(e.label, "".join(body), root="../")
