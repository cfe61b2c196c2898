"""The run report's plots, as inline SVG (`visphy_core.report.svg`):

* `headline_plot`: the headline score with its 95% bootstrap interval, over every scored scene
  and over the model's successes, on the headline's own scale (0 = a still clip, 1 = the ground
  truth);
* `family_bars`: every metric of the plain pairing (and each judge), grouped by family, as bars
  on one scale where longer is better: the variance-normalised score where the run has it
  (0 = the still clip, 1 = the ground truth's twin), else the mean's place in the metric's
  declared range (metrics without a bounded range are listed without a bar);
* per scene (`visphy_core.report.scene_plots`): the per-frame PSNR curve against the ground
  truth (with the still clip's for scale) and the tracked bodies' paths in both clips over the
  first key frame (`visphy_core.report.frame_data`).

A plot that cannot be drawn is one line saying why, never an empty or broken element. Every
plotted number is also in the element's ``data-*`` attributes (what the tests read).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

from visphy_core.report.column_groups import direction_of, group_of
from visphy_core.report.markup import attr, esc, fmt
from visphy_core.report.svg import GRID, MUTED, SERIES, line, n, nice_ticks, svg, text
from visphy_core.results.columns import JUDGE_PREFIX, norm_column

#: The headline's axis always shows at least this range (its default clip).
HEADLINE_SPAN = (-1.0, 1.0)
#: Normalised bars are drawn within this range; a value beyond it ends in an arrow.
NORM_SPAN = (-1.0, 2.0)
#: Highest PSNR drawn (dB): identical frames (infinite PSNR) sit on this line.
PSNR_CAP = 60.0


def _why(reason: str, cls: str) -> str:
    return f'<p class="note plot-missing {esc(cls)}">{esc(reason)}</p>'


def _finite(value: Any) -> float | None:
    try:
        v = float(value)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


# ------------------------------------------------------------------ run level


class IntervalRow(NamedTuple):
    """One row of an interval chart (`interval_chart`): a mean as a dot, its interval as a bar."""

    label: str
    mean: float
    lo: float | None
    hi: float | None
    #: the text right of the plot
    value: str
    #: the row's ``data-*`` attributes
    data: str
    colour: str = SERIES[0]
    #: drawn hollow, its label in its colour (the leaderboard's reference rows)
    hollow: bool = False


class IntervalLayout(NamedTuple):
    """Where an interval chart draws, in user units; the defaults are the report's."""

    left: float = 130.0
    width: float = 300.0
    top: float = 18.0
    row_h: float = 26.0
    ticks: int = 5
    #: the grid above the first row
    overhang: float = 6.0
    #: below the last row; the tick labels stand ``tick_labels`` above the bottom
    bottom: float = 34.0
    tick_labels: float = 16.0
    whisker: float = 6.0
    radius: float = 5.0
    #: the dot drawn with an outline in its colour (white when hollow)
    outlined: bool = False
    #: between the plot and each row's value, and the room right of the plot
    gap: float = 10.0
    margin: float = 170.0
    value_weight: str = "600"
    #: the still clip's (0) and the ground truth's (1) lines named under the axis
    landmarks: bool = True


def interval_chart(rows: list[IntervalRow], span: tuple[float, float], caption: str, cls: str,
                   layout: IntervalLayout = IntervalLayout()) -> str:
    """The headline chart of the report and of the leaderboard site: one line per row, sorted as
    given, on an axis covering ``span`` and every value; a dashed line at 0."""
    values = [v for r in rows for v in (r.mean, r.lo, r.hi) if v is not None]
    lo_axis, hi_axis = min(span[0], *values), max(span[1], *values)
    g = layout
    height = g.top + g.row_h * len(rows) + g.bottom
    y0, y1 = g.top - g.overhang, g.top + g.row_h * len(rows) + 6

    def x(v: float) -> float:
        return g.left + (v - lo_axis) / (hi_axis - lo_axis) * g.width

    body = []
    for t in nice_ticks(lo_axis, hi_axis, g.ticks):
        body.append(line(x(t), y0, x(t), y1))
        body.append(text(x(t), height - g.tick_labels, fmt(t, 3), "middle", fill=MUTED))
    body.append(line(x(0), y0, x(0), y1, MUTED, 1, ' stroke-dasharray="3 3"'))
    if g.landmarks:
        body.append(text(x(0), height - 4, "still clip", "middle", fill=MUTED, size=10))
        if lo_axis <= 1 <= hi_axis:
            body.append(line(x(1), y0, x(1), y1, "#17803d", 1, ' stroke-dasharray="3 3"'))
            body.append(text(x(1), height - 4, "ground truth", "middle", fill="#17803d",
                             size=10))
    for i, r in enumerate(rows):
        y = g.top + g.row_h * i + g.row_h / 2
        parts = [text(g.left - 8, y + 4, r.label, "end", fill=r.colour if r.hollow else "")]
        if r.lo is not None and r.hi is not None:
            parts += [line(x(r.lo), y, x(r.hi), y, r.colour, 2),
                      line(x(r.lo), y - g.whisker, x(r.lo), y + g.whisker, r.colour, 2),
                      line(x(r.hi), y - g.whisker, x(r.hi), y + g.whisker, r.colour, 2)]
        fill = "#fff" if r.hollow else r.colour
        outline = f' stroke="{r.colour}" stroke-width="2"' if g.outlined else ""
        parts.append(f'<circle cx="{n(x(r.mean))}" cy="{n(y)}" r="{n(g.radius)}" '
                     f'fill="{fill}"{outline}/>')
        parts.append(text(g.left + g.width + g.gap, y + 4, r.value, weight=g.value_weight))
        body.append(f'<g class="headline-row" {r.data}>' + "".join(parts) + "</g>")
    return (f'<figure class="plot {cls}"><figcaption>{esc(caption)}</figcaption>'
            + svg(g.left + g.width + g.margin, height, "".join(body), caption) + "</figure>")


def headline_plot(summary: dict, clip: Any = None) -> str:
    """The headline mean with its interval, one row per view (all scored scenes, model
    successes)."""
    head = summary.get("headline") or {}
    if not head.get("metric"):
        return _why("no headline plot: the run has no headline score (none of its components "
                    "was among the run's metrics, or metrics.headline.enabled=false)",
                    "headline-plot")
    rows = []
    for label_, mean, ci, count in (
            ("all scored scenes", head.get("mean"), head.get("ci"), head.get("n")),
            ("model successes", head.get("mean_model_success"), head.get("ci_model_success"),
             head.get("n_model_success"))):
        m = _finite(mean)
        if m is None:
            continue
        lo, hi = ((_finite(ci[0]), _finite(ci[1])) if isinstance(ci, (list, tuple))
                  and len(ci) == 2 else (None, None))
        count = int(count or 0)
        interval = f" [{fmt(lo, 3)}, {fmt(hi, 3)}]" if lo is not None and hi is not None else ""
        rows.append(IntervalRow(
            label_, m, lo, hi, f"{fmt(m, 3)}{interval}  n={count}",
            f'data-view={attr(label_)} data-mean="{m!r}" '
            f'data-lo={attr(repr(lo) if lo is not None else "")} '
            f'data-hi={attr(repr(hi) if hi is not None else "")} data-n="{count}"'))
    if not rows:
        return _why("no headline plot: no scene has a headline value yet", "headline-plot")
    try:
        span = (float(clip[0]), float(clip[1])) if clip else HEADLINE_SPAN
    except (TypeError, ValueError, IndexError):
        span = HEADLINE_SPAN
    small = " · fewer than 10 scenes: read the interval" if head.get("small_sample") else ""
    caption = (f"headline {head['metric']} ↑ higher is better: mean and 95% bootstrap "
               f"interval (0 = a still clip, 1 = the ground truth){small}")
    return interval_chart(rows, span, caption, "headline-plot")


def _bar_rows(summary: dict) -> tuple[str, list[tuple[str, list[tuple]]]]:
    """The scale and, per family, ``(column, shown text, bar value or None, n, why no bar)``."""
    metrics = summary.get("metrics") or {}
    info = summary.get("metric_info") or {}
    headline = (summary.get("headline") or {}).get("metric")
    names = [c for c in metrics if group_of(c) in ("visphy", "judge") and c != headline]
    normed = any((metrics.get(norm_column(c)) or {}).get("mean_model_success") is not None
                 for c in names)
    scale = "normalised" if normed else "range"
    families: dict[str, list[tuple]] = {}
    for c in names:
        entry = metrics[c]
        meta = info.get(c) if isinstance(info.get(c), dict) else {}
        family = "judges" if c.startswith(JUDGE_PREFIX) else str(meta.get("family") or "other")
        mean, count = _finite(entry.get("mean_model_success")), int(
            entry.get("n_model_success") or 0)
        shown = (f"{fmt(mean)} (n={count})" if mean is not None else
                 f"unavailable: {entry['unavailable']}" if entry.get("unavailable")
                 else "— (n=0)")
        bar, why = None, ""
        if mean is None:
            why = "no value"
        elif normed:
            norm = metrics.get(norm_column(c)) or {}
            bar = _finite(norm.get("mean_model_success"))
            why = "" if bar is not None else "not normalised"
        else:
            rng = meta.get("range") if not c.startswith(JUDGE_PREFIX) else (0, 10)
            lo, hi = ((_finite(rng[0]), _finite(rng[1])) if isinstance(rng, (list, tuple))
                      and len(rng) == 2 else (None, None))
            if lo is None or hi is None or hi <= lo:
                why = "unbounded range"
            else:
                frac = (mean - lo) / (hi - lo)
                bar = min(max(frac if direction_of(c, summary) != "lower" else 1 - frac,
                              0.0), 1.0)
        families.setdefault(family, []).append((c, shown, bar, count, why))
    return scale, list(families.items())


def family_bars(summary: dict) -> str:
    """Every plain-pairing metric's mean over the model's successes, grouped by family, as
    bars where longer is better."""
    scale, families = _bar_rows(summary)
    if not families:
        return _why("no family bars: no scores yet", "family-bars")
    lo_axis, hi_axis = NORM_SPAN if scale == "normalised" else (0.0, 1.0)
    left, width, row_h, top = 190.0, 220.0, 17.0, 20.0
    n_rows = sum(len(m) + 1 for _, m in families)
    height = top + row_h * n_rows + 30

    def x(v: float) -> float:
        return left + (min(max(v, lo_axis), hi_axis) - lo_axis) / (hi_axis - lo_axis) * width

    body = []
    ticks = ([(-1, "−1"), (0, "0 still"), (1, "1 twin"), (2, "2")] if scale == "normalised"
             else [(0, "worst end"), (0.5, "½"), (1, "best end")])
    for t, name in ticks:
        body.append(line(x(t), top - 4, x(t), height - 26, GRID if t not in (0, 1) else MUTED,
                         1, "" if t not in (0, 1) else ' stroke-dasharray="3 3"'))
        body.append(text(x(t), height - 12, name, "middle", fill=MUTED, size=10))
    y = top
    for k, (family, rows) in enumerate(families):
        body.append(text(4, y + 12, family, weight="700"))
        y += row_h
        colour = SERIES[k % len(SERIES)]
        for c, shown, bar, count, why in rows:
            arrow = {"higher": " ↑", "lower": " ↓"}.get(direction_of(c, summary), "")
            parts = [text(left - 6, y + 12, f"{c}{arrow}", "end")]
            if bar is not None:
                x0, x1 = x(0.0 if scale == "normalised" else lo_axis), x(bar)
                parts.append(f'<rect x="{n(min(x0, x1))}" y="{n(y + 3)}" '
                             f'width="{n(max(abs(x1 - x0), 1.5))}" height="{n(row_h - 6)}" '
                             f'fill="{colour}"/>')
                if bar > hi_axis or bar < lo_axis:
                    edge = x(bar) + (4 if bar > hi_axis else -4)
                    parts.append(text(edge, y + 12, "›" if bar > hi_axis else "‹", "middle",
                                      weight="700"))
            parts.append(text(left + width + 10, y + 12,
                              shown + (f"  [{fmt(bar, 3)}]" if bar is not None and
                                       scale == "normalised" else "")
                              + (f"  no bar: {why}" if why and why != "no value" else ""),
                              fill="" if bar is not None else MUTED))
            body.append(f'<g class="bar" data-metric={attr(c)} data-family={attr(family)} '
                        f'data-value={attr(repr(bar) if bar is not None else "")} '
                        f'data-n="{count}">' + "".join(parts) + "</g>")
            y += row_h
    caption = ("metric means over the model's successes by family, longer is better: "
               + ("the variance-normalised score (0 = the still clip, 1 = the ground truth's "
                  "twin; raw mean and its n beside, normalised value in brackets)"
                  if scale == "normalised" else
                  "the mean's place in the metric's declared range, the best end at the right "
                  "(raw mean and its n beside)"))
    return (f'<figure class="plot family-bars" data-scale="{scale}"><figcaption>'
            f'{esc(caption)}</figcaption>'
            + svg(left + width + 230, height, "".join(body), caption) + "</figure>")
