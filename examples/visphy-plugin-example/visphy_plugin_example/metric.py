"""Metric ``example_mae``: the mean absolute pixel difference between paired frames.

A ``pairs`` metric: the scorer hands it batches of (reference, generated) frame pairs and
averages its values over each pairing (by time, aligned, the paper's sampled one), so one
function serves every protocol. ``metrics.names=[psnr,example_mae]`` selects it.
"""

from __future__ import annotations

import numpy as np

from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.metrics import LOWER, PAIRS, Metric


class MeanAbsoluteError(Metric):
    name = "example_mae"
    direction = LOWER               # lower is better
    score_range = (0.0, 255.0)
    family = "pixel"
    kind = PAIRS
    needs = ("frames",)
    weights = None                  # nothing to load: always available
    version = "1"                   # bump when the value changes: cached scores are keyed by it

    def pair_values(self, reference: np.ndarray, generated: np.ndarray) -> np.ndarray:
        """K values for two K×H×W×3 uint8 batches."""
        diff = reference.astype(np.float64) - generated.astype(np.float64)
        return np.abs(diff).mean(axis=(1, 2, 3))


@hookimpl
def visphy_register_metrics(register):
    register(MeanAbsoluteError())  # an instance: it carries its own name
