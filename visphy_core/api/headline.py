"""The headline physics score's defaults (``metrics.headline``), read by the config schema and by
the scorer (`visphy_core.scoring.headline`), so the config does not depend on the scorer."""

from __future__ import annotations

#: The default components, chosen by the validity study's goals
#: (``benchmarks/validity_headlines.py`` on the study's checkpoint of the whole test split,
#: docs/metrics.md): where and when things move, compared with a tolerance of 15 % of the moving
#: bodies' size (`visphy_plugins.metrics.object_level`), so how a body is drawn (size, outline,
#: colours) does not move the score while a path 20 px off does. Of every set of at most three
#: candidates it orders the most scenes strictly (44/49; with `weighted_spatial_iou_tol`, the
#: 17-scene choice, 38/49), as monotone in the dose and as invariant to the drawing.
DEFAULT_COMPONENTS = ("spatiotemporal_iou_tol",)
#: Metrics subtracted from the mean of the normalised components, each times its weight (a
#: metric a still clip cannot fail, so it has no floor to normalise against): the drawn bodies'
#: area drift beyond the reference's (`visphy_plugins.metrics.area_drift`), so a clip whose
#: bodies smear or tear (the flow extrapolation) does not score above one whose bodies move
#: rigidly somewhere wrong. Weight 0.5: the middle of the range the study's goals hold
#: (0.3–0.6, docs/metrics.md).
DEFAULT_PENALTIES = {"body_area_drift": 0.5}
DEFAULT_NAME = "physics_score"
#: Where each component's 1 comes from: ``"ideal"`` (the metric's best value) or ``"twin"`` (what
#: the ground truth's twin scores, where the scene has one; the ideal elsewhere).
CEILINGS = ("ideal", "twin")
DEFAULT_CEILING = "ideal"
