"""Score columns grouped the way a reader compares them: the plain pairing first, then the
other pairings and tracks of the same metrics (see README, *Metrics and scoring protocols*)."""

from __future__ import annotations

from visphy_core.results.columns import JUDGE_PREFIX, column_direction, decompose_column

#: Groups in display order: (key, heading).
GROUPS = (
    ("visphy", "visphy pairing (frames by index, unaligned)"),
    ("judge", "judges"),
    ("aligned", "temporally aligned"),
    ("paper", "paper protocol (every 3rd frame, aligned)"),
    ("align", "alignment (offset, cost)"),
    ("spec", "spec track (the model's S simulated and replayed)"),
    ("norm", "variance-normalised (0 = the static floor, 1 = the ground truth's twin)"),
)
HEADINGS = dict(GROUPS)
#: Groups shown unfolded.
PRIMARY = ("visphy", "judge")


def group_of(column: str) -> str:
    """The group (`GROUPS`) of a column, from its name spelt out
    (`visphy_core.results.columns.decompose_column`): normalised, then the spec track, then
    judges, alignments and the pairing."""
    spelt = decompose_column(column)
    if spelt.normalised:
        return "norm"
    if spelt.track == "spec":
        return "spec"
    if spelt.kind in ("judge", "alignment"):
        return "judge" if spelt.kind == "judge" else "align"
    return str(spelt.pairing)


def grouped(columns: list[str]) -> list[tuple[str, list[str]]]:
    """``columns`` by group, groups in display order, columns in their given order."""
    out = []
    for key, _ in GROUPS:
        members = [c for c in columns if group_of(c) == key]
        if members:
            out.append((key, members))
    return out


def direction_of(column: str, summary: dict) -> str:
    info = (summary.get("metrics") or {}).get(column) or {}
    if info.get("direction") in ("higher", "lower"):
        return str(info["direction"])
    base = {name: str(m.get("direction")) for name, m in (summary.get("metric_info") or {}).items()
            if isinstance(m, dict)}
    return column_direction(column, base)


def label(column: str) -> str:
    """A column's display name (judges by their key)."""
    return f"judge: {column.removeprefix(JUDGE_PREFIX)}" if column.startswith(JUDGE_PREFIX) \
        else column
