"""Small inline-SVG building blocks of the report's plots: no script, no external file but the
report's own images, every text escaped (the page's Content Security Policy allows exactly
that). Coordinates are rounded to 0.1 so pages stay small and byte-identical across writes."""

from __future__ import annotations

import math
from typing import Iterable, Sequence

from visphy_core.report.markup import attr, esc

#: Line colours of the series (colour-blind-safe: Okabe–Ito).
SERIES = ("#0072b2", "#d55e00", "#009e73", "#cc79a7", "#e69f00", "#56b4e9")
MUTED = "#5c6577"
GRID = "#d9dde5"
FONT = 'font-family="system-ui, DejaVu Sans, sans-serif"'


def n(value: float) -> str:
    """A coordinate: one decimal, no trailing zero."""
    text = f"{value:.1f}"
    return text[:-2] if text.endswith(".0") else text


def svg(width: float, height: float, body: str, label: str, cls: str = "plot",
        extra: str = "") -> str:
    """An ``<svg>`` of ``width`` × ``height`` user units, scaled to its container's width."""
    return (f'<svg class={attr(cls)} viewBox="0 0 {n(width)} {n(height)}" '
            f'width="{n(width)}" height="{n(height)}" role="img" aria-label={attr(label)} '
            f'{FONT} font-size="11"{extra}><title>{esc(label)}</title>{body}</svg>')


def text(x: float, y: float, value: object, anchor: str = "start", cls: str = "",
         fill: str = "", size: float | None = None, weight: str = "") -> str:
    extra = (f' class={attr(cls)}' if cls else "") + (f' fill="{fill}"' if fill else "") + (
        f' font-size="{n(size)}"' if size else "") + (f' font-weight="{weight}"' if weight else "")
    return (f'<text x="{n(x)}" y="{n(y)}" text-anchor="{anchor}"{extra}>{esc(value)}</text>')


def line(x1: float, y1: float, x2: float, y2: float, stroke: str = GRID, width: float = 1,
         extra: str = "") -> str:
    return (f'<line x1="{n(x1)}" y1="{n(y1)}" x2="{n(x2)}" y2="{n(y2)}" stroke="{stroke}" '
            f'stroke-width="{n(width)}"{extra}/>')


def points(xy: Iterable[tuple[float, float]]) -> str:
    return " ".join(f"{n(x)},{n(y)}" for x, y in xy)


def runs_of(values: Sequence[object]) -> list[list[int]]:
    """Indices of ``values`` in runs of consecutive entries that are not None."""
    out: list[list[int]] = []
    for i, v in enumerate(values):
        if v is None:
            continue
        if out and out[-1][-1] == i - 1:
            out[-1].append(i)
        else:
            out.append([i])
    return out


def nice_ticks(lo: float, hi: float, count: int = 5) -> list[float]:
    """About ``count`` round tick values covering [lo, hi]."""
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
        return [lo]
    raw = (hi - lo) / max(count - 1, 1)
    mag = 10 ** math.floor(math.log10(raw))
    step = next(m * mag for m in (1, 2, 2.5, 5, 10) if m * mag >= raw)
    first = math.ceil(lo / step - 1e-9) * step
    out = []
    v = first
    while v <= hi + 1e-9 * step:
        out.append(round(v, 10))
        v += step
    return out


def hex_colour(rgb: Sequence[int]) -> str:
    return "#" + "".join(f"{int(c):02x}" for c in list(rgb)[:3])
