"""The site's page shell and sortable tables.

Every page is one file with its stylesheet and its one script inline (``assets/``), so a page
works from ``file://`` and from any static host, fetches nothing, and needs no path to an asset.
A Content Security Policy allows that script alone (by its SHA-256), media from the site's own
folder, and no network request; untrusted text enters only through
`visphy_core.report.markup.esc` / ``attr``. Links are relative, so the folder can move.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources

from visphy_core.report.markup import attr, csp, esc, fmt


def asset(name: str) -> str:
    return resources.files("visphy_core.leaderboard").joinpath("assets", name).read_text("utf-8")


NAV = (("index.html", "Leaderboard"), ("breakdowns.html", "Breakdowns"),
       ("metrics/index.html", "Metrics"))


def page(title: str, body: str, root: str = "") -> str:
    """A complete page; ``root`` is the path from the page to the site's root (``../``)."""
    script = asset("leaderboard.js")
    nav = "".join(f"<a href={attr(root + href)}>{esc(name)}</a>" for href, name in NAV)
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<meta http-equiv=\"Content-Security-Policy\" content={attr(csp(script))}>"
            "<meta name=\"referrer\" content=\"no-referrer\">"
            "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
            f"<title>{esc(title)}</title><style>{asset('leaderboard.css')}</style></head>"
            f"<body><header class=\"top\"><h1>{esc(title)}</h1><nav>{nav}</nav></header>"
            f"{body}<script>{script}</script></body></html>\n")


@dataclass
class Cell:
    """A table cell: its HTML, the value it sorts by (None: as its text) and its class."""

    html: str
    sort: object = None
    cls: str = ""


def num(value: float | None, digits: int = 3, cls: str = "num") -> Cell:
    return Cell(esc(fmt(value, digits)) if value is not None else "—", value, cls)


def text(value: object) -> Cell:
    return Cell(esc(value if value not in (None, "") else "—"))


def headline_cell(mean: float | None, ci: tuple[float, float] | None, n: int | None) -> Cell:
    if mean is None:
        return Cell("—", None, "num")
    interval = (f' <span class="ci">[{esc(fmt(ci[0], 3))}, {esc(fmt(ci[1], 3))}]</span>'
                if ci else "")
    count = f' <span class="small">n={n}</span>' if n else ""
    return Cell(f"<b>{esc(fmt(mean, 3))}</b>{interval}{count}", mean, "num")


def percent(value: float | None) -> Cell:
    return Cell("—" if value is None else f"{100 * value:.0f}%", value, "num")


def seconds(value: float | None) -> Cell:
    if value is None:
        return Cell("—", None, "num")
    shown = f"{value:.1f} s" if value < 120 else f"{value / 60:.1f} min"
    return Cell(shown, value, "num")


def sortable(headers: list[tuple[str, str]], rows: list[list[Cell]], ident: str = "",
             cls: str = "") -> str:
    """A table whose headers sort it (``headers``: (HTML, hint shown on hover))."""
    head = "".join(f"<th title={attr(hint)}>{h}</th>" if hint else f"<th>{h}</th>"
                   for h, hint in headers)
    body = []
    for row in rows:
        cells = []
        for c in row:
            sort = f" data-sort={attr(c.sort)}" if c.sort is not None else ""
            klass = f" class={attr(c.cls)}" if c.cls else ""
            cells.append(f"<td{klass}{sort}>{c.html}</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    ident_attr = f" id={attr(ident)}" if ident else ""
    return (f'<div class="scroll"><table class="sortable {esc(cls)}"{ident_attr}><thead><tr>'
            f"{head}</tr></thead><tbody>{''.join(body)}</tbody></table></div>")


def warnings(lines: list[str]) -> str:
    if not lines:
        return ""
    return ('<div class="warnings"><b>Read with care</b><ul>'
            + "".join(f"<li>{esc(w)}</li>" for w in lines) + "</ul></div>")
