"""The names of a run's score columns and what they say.

A row's scores are columns ``score_<name>`` (`SCORE`). ``<name>`` is a metric's name under the
unaligned pairing (``psnr``), with ``.aligned`` under the aligned pairing, ``paper.`` under the
paper protocol, ``align.`` for an alignment's own offset and cost, ``norm.`` for a
variance-normalised value, ``spec.`` for the spec track (the model's stated physics replayed),
``judge_`` for a judge's verdict; the prefixes combine (``spec.norm.psnr``).
"""

from __future__ import annotations

from typing import NamedTuple

SCORE = "score_"        # a row's score columns
SPEC_PREFIX = "spec."   # the spec track's columns (visphy_core.spec.spec_track)
NORM_PREFIX = "norm."   # variance-normalised (visphy_core.scoring.normalisation)
PAPER_PREFIX = "paper."  # the paper protocol (visphy_core.scoring.paper_protocol)
ALIGNED_SUFFIX = ".aligned"
ALIGN_PREFIX = "align."
JUDGE_PREFIX = "judge_"


def norm_column(column: str) -> str:
    """``psnr`` → ``norm.psnr``; ``spec.psnr`` → ``spec.norm.psnr``."""
    if column.startswith(SPEC_PREFIX):
        return SPEC_PREFIX + NORM_PREFIX + column[len(SPEC_PREFIX):]
    return NORM_PREFIX + column


def column_direction(column: str, base: dict[str, str]) -> str:
    """``higher``/``lower`` of a score column from its metric's declared direction (``base``:
    metric name → direction): derived pairings keep the metric's direction,
    variance-normalised scores and judges are ↑, alignment offsets and costs ↓."""
    if column.startswith(JUDGE_PREFIX):
        return "higher"
    name = column.removeprefix(SPEC_PREFIX)
    if name.startswith(NORM_PREFIX):
        return "higher"
    name = name.removeprefix(PAPER_PREFIX).removesuffix(ALIGNED_SUFFIX)
    if name.startswith(ALIGN_PREFIX):
        return "lower"
    return base.get(name, "higher")


class ScoreColumn(NamedTuple):
    """A score column's name spelt out (`decompose_column`)."""

    kind: str
    metric: str
    pairing: str | None
    track: str
    normalised: bool


def decompose_column(column: str, headline: str | None = None) -> ScoreColumn:
    """``spec.norm.psnr.aligned`` → (metric, psnr, aligned, spec, True); ``headline`` names
    the run's headline column (``physics_score``), reported as kind ``headline``."""
    name = column
    track = "program"
    if name.startswith(SPEC_PREFIX):
        track, name = "spec", name[len(SPEC_PREFIX):]
    normalised = name.startswith(NORM_PREFIX)
    name = name.removeprefix(NORM_PREFIX)
    if name.startswith(JUDGE_PREFIX):
        return ScoreColumn("judge", name[len(JUDGE_PREFIX):], None, track, normalised)
    pairing = "visphy"
    if name.startswith(PAPER_PREFIX):
        pairing, name = "paper", name[len(PAPER_PREFIX):]
    if name.startswith(ALIGN_PREFIX):
        return ScoreColumn("alignment", name[len(ALIGN_PREFIX):],
                           "aligned" if pairing == "visphy" else pairing, track, normalised)
    if pairing == "visphy" and name.endswith(ALIGNED_SUFFIX):
        pairing, name = "aligned", name[:-len(ALIGNED_SUFFIX)]
    kind = "headline" if headline is not None and name == headline else "metric"
    return ScoreColumn(kind, name, pairing, track, normalised)


def score_column(kind: str, metric: str, pairing: str | None = "visphy",
                 track: str = "program", normalised: bool = False) -> str:
    """The column name of a decomposed score (the inverse of `decompose_column`)."""
    if kind == "judge":
        name = JUDGE_PREFIX + metric
    elif kind == "alignment":
        name = (PAPER_PREFIX if pairing == "paper" else "") + ALIGN_PREFIX + metric
    elif pairing == "paper":
        name = PAPER_PREFIX + metric
    elif pairing == "aligned":
        name = metric + ALIGNED_SUFFIX
    else:
        name = metric
    if normalised:
        name = NORM_PREFIX + name
    return SPEC_PREFIX + name if track == "spec" else name
