"""The site's plots as inline SVG (`visphy_core.report.svg`): every row's headline with its 95 %
interval, rows of one tie rank sharing a colour; and per-family bars, one bar per row.
Reference rows are drawn hollow and labelled as such, apart from the measured ones. Each drawn
number is also in the element's ``data-*`` attributes."""

from __future__ import annotations

from visphy_core.leaderboard.entries import Entry
from visphy_core.leaderboard.references import Reference
from visphy_core.leaderboard.ties import Standing
from visphy_core.report.markup import attr, esc, fmt
from visphy_core.report.plots import IntervalLayout, IntervalRow, interval_chart
from visphy_core.report.svg import GRID, MUTED, SERIES, line, n, nice_ticks, svg, text

REFERENCE_COLOUR = "#7b4fc9"


#: The site's headline chart: narrower rows than the report's, one colour per tie rank.
_LAYOUT = IntervalLayout(width=380.0, top=10.0, row_h=22.0, ticks=6, overhang=4.0, bottom=30.0,
                         tick_labels=10.0, whisker=5.0, radius=4.5, outlined=True, gap=8.0,
                         margin=110.0, value_weight="", landmarks=False)


def headline_chart(entries: list[Entry], ranks: dict[str, Standing],
                   references: list[Reference]) -> str:
    """One line per row: the mean as a dot, the interval as a bar; sorted as given
    (`visphy_core.report.plots.interval_chart`)."""
    rows = [(e.label, e.mean, e.ci, ranks.get(e.slug, Standing()).rank, False)
            for e in entries if e.mean is not None]
    rows += [(f"{r.model} {r.engine}".strip() + " (reference)", r.score, r.ci, None, True)
             for r in references if r.score is not None]
    if not rows:
        return '<p class="note">No row has a headline value to plot.</p>'
    drawn = []
    for label, mean, ci, rank, ref in rows:
        tag = f"  rank {rank}" if rank else ("  reference" if ref else "")
        drawn.append(IntervalRow(
            label, mean, ci[0] if ci else None, ci[1] if ci else None, f"{fmt(mean, 3)}{tag}",
            f'data-label={attr(label)} data-mean="{mean!r}" data-reference="{str(ref).lower()}"',
            REFERENCE_COLOUR if ref else SERIES[((rank or 1) - 1) % len(SERIES)], ref))
    caption = ("headline mean and 95 % bootstrap interval per row (higher is better; one colour "
               "per tie rank; hollow: a reference number, not measured here)")
    layout = _LAYOUT._replace(left=min(360.0, 30 + 6.6 * max(len(r[0]) for r in rows)))
    return interval_chart(drawn, (0.0, 1.0), caption, "headline-chart", layout)


def family_chart(entries: list[Entry]) -> str:
    """Per metric family, one bar per row (the family's mean place, higher is better)."""
    families = sorted({f for e in entries for f in e.families})
    shown = [e for e in entries if e.families]
    if not families or not shown:
        return '<p class="note">No metric family to plot (the runs carry no metric means).</p>'
    left = min(300.0, 30 + 6.6 * max(len(e.label) for e in shown))
    width, row_h, top = 300.0, 14.0, 8.0
    block = row_h * len(shown) + 22
    height = top + block * len(families) + 24
    values = [v for e in shown for v in e.families.values()]
    lo_axis, hi_axis = min(0.0, *values), max(1.0, *values)

    def x(v: float) -> float:
        return left + (v - lo_axis) / (hi_axis - lo_axis) * width

    body = []
    for t in nice_ticks(lo_axis, hi_axis, 5):
        body.append(line(x(t), top, x(t), height - 22, GRID))
        body.append(text(x(t), height - 8, fmt(t, 3), "middle", fill=MUTED))
    y = top
    for family in families:
        body.append(text(4, y + 12, family, weight="700"))
        y += 18
        for k, e in enumerate(shown):
            value = e.families.get(family)
            parts = [text(left - 6, y + 10, e.label, "end", size=10.5)]
            if value is not None:
                x0, x1 = x(max(lo_axis, 0.0)), x(value)
                parts.append(f'<rect x="{n(min(x0, x1))}" y="{n(y + 2)}" '
                             f'width="{n(max(abs(x1 - x0), 1.5))}" height="{n(row_h - 4)}" '
                             f'fill="{SERIES[k % len(SERIES)]}"/>')
                parts.append(text(max(x0, x1) + 4, y + 10, fmt(value, 3), size=10))
            body.append(f'<g class="family-bar" data-family={attr(family)} '
                        f'data-label={attr(e.label)} '
                        f'data-value={attr(repr(value) if value is not None else "")}>'
                        + "".join(parts) + "</g>")
            y += row_h
        y += 4
    caption = ("metric families per row: each metric's variance-normalised mean (0 = the still "
               "clip, 1 = the ground truth's twin), else its place in its declared range, "
               "averaged per family; longer is better")
    return (f'<figure class="plot family-chart"><figcaption>{esc(caption)}</figcaption>'
            + svg(left + width + 60, height, "".join(body), caption) + "</figure>")
