"""The metric contract: what a metric is, declared once next to its computation (pyiqa style).

Every metric declares its ``name``, ``direction`` (``higher`` or ``lower`` is better),
``score_range``, ``family`` (pixel, perceptual, semantic, text, motion, motion_mask, physics),
``needs``
(``frames``, ``analysis``, ``reference_text``, ``spec``…) and ``weights`` (None: weight-free;
else what it loads and how to supply it). A metric that cannot run here (weights missing, extra
not installed) says so through `unavailable_reason`, with the reason and how to fix it; the
scorer then records it as unavailable, never as a number.

Three kinds of computation (``kind``):

* ``pairs``: one value per (reference frame, generated frame) pair, `pair_values` on a batch of
  pairs; the scorer evaluates each distinct pair once and averages over each pairing (the
  unaligned time pairing, the aligned one, the paper's sampled one);
* ``sequence``: a value from the paired sequences (optical flow between consecutive paired
  frames, object tracks), `compute_sequence` given the `Alignment`;
* ``scene``: one value per scene, `compute` (text metrics, spec metrics, or any metric written
  against the original single-method contract).
"""

from __future__ import annotations

from abc import ABC
from dataclasses import dataclass, field

import numpy as np

from visphy_core.api.scene import Scene

HIGHER, LOWER = "higher", "lower"
PAIRS, SEQUENCE, SCENE = "pairs", "sequence", "scene"


@dataclass
class Alignment:
    """Which generated frame is paired with each reference frame (`visphy_core.scoring.alignment`
    makes it; a ``sequence`` metric reads it)."""

    ref_idx: np.ndarray            # reference frame indices, in time order
    gen_idx: np.ndarray            # the generated frame paired with each
    offset: int = 0                # generated = reference + offset (frames of the input clips)
    align_err: float = 0.0         # the cost of the chosen pairing, penalty excluded
    method: str = "unaligned"      # unaligned | offset | dtw
    candidates: list[tuple[int, float]] = field(default_factory=list)  # (offset, cost) refined

    @property
    def n_pairs(self) -> int:
        return int(len(self.ref_idx))

    def pairs(self) -> list[tuple[int, int]]:
        return list(zip(self.ref_idx.tolist(), self.gen_idx.tolist()))




def unaligned(n_ref: int, n_gen: int) -> Alignment:
    """Frame k with frame k (both clips already on the reference's time grid)."""
    n = min(n_ref, n_gen)
    idx = np.arange(n)
    return Alignment(ref_idx=idx, gen_idx=idx.copy(), offset=0, align_err=0.0,
                     method="unaligned")


@dataclass
class MetricInput:
    """One scene's clips on the reference's time grid (N×H×W×3 uint8: frame k at k / fps) and
    the model's text outputs."""

    scene: Scene
    reference: np.ndarray
    generated: np.ndarray
    analysis: str | None = None
    spec: dict | None = None
    reference_text: str | None = None  # the scene's reference description (text metrics)
    program: str | None = None         # the model's program source (static analysis metrics)
    language: str | None = None        # its language (``html``, ``python``…)
    extra: dict = field(default_factory=dict)  # per-scene memo shared by the metrics


class Metric(ABC):
    name: str = ""
    direction: str = HIGHER          # "higher" or "lower" is better
    score_range: tuple[float, float] = (float("-inf"), float("inf"))
    family: str = "pixel"
    kind: str = SCENE
    needs: tuple[str, ...] = ("frames",)
    weights: str | None = None       # what it loads, e.g. "AlexNet + LPIPS v0.1 linear layers"
    version: str = "1"
    # kind ``pairs``: at most this many pairs of each pairing are scored, evenly spaced in time
    # (first and last included); None: every pair. Set on costly metrics, overridable with
    # ``metrics.max_pairs.<name>``; recorded in the metric's identity.
    max_pairs: int | None = None

    def unavailable_reason(self) -> str | None:
        """Why this metric cannot be computed here, and how to make it possible (None: it can)."""
        return None

    def identity(self) -> str:
        """What changes a value: the registered name, class, version and (for loaded models)
        the weights' digest. Part of every cached score's key. The class's module is not part
        of it (names are unique in the registry), so moving a metric to another module keeps
        its cached scores and ground-truth anchors."""
        ident = f"{self.name}:{type(self).__qualname__}@{self.version}"
        return ident if self.max_pairs is None else f"{ident}/max_pairs={self.max_pairs}"

    # ----------------------------------------------------------------- the three kinds
    def pair_values(self, reference: np.ndarray, generated: np.ndarray) -> np.ndarray:
        """kind ``pairs``: K values for K frame pairs (two K×H×W×3 uint8 batches)."""
        raise NotImplementedError

    def compute_sequence(self, inp: MetricInput, alignment: "Alignment") -> float:
        """kind ``sequence``: one value from the paired sequences. It may depend on the
        alignment's pairs (``ref_idx``, ``gen_idx``) only: two pairings with the same pairs
        share one computation."""
        raise NotImplementedError

    def compute(self, inp: MetricInput) -> float:
        """kind ``scene``: the scene-level value. For a ``pairs`` metric: the mean over the
        frames paired by time."""
        if self.kind == PAIRS:
            return float(np.mean(self.pair_values(inp.reference, inp.generated)))
        raise NotImplementedError

    #: metrics that share one breakdown (e.g. every parameter-recovery error) share this key
    details_key: str | None = None

    def details(self, inp: MetricInput) -> dict | None:
        """A JSON-serialisable per-scene breakdown behind the value (what was matched, where a
        value came from), written to the scene's ``metric_details.json`` under `details_key`
        (or the metric's name). Called on every scoring, cached value or not, so it must be
        cheap; None: nothing to add."""
        return None

    def describe(self) -> dict:
        return {"name": self.name, "direction": self.direction, "family": self.family,
                "kind": self.kind, "range": list(self.score_range), "needs": list(self.needs),
                "weights": self.weights, "max_pairs": self.max_pairs,
                "unavailable": self.unavailable_reason(), "validity": self.validity()}

    def validity(self) -> dict | None:
        """This metric's figures from the validity study (`visphy_core.api.validity`:
        strict, means and monotone shares, invariance, physics drop), or None when the study
        did not score it."""
        from visphy_core.api.validity import figures

        return figures(self.name)
