"""`write_study_report`: several runs on one page, the leaderboard first.

The page shows the study's leaderboard (``tables["leaderboard"]`` when the analysis made one,
else one row per run from its ``summary.json``), then the analysis' markdown, other tables and
figures (copied into the folder), then a link to each run's own report in its run directory
(``<run_dir>/report/index.html``, written when missing or older than the run's results). Links
are relative: move the output folder together with the runs it points at.
"""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path
from typing import TYPE_CHECKING

from visphy_core.infra.files import atomic_write
from visphy_core.report.column_groups import PRIMARY, direction_of, grouped, label
from visphy_core.report.markup import arrow, attr, details, esc, fmt, page, rate, table, url
from visphy_core.report.run_report import write_run_report
from visphy_core.results.layout import is_run_dir
from visphy_core.results.load import RunData, load_run
from visphy_core.results.run_dir import RunDir

if TYPE_CHECKING:
    import pandas as pd

#: Markdown notes up to this length are shown unfolded.
MARKDOWN_OPEN = 2000
#: Figure files shown inline, most preferred first; other files are linked.
IMAGE_PREFERENCE = {".svg": 0, ".png": 1, ".webp": 2, ".jpg": 3, ".jpeg": 3, ".gif": 4}


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]", "_", name) or "item"


def run_report_of(run_dir: Path) -> Path:
    """``<run_dir>/report/index.html``, written when missing or older than the run's results."""
    index = run_dir / "report" / "index.html"
    run = RunDir(run_dir)
    newest = max((p.stat().st_mtime for p in (run.rows_file, run.summary_file) if p.is_file()),
                 default=0.0)
    if not index.is_file() or index.stat().st_mtime < newest:
        index = write_run_report(run_dir)
    return index


def frame_table(frame: "pd.DataFrame", ident: str = "") -> str:
    """A DataFrame as an escaped HTML table (numbers to 4 significant figures)."""
    import pandas as pd

    keep_index = not (isinstance(frame.index, pd.RangeIndex) and frame.index.name is None)
    html = frame.to_html(escape=True, na_rep="—", border=0, index=keep_index,
                         float_format=lambda v: fmt(float(v)), classes="table")
    if ident:
        html = html.replace("<table ", f"<table id={attr(ident)} ", 1)
    return f'<div class="scroll">{html}</div>'


def built_leaderboard(runs: list[RunData], links: dict[str, str]) -> str:
    """One row per run: success, fallbacks and the plain pairing's means (model successes;
    the means with fallbacks in a second table)."""
    columns: list[str] = []
    for run in runs:
        metrics = list((run.summary.get("metrics") or {}))
        columns += [c for key, members in grouped(metrics) if key in PRIMARY
                    for c in members if c not in columns]
    summary = next((r.summary for r in runs if r.summary.get("metrics")), {})
    heads = ["run", "model", "engine", "dataset", "status", "model success", "fallbacks"] + [
        f"{esc(label(c))}{arrow(direction_of(c, summary))}" for c in columns]

    def rows(view: str) -> list[list[str]]:
        out = []
        for run in runs:
            s, metrics = run.summary, run.summary.get("metrics") or {}
            link = links.get(str(run.run_dir))
            name = (f"<a href={attr(link)}>{esc(run.name)}</a>" if link else esc(run.name))
            cells = [name, esc(s.get("model") or run.cfg("model.name")),
                     esc(s.get("engine") or run.cfg("engine.name")),
                     esc(s.get("dataset") or run.cfg("dataset.name")), esc(run.status),
                     esc(rate(s.get("model_success"), s.get("n_scenes"))),
                     esc(s.get("fallbacks", 0))]
            for c in columns:
                info = metrics.get(c) or {}
                mean, n = info.get(f"mean_{view}"), info.get(f"n_{view}") or 0
                if mean is None and info.get("unavailable"):
                    cells.append(f'<span class="unavailable">unavailable: '
                                 f'{esc(info["unavailable"])}</span>')
                else:
                    cells.append(f'{esc(fmt(mean))} <span class="note">(n={int(n)})</span>'
                                 if mean is not None else "—")
            out.append(cells)
        return out

    return ('<p class="note">means over each run\'s model successes (the scenes where its own '
            "program made a clip):</p>"
            + '<div class="scroll">' + table(heads, rows("model_success"), cls="leaderboard",
                                             attrs=' id="leaderboard-table"') + "</div>"
            + '<p class="note">means over every scene with a clip, the fallback clips scored:</p>'
            + '<div class="scroll">' + table(heads, rows("with_fallbacks"), cls="leaderboard")
            + "</div>")


def _markdown(text: str, copied: dict[str, str]) -> str:
    """``text`` as HTML. Raw HTML in it is shown as text and unsafe link schemes are refused
    (markdown-it's ``html=False``); an image that names a figure file (the analysis writes
    ``![](boxplot_psnr.png)`` beside its figures) points at the copy in this folder, and any
    other image that is not a web address is dropped for its alt text (nothing to load)."""
    from markdown_it import MarkdownIt
    from markdown_it.token import Token

    md = MarkdownIt("commonmark", {"html": False}).enable("table")
    tokens = md.parse(text)
    for block in tokens:
        children = block.children or []
        for i, token in enumerate(children):
            if token.type != "image":
                continue
            src = str(token.attrGet("src") or "")
            name = Path(src).name
            if name in copied:
                token.attrSet("src", url(copied[name]))
            else:
                alt = Token("text", "", 0)
                alt.content = f"[figure {src}]"
                children[i] = alt
    return md.renderer.render(tokens, md.options, {})


def _figures(figures: dict[str, list[Path]], out_dir: Path, copied: dict[str, str]) -> str:
    """Each figure copied in (``copied``: file name -> its path in the folder); one image per
    plot (a plot saved as both SVG and PNG is shown once, as SVG; the others are linked)."""
    parts = []
    for name, paths in figures.items():
        items, shown = [], set()
        files = sorted((Path(p) for p in paths),
                       key=lambda p: IMAGE_PREFERENCE.get(p.suffix.lower(), len(IMAGE_PREFERENCE)))
        for src in files:
            if not src.is_file():
                items.append(f'<p class="note warn">missing figure: {esc(src)}</p>')
                continue
            rel = f"figures/{_safe(name)}/{_safe(src.name)}"
            (out_dir / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(src, out_dir / rel)
            copied.setdefault(src.name, rel)
            if src.suffix.lower() in IMAGE_PREFERENCE and src.stem not in shown:
                shown.add(src.stem)
                items.append(f"<img alt={attr(f'{name}: {src.name}')} src={attr(url(rel))}>")
            else:
                items.append(f'<p class="note">also as <a href={attr(url(rel))}>'
                             f"{esc(src.name)}</a></p>")
        parts.append(f'<h3>{esc(name)}</h3><div class="figures">{"".join(items)}</div>')
    return f'<section id="figures"><h2>Figures</h2>{"".join(parts)}</section>' if parts else ""


def write_study_report(run_dirs: list[Path], out_dir: Path, title: str,
                       tables: "dict[str, pd.DataFrame] | None" = None,
                       figures: dict[str, list[Path]] | None = None,
                       markdown: str | None = None) -> Path:
    """Write the study page into ``out_dir``; returns the path of its ``index.html``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    tables = dict(tables or {})
    dirs = [Path(d) for d in run_dirs]
    runs = [load_run(d) for d in dirs if is_run_dir(d)]
    not_runs = [d for d in dirs if not is_run_dir(d)]
    links: dict[str, str] = {}
    failed: dict[str, str] = {}
    for run in runs:
        try:
            index = run_report_of(run.run_dir)
        except Exception as exc:  # noqa: BLE001 - one broken run must not sink the study page
            failed[str(run.run_dir)] = f"{type(exc).__name__}: {exc}"
            continue
        links[str(run.run_dir)] = url(os.path.relpath(index, out_dir))
    board = tables.pop("leaderboard", None)
    body = [f'<header class="top"><h1>{esc(title)}</h1><div class="meta">'
            f"<span>runs: <b>{len(runs)}</b></span></div></header>"]
    board_html = frame_table(board, "leaderboard-table") if board is not None \
        else built_leaderboard(runs, links)
    body.append(f'<section id="leaderboard"><h2>Leaderboard</h2>{board_html}</section>')
    copied: dict[str, str] = {}
    figure_html = _figures(figures or {}, out_dir, copied)
    if markdown:
        # the analysis' own write-up repeats its tables and figures: folded when that long
        notes = _markdown(markdown, copied)
        body.append('<section id="notes" class="markdown"><h2>Analysis notes</h2>' + details(
            "the write-up (markdown)", notes, open_=len(markdown) <= MARKDOWN_OPEN)
            + "</section>")
    if tables:
        body.append('<section id="tables"><h2>Tables</h2>' + "".join(
            f"<h3>{esc(name)}</h3>{frame_table(frame)}" for name, frame in tables.items())
            + "</section>")
    body.append(figure_html)
    def run_link(r: RunData) -> str:
        if str(r.run_dir) in links:
            return f"<a href={attr(links[str(r.run_dir)])}>{esc(r.name)}</a>"
        return (f'{esc(r.name)} <span class="bad">(report failed: '
                f"{esc(failed.get(str(r.run_dir)))})</span>")

    rows = [[run_link(r),
             esc(r.summary.get("model") or r.cfg("model.name")),
             esc(r.summary.get("engine") or r.cfg("engine.name")), esc(r.status),
             esc(rate(r.summary.get("model_success"), r.summary.get("n_scenes")))]
            for r in runs]
    rows += [[esc(d), "", "", '<span class="bad">not a run directory</span>', ""]
             for d in not_runs]
    body.append('<section id="runs"><h2>Runs</h2>'
                + table(["run report", "model", "engine", "status", "model success"], rows)
                + "</section>")
    index = out_dir / "index.html"
    atomic_write(index, page(title, "".join(body)))
    return index
