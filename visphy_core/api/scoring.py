"""The API for scoring clips outside a run, for plugins that study the metrics themselves
(study plugins: they make their own clips and score them as a run would): one scene's metrics
under a scoring protocol (`visphy_core.scoring.score`), the headline
(`visphy_core.scoring.headline`) and the ground truth's twin
(`visphy_core.scoring.normalisation`)."""

from __future__ import annotations

from visphy_core.scoring.headline import Headline, scene_headline
from visphy_core.scoring.normalisation import twin_spec
from visphy_core.scoring.score import ScoringProtocol, score_scene

__all__ = [
    "Headline", "scene_headline", "score_scene", "ScoringProtocol", "twin_spec",
]
