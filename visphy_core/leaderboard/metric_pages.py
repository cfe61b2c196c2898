"""A page per metric, generated from the metric registry, so the site's definitions cannot drift.

Each page shows what `Metric.describe` declares (direction, range, family, kind, needs,
weights, whether it runs here) and its validity figures (`Metric.validity`: the validity
study's strict and monotone shares, restyle invariance and physics drop), the definition from
the metric's docstrings, and the headline's own page from the study's ``headline`` block.
``metrics/index.html`` lists them all, grouped by family.
"""

from __future__ import annotations

import inspect
from pathlib import Path
from typing import Any

from visphy_core.infra.files import atomic_write
from visphy_core.leaderboard.html import page
from visphy_core.report.markup import attr, esc, table

HEADLINE_PAGE = "headline"
FIGURE_TEXT = (
    ("strict", "share of scenes where every physics-right redraw scores above every "
               "physics-wrong clip (≥ 20 px off) and those above both baselines"),
    ("means", "the same with the means per kind"),
    ("monotone", "share of dose series over which the score falls with the physics error"),
    ("invariance", "largest median change a restyle causes (headline scale; lower is better)"),
    ("physics_drop", "smallest median drop a physics error causes (headline scale; higher is "
                     "better)"),
    ("scenes", "scenes the study scored"),
)


def definition(metric: Any) -> str:
    """The metric's own class docstring and its module's first paragraph."""
    own = inspect.cleandoc(type(metric).__dict__.get("__doc__") or "")
    module = inspect.getmodule(type(metric))
    first = inspect.cleandoc((module.__doc__ if module else "") or "").split("\n\n")[0]
    parts = [p for p in (own, first) if p]
    return "\n\n".join(dict.fromkeys(parts))


def _figure_value(key: str, value: Any) -> str:
    if value is None:
        return "—"
    if key in ("strict", "means", "monotone"):
        return f"{100 * float(value):.0f} %"
    if key == "scenes":
        return str(value)
    return f"{float(value):.3f}"


def validity_table(fig: dict | None) -> str:
    if not fig:
        return '<p class="note">The validity study did not score this metric.</p>'
    rows = [[esc(k), esc(_figure_value(k, fig.get(k))), esc(why)] for k, why in FIGURE_TEXT]
    return table(["figure", "value", "what it is"], rows)


def _paragraphs(text: str) -> str:
    return "".join(f'<p class="note">{esc(p)}</p>' for p in text.split("\n\n") if p.strip())


def metric_page(name: str, described: dict, text: str) -> str:
    rng = described.get("range") or ["?", "?"]
    facts = [("direction", f"{described.get('direction')} is better"),
             ("range", f"{rng[0]} … {rng[1]}"), ("family", described.get("family")),
             ("kind", described.get("kind")), ("needs", ", ".join(described.get("needs") or [])),
             ("weights", described.get("weights") or "none"),
             ("here", described.get("unavailable") or "available")]
    body = ('<dl class="facts">' + "".join(f"<dt>{esc(k)}</dt><dd>{esc(v)}</dd>"
                                          for k, v in facts) + "</dl>"
            + "<h2>Definition</h2>" + (_paragraphs(text) or '<p class="note">—</p>')
            + "<h2>Validity</h2>" + validity_table(described.get("validity"))
            + '<p class="note"><a href="index.html">all metrics</a></p>')
    return page(f"metric {name}", body, root="../")


def headline_page() -> str:
    from visphy_core.api.validity import figures, load_summary, scope

    summary = load_summary() or {}
    head = summary.get("headline") or {}
    comps = ", ".join(head.get("components") or []) or "its components"
    less = "".join(f", less {w:g} × {n}" for n, w in (head.get("penalties") or {}).items())
    body = (f'<p class="note">The headline <b>{esc(head.get("name") or "physics_score")}</b> is '
            f"the mean of {esc(comps)}, each placed between the still clip (0) and its ceiling "
            f"(1){esc(less)}. The leaderboard ranks rows by it. Validity study: "
            f"{esc(scope(summary))}."
            "</p><h2>Validity</h2>" + validity_table(figures("headline", summary) if summary
                                                     else None)
            + '<p class="note"><a href="index.html">all metrics</a></p>')
    return page("the headline score", body, root="../")


def write_metric_pages(site: Path) -> list[str]:
    """Write ``metrics/*.html``; returns the metric names."""
    from visphy_core.api.registry import get_registry

    registry = get_registry()
    out = site / "metrics"
    out.mkdir(parents=True, exist_ok=True)
    described = {}
    for name in sorted(registry.metrics):
        metric = registry.get("metrics", name)
        described[name] = metric.describe()
        atomic_write(out / f"{name}.html", metric_page(name, described[name],
                                                       definition(metric)))
    atomic_write(out / f"{HEADLINE_PAGE}.html", headline_page())
    families: dict[str, list[str]] = {}
    for name, d in described.items():
        families.setdefault(str(d.get("family") or "other"), []).append(name)
    parts = [f'<p><a href="{HEADLINE_PAGE}.html">the headline score</a></p>']
    for family in sorted(families):
        rows = []
        for name in families[family]:
            d = described[name]
            fig = d.get("validity") or {}
            rows.append([f"<a href={attr(name + '.html')}>{esc(name)}</a>",
                         esc(d.get("direction")), esc(d.get("kind")),
                         esc(_figure_value("strict", fig.get("strict"))),
                         esc(_figure_value("monotone", fig.get("monotone")))])
        parts.append(f"<h2>{esc(family)}</h2>"
                     + table(["metric", "better", "kind", "strict", "monotone"], rows))
    atomic_write(out / "index.html", page("metrics", "".join(parts), root="../"))
    return list(described)
