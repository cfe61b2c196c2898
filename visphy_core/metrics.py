"""The metric contract: declared name, direction and range next to the computation (pyiqa style).

A metric that cannot run here (weights missing, extra not installed) says so through
`unavailable_reason`; the scorer then records it as unavailable, never as a number.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from visphy_core.scene import Scene

HIGHER, LOWER = "higher", "lower"


@dataclass
class MetricInput:
    """One scene's temporally aligned clips (N×H×W×3 uint8) and the model's text outputs."""

    scene: Scene
    reference: np.ndarray
    generated: np.ndarray
    analysis: str | None = None
    spec: dict | None = None
    reference_text: str | None = None  # the scene's reference description (text metrics)


class Metric(ABC):
    name: str = ""
    direction: str = HIGHER          # "higher" or "lower" is better
    score_range: tuple[float, float] = (float("-inf"), float("inf"))
    needs: tuple[str, ...] = ("frames",)
    version: str = "1"

    def unavailable_reason(self) -> str | None:
        """Why this metric cannot be computed here (None when it can)."""
        return None

    @abstractmethod
    def compute(self, inp: MetricInput) -> float:
        """The scene-level value (mean over aligned frame pairs for frame metrics)."""

    def describe(self) -> dict:
        return {"name": self.name, "direction": self.direction,
                "range": list(self.score_range), "needs": list(self.needs)}
