"""Typed schemas for every config group, so a misspelt key fails when the config is composed.

Each YAML entry starts with ``defaults: [schema_<group>]``; plugins with extra settings register a
subclass under their own name through ``visphy_register_configs``. Registered through the same
``visphy`` entry-point group as every other plugin.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Optional

from omegaconf import MISSING

from visphy_core.hookspecs import hookimpl


@dataclass
class PathsConfig:
    root: str = "visphy-out"
    data_dir: str = MISSING
    runs_dir: str = MISSING
    cache_dir: str = MISSING


@dataclass
class PromptConfig:
    frames: list[int] = field(default_factory=lambda: [1, 10])
    detection: bool = True
    forecast_only: bool = False
    timed: bool = False


@dataclass
class RunConfig:
    retry: bool = True
    fallback: bool = True
    seed: int = 0
    cache: bool = True
    progress: bool = True


@dataclass
class DatasetConfig:
    name: str = MISSING
    source: str = "generated"          # "generated" (visphy's builder) or "original"
    seed: int = 0                      # generated: the benchmark's seed
    root: Optional[str] = None         # original layout: folder holding <split>/
    split: Optional[str] = None
    scenes: Optional[list[str]] = None  # explicit scene ids
    limit: Optional[int] = None         # first N scenes


@dataclass
class ModelConfig:
    name: str = MISSING


@dataclass
class EngineConfig:
    name: str = MISSING
    timeout_s: float = 60.0


@dataclass
class MetricsConfig:
    names: list[str] = field(default_factory=lambda: ["psnr", "ssim"])


@dataclass
class JudgeConfig:
    name: str = "none"


@dataclass
class TrackingConfig:
    backend: str = "mlflow"            # "mlflow" or "none"
    experiment: str = "visphy"
    uri: Optional[str] = None
    artifact_root: Optional[str] = None


@dataclass
class RootConfig:
    dataset: Any = MISSING
    model: Any = MISSING
    engine: Any = MISSING
    metrics: Any = MISSING
    judge: Any = MISSING
    tracking: Any = MISSING
    paths: PathsConfig = field(default_factory=PathsConfig)
    prompt: PromptConfig = field(default_factory=PromptConfig)
    run: RunConfig = field(default_factory=RunConfig)


GROUP_SCHEMAS = {
    "dataset": DatasetConfig, "model": ModelConfig, "engine": EngineConfig,
    "metrics": MetricsConfig, "judge": JudgeConfig, "tracking": TrackingConfig,
}


@hookimpl
def visphy_register_configs(config_store):
    config_store.store(name="schema_root", node=RootConfig)
    for group, schema in GROUP_SCHEMAS.items():
        config_store.store(group=group, name=f"schema_{group}", node=schema)
