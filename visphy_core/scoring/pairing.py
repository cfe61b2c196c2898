"""How a generated clip is paired with its reference in time: the alignment settings
(`AlignParams`) and the two named ones, upstream's (`PAPER`) and visphy's aligned variant
(`EVERY_FRAME`). The search itself is `visphy_core.scoring.alignment.align`; the `Alignment` it
returns is part of the metric contract (`visphy_core.api.metrics`)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class AlignParams:
    sample_every: int = 1
    downsample: int = 64
    max_offset: int = 30          # in sampled frames
    top_k: int = 5
    max_samples: int = 16
    window: int = 3
    offset_penalty: float = 0.05
    min_overlap: int = 3          # sampled frames that must overlap for an offset to count
    dtw: bool = False
    dtw_size: int = 48
    dtw_step_penalty: float = 0.005
    # "visphy": this module's search (DTW, when on, replaces it); "upstream": the paper
    # protocol's rules (visphy_core.scoring.paper_protocol; DTW, when on, runs after the offset
    # step)
    rules: str = "visphy"


#: The upstream evaluation's settings and rules (``evaluate_pair(sample_every=3)``: DTW after
#: the offset step, as upstream's ``auto_align`` always runs it).
PAPER = AlignParams(sample_every=3, dtw=True, rules="upstream")
#: visphy's aligned variant: every frame.
EVERY_FRAME = AlignParams(sample_every=1)
