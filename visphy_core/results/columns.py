"""The names of a run's score columns and what they say.

A row's scores are columns ``score_<name>`` (`SCORE`). ``<name>`` is a metric's name under the
unaligned pairing (``psnr``), with ``.aligned`` under the aligned pairing, ``paper.`` under the
paper protocol, ``align.`` for an alignment's own offset and cost, ``norm.`` for a
variance-normalised value, ``spec.`` for the spec track (the model's stated physics replayed),
``judge_`` for a judge's verdict; the prefixes combine (``spec.norm.psnr``).
"""

from __future__ import annotations

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
