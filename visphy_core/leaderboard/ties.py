"""Which differences between rows are real: a paired bootstrap over the scenes two runs share.

Rows are compared within a dataset only. Two rows are *separated* when the paired bootstrap's
95 % interval of their headline difference (`visphy_core.analysis.bootstrap.paired_bootstrap`,
over the scenes both scored) excludes 0 **and** the difference is at least the validity study's
discriminative power on that many scenes (`visphy_core.api.validity.power_at`: a smaller
difference is one the headline's own noise between two wrong simulators makes). A row's rank
is 1 + the number of rows separated from it and above it, so rows no comparison separates share
a rank: the rank is the tie label. A row that shares fewer than two scenes with every other row
of its dataset is not ranked, and each such pair is named in a warning.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import combinations

import numpy as np

from visphy_core.analysis.bootstrap import PairedDifference, paired_bootstrap, resample_indices
from visphy_core.api.validity import power_at
from visphy_core.leaderboard.entries import Entry


@dataclass
class Comparison:
    """Row ``a`` against row ``b`` on their shared scenes."""

    a: str
    b: str
    shared: int
    result: PairedDifference | None
    power: float | None
    separated: bool
    better: str | None


@dataclass
class Standing:
    """A row's place: its rank (None: not comparable) and the rows it cannot be told from."""

    rank: int | None = None
    tied_with: list[str] = field(default_factory=list)
    compared: int = 0


def compare(a: Entry, b: Entry, draws: dict[int, np.ndarray]) -> Comparison:
    ids = sorted(set(a.values.index) & set(b.values.index))
    if len(ids) < 2:
        return Comparison(a.slug, b.slug, len(ids), None, None, False, None)
    if len(ids) not in draws:
        draws[len(ids)] = resample_indices(len(ids))
    r = paired_bootstrap(a.values.loc[ids].to_numpy(np.float64),
                         b.values.loc[ids].to_numpy(np.float64), indices=draws[len(ids)])
    power = power_at(len(ids))
    separated = not (r.ci_low <= 0 <= r.ci_high) and (power is None or abs(r.diff) >= power)
    better = (a.slug if r.diff > 0 else b.slug) if separated else None
    return Comparison(a.slug, b.slug, len(ids), r, power, separated, better)


def standings(entries: list[Entry]) -> tuple[dict[str, Standing], list[Comparison], list[str]]:
    """Each row's `Standing` (by slug), every comparison made, and the warnings (pairs of one
    dataset sharing no scenes, or only part of them)."""
    out = {e.slug: Standing() for e in entries}
    comparisons: list[Comparison] = []
    warnings: list[str] = []
    draws: dict[int, np.ndarray] = {}
    datasets: dict[str, list[Entry]] = {}
    for e in entries:
        if len(e.values):
            datasets.setdefault(e.dataset, []).append(e)
    for dataset, members in datasets.items():
        for a, b in combinations(members, 2):
            c = compare(a, b, draws)
            comparisons.append(c)
            if c.result is None:
                warnings.append(f"{a.label} and {b.label} share {c.shared} scene(s) of "
                                f"{dataset}: their headlines are not compared (run them on the "
                                "same scenes to rank them against each other)")
                continue
            out[a.slug].compared += 1
            out[b.slug].compared += 1
            if c.shared < max(len(a.values), len(b.values)):
                warnings.append(f"{a.label} ({len(a.values)} scenes) and {b.label} "
                                f"({len(b.values)} scenes) are compared on the {c.shared} "
                                "scenes they share")
            if not c.separated:
                out[a.slug].tied_with.append(b.label)
                out[b.slug].tied_with.append(a.label)
        for e in members:
            if out[e.slug].compared == 0 and len(members) > 1:
                continue
            above = sum(1 for c in comparisons if c.better and c.better != e.slug
                        and e.slug in (c.a, c.b))
            out[e.slug].rank = 1 + above
    for s in out.values():
        s.tied_with = sorted(set(s.tied_with))
    return out, comparisons, warnings
