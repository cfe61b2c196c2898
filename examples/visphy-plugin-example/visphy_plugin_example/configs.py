"""Config-group entries of the example plugin: what ``model=example_still``,
``engine=example_boxes`` and ``judge=example_pixels`` compose to.

Each entry is a structured config (a dataclass extending the contract's schema in
`visphy_core.api.config_schema`) stored in Hydra's ConfigStore, so a misspelt key fails when
the config is composed. The values are checked before any work (`visphy_core.config.check`):
a key with a fixed set of choices is a `StrEnum` whose member names equal their values; a
number's range is in its field's metadata (bounds inclusive, either optional).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

from visphy_core.api.config_schema import EngineConfig, JudgeConfig, ModelConfig
from visphy_core.api.hookspecs import hookimpl


@dataclass
class StillConfig(ModelConfig):
    name: str = "example_still"


@dataclass
class BoxesConfig(EngineConfig):
    name: str = "example_boxes"
    timeout_s: float = 10.0  # the range (1 … 3600) is EngineConfig's: a subclass keeps it


class Reduce(StrEnum):
    mean = "mean"  # the mean difference over the clip
    max = "max"    # the worst frame's


@dataclass
class PixelJudgeConfig(JudgeConfig):
    name: str = "example_pixels"
    scale: float = field(default=32.0, metadata={"min": 1, "max": 255})  # difference → 1/10
    reduce: Reduce = Reduce.mean


@hookimpl
def visphy_register_configs(config_store):
    config_store.store(group="model", name="example_still", node=StillConfig)
    config_store.store(group="engine", name="example_boxes", node=BoxesConfig)
    # a judge's entry lives at judge.<name>, so several judges can be selected at once
    config_store.store(group="judge", name="example_pixels", node=PixelJudgeConfig,
                       package="judge.example_pixels")
