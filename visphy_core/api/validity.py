"""Each metric's validity figures, as the validity study last measured them.

``benchmarks/validity_study.py --order`` writes its summary to
``validity_summary.json`` next to this module (`SUMMARY_FILE`); the metric registry
(`Metric.describe`), the generated docs pages (``docs/reference/metrics.md``,
``docs/reference/validity.md``) and the tests read it from here, so no figure is copied by hand.
The figures of a score (the headline, or one metric on its own between the still clip and the
twin):

* ``strict``: the share of scenes where every physics-right redraw scores above every
  physics-wrong clip whose trajectory departs by at least the study's ``min_px`` (20 px), and
  every such clip above both baselines; ``means``: the same with means per kind;
* ``monotone``: the share of dose series (gravity, restitution, launch angle, playback speed)
  over which the score falls with the dose (Spearman ρ ≤ −0.9);
* ``invariance``: the largest, over the restyles, median |change| of the score normalised like
  the headline (0 = the still clip, 1 = the twin) when only the drawing changes;
* ``physics_drop``: the smallest, over the physics interventions, median drop of that
  normalised score.

A file from an older study (or none) gives None: nothing is invented.
"""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path

SUMMARY_FILE = Path(__file__).with_name("validity_summary.json")


@lru_cache(maxsize=4)
def load_summary(path: str | None = None) -> dict | None:
    """The study's summary (None when the file is missing or unreadable)."""
    try:
        return json.loads(Path(path or SUMMARY_FILE).read_text())
    except (OSError, ValueError):
        return None


def _share(block: dict | None) -> float | None:
    share = (block or {}).get("share")
    return float(share) if isinstance(share, (int, float)) else None


def figures(name: str, summary: dict | None = None) -> dict | None:
    """``name``'s validity figures (``strict``, ``means``, ``monotone``: shares in [0, 1];
    ``invariance``, ``physics_drop``: on the headline's scale; ``scenes``), or None when the
    study did not score it. ``name`` is a metric's name or ``headline``."""
    summary = load_summary() if summary is None else summary
    score = ((summary or {}).get("scores") or {}).get(name)
    if not isinstance(score, dict):
        return None
    inv = (score.get("invariance") or {}).get("max_median")
    drop = (score.get("physics_drop") or {}).get("min_median")
    return {"strict": _share(score.get("strict")), "means": _share(score.get("means")),
            "monotone": _share(score.get("monotone")),
            "invariance": float(inv) if isinstance(inv, (int, float)) else None,
            "physics_drop": float(drop) if isinstance(drop, (int, float)) else None,
            "scenes": (score.get("strict") or {}).get("scenes")}


def scope(summary: dict | None = None) -> str:
    """Which study the figures come from, in a few words (empty without a summary)."""
    summary = load_summary() if summary is None else summary
    if not summary:
        return ""
    dims = ", ".join(f"{n} {d.upper()}" for d, n in sorted((summary.get("dims") or {}).items()))
    every = int(summary.get("every") or 1)
    suffix = {1: "st", 2: "nd", 3: "rd"}.get(every % 10 if every % 100 not in (11, 12, 13)
                                           else 0, "th")
    part = f"every {every}{suffix} scene of the" if every > 1 else "the whole"
    return (f"{part} {summary.get('split', '?')} split: {summary.get('n_scenes', '?')} "
            f"scenes ({dims}), {summary.get('created', '')[:10]}")


def power_at(n_scenes: int, summary: dict | None = None) -> float | None:
    """The discriminative power on ``n_scenes`` scenes: the smallest difference in mean
    headline that a paired bootstrap over that many scenes separates at 95 %, for two
    simulators that are both wrong in different ways (the study's ``wrong`` block: the
    half-width of the bootstrap interval between two of its physics interventions, median over
    pairs, at 49 scenes, scaled by √(49 / n); redraws of right physics move the headline far
    less, so two models differ mostly as two wrong physics do). None without a study or for
    n < 2."""
    summary = load_summary() if summary is None else summary
    block = (((summary or {}).get("discriminative_power") or {}).get("wrong") or {})
    at = (block.get("n_scenes") or {})
    if n_scenes < 2 or not at:
        return None
    ref_n = 49 if "49" in at else int(min(at, key=lambda k: abs(int(k) - n_scenes)))
    value = (at.get(str(ref_n)) or {}).get("median")
    if not isinstance(value, (int, float)):
        return None
    return float(value) * (ref_n / n_scenes) ** 0.5
