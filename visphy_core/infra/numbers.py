"""One way to write a score for people, shared by the end-of-run console, the HTML report and
the analysis tables, so one value reads the same wherever it is shown."""

from __future__ import annotations

import math

MISSING = "—"


def number(value, digits: int = 4) -> str:
    """``value`` with ``digits`` significant figures (``0.9876``, ``34.21``, ``4.701e-05``);
    whole numbers below 10⁶ as integers, larger magnitudes without an exponent up to 10¹⁵;
    ``—`` for None, ``NaN``, ``∞`` / ``−∞``; never a negative zero (``-0.0000`` reads as a
    sign where there is none): a value that rounds to zero is written ``0``."""
    if value is None:
        return MISSING
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return str(value)
    try:
        v = float(value)
    except (TypeError, ValueError):
        return str(value)
    if math.isnan(v):
        return "NaN"
    if math.isinf(v):
        return "∞" if v > 0 else "−∞"
    if v.is_integer() and abs(v) < 1e6:
        return str(int(v))
    if 10 ** digits <= abs(v) < 1e15:
        return f"{v:.0f}"
    text = f"{v:.{digits}g}"
    if text.startswith("-") and float(text) == 0:
        return text[1:]
    return text
