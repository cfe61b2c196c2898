"""Typed schemas for every config group, so a misspelt key fails when the config is composed.

Each YAML entry starts with ``defaults: [schema_<group>]``; plugins with extra settings register a
subclass under their own name through ``visphy_register_configs``. Registered through the same
``visphy`` entry-point group as every other plugin.

Value conventions, checked by `visphy_core.config.check` before any work (plugin schemas too):

* a key with a fixed set of choices is a `StrEnum` whose member names equal their values
  (OmegaConf rejects anything else when the config is composed; members compare equal to str);
* a number with a range declares it in the field's metadata,
  ``field(default=60.0, metadata={"min": 1, "max": 3600})`` (either bound optional, inclusive);
  on a list of numbers the bounds apply to every item, and ``"min_items"`` bounds its length;
* ``model.name``, ``engine.name``, ``judge.name`` and ``metrics.names`` are checked against the
  installed plugins.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any, Optional

from omegaconf import MISSING

from visphy_core.api.config_schema import EngineConfig, JudgeConfig, ModelConfig
from visphy_core.api.headline import (
    DEFAULT_CEILING,
    DEFAULT_COMPONENTS,
    DEFAULT_NAME,
    DEFAULT_PENALTIES,
)
from visphy_core.api.hookspecs import hookimpl


class TrackingBackend(StrEnum):
    mlflow = "mlflow"
    none = "none"


class SummaryMode(StrEnum):
    short = "short"
    full = "full"


@dataclass
class PathsConfig:
    root: str = "visphy-out"
    data_dir: str = MISSING
    runs_dir: str = MISSING
    cache_dir: str = MISSING
    # the ground-truth store (visphy_core/scoring/ground_truth.py): normalisation anchors and twin
    # renders, shared by every run of the data dir; null: none (anchors in the run cache only)
    ground_truth_dir: Optional[str] = MISSING


@dataclass
class PromptConfig:
    frames: list[int] = field(default_factory=lambda: [1, 10],
                              metadata={"min": 1, "min_items": 1})  # 1-based key frames
    detection: bool = True
    forecast_only: bool = False
    timed: bool = False


@dataclass
class RunConfig:
    retry: bool = True
    fallback: bool = True
    seed: int = field(default=0, metadata={"min": 0, "max": 2**32 - 1})
    cache: bool = True
    progress: bool = True
    # The end-of-run summary: short (headline, a few columns per scene, means per family) or
    # full (every metric under every pairing, with a legend). Changes no row.
    summary: SummaryMode = SummaryMode.short
    # Stop making new model/judge calls once this much USD is spent (null: no cap).
    cost_cap_usd: Optional[float] = field(default=None, metadata={"min": 0})
    # Model calls started ahead of the scene being rendered (they overlap with rendering).
    prefetch: int = field(default=8, metadata={"min": 0, "max": 1024})
    # Scenes rendered or scored at once (visphy_core.execute.scheduler): auto (the usable cores, as
    # many as the available memory holds) or a whole number ≥ 1. Rows do not depend on it.
    workers: str = "auto"
    # Which unfinished run this command continues: auto (the newest one with this command's
    # config that no process holds), never (always a new run directory), or the path of a
    # run directory (that one: same config, not finished, not in use).
    resume: str = "auto"


class ReferenceSource(StrEnum):
    spec = "spec"   # written deterministically from the ground-truth spec and contact events
    llm = "llm"     # written by the model in reference.model from uniformly sampled GT frames


@dataclass
class ReferenceConfig:
    """The reference description of each scene for the text metrics (one per scene, shared by
    every model, cached at the dataset level; never made from a model's own output)."""

    source: ReferenceSource = ReferenceSource.spec
    model: Optional[str] = None     # source=llm: a model config name (conf/model/<name>.yaml)
    frames: int = field(default=8, metadata={"min": 1, "max": 64})


@dataclass
class RenderConfig:
    """``visphy render``'s defaults (`visphy_core.cli.render`)."""

    dataset: str = MISSING   # the dataset config holding --scene when --dataset is not given
    model: str = MISSING     # the model that plays a reply file back (no model call)


@dataclass
class DatasetConfig:
    name: str = MISSING
    # a dataset plugin's name (`python -m visphy_core plugins`): generated (the paper's benchmark
    # regenerated from its templates), original (the published layout on disk), tiny (a fixture)
    source: str = "generated"
    seed: int = field(default=0, metadata={"min": 0})  # generated: the benchmark's seed
    # generated: the generator version to load (None: this visphy's, built on first use; an
    # older one is loaded from its existing build, never regenerated)
    version: Optional[int] = field(default=None, metadata={"min": 2})
    lossless: bool = False             # generated: exact-RGB clips instead of the published crf 23
    root: Optional[str] = None         # original layout: folder holding <split>/
    split: Optional[str] = None
    scenes: Optional[list[str]] = None  # explicit scene ids
    limit: Optional[int] = field(default=None, metadata={"min": 1})  # N scenes across the split
    shard: Optional[str] = None        # "i/n": shard i (0-based) of n disjoint parts (merge)


@dataclass
class PaperAlignConfig:
    """The upstream protocol's search; `visphy_core.scoring.alignment.AlignParams`."""

    sample_every: int = 3
    downsample: int = 64
    max_offset: int = 30
    top_k: int = 5
    max_samples: int = 16
    window: int = 3
    offset_penalty: float = 0.05
    dtw: bool = True              # upstream always runs DTW after the offset step
    dtw_size: int = 48
    dtw_step_penalty: float = 0.005


@dataclass
class VisphyAlignConfig(PaperAlignConfig):
    """visphy's aligned variant: the same search on every frame, no DTW (it can hide the very
    timing errors physics gets wrong)."""

    sample_every: int = 1
    dtw: bool = False


class HeadlineCeiling(StrEnum):
    ideal = "ideal"
    twin = "twin"


@dataclass
class HeadlineConfig:
    enabled: bool = True
    name: str = DEFAULT_NAME
    components: list[str] = field(default_factory=lambda: list(DEFAULT_COMPONENTS))
    clip: list[float] = field(default_factory=lambda: [-1.0, 1.0])
    # each component's 1: ideal (the metric's best value) or twin (the ground truth's twin)
    ceiling: HeadlineCeiling = HeadlineCeiling[DEFAULT_CEILING]
    # metric -> weight: subtracted from the components' mean (weight × value); {} for none
    penalties: dict[str, float] = field(default_factory=lambda: dict(DEFAULT_PENALTIES))


@dataclass
class MetricsConfig:
    names: list[str] = field(default_factory=lambda: ["psnr", "ssim"])
    protocol: list[str] = field(  # visphy, paper (checked in config_check)
        default_factory=lambda: ["visphy", "paper"])
    aligned: bool = True          # visphy: also the aligned variant (.aligned, align.offset/err)
    align: VisphyAlignConfig = field(default_factory=VisphyAlignConfig)
    paper: PaperAlignConfig = field(default_factory=PaperAlignConfig)
    # Model weights (LPIPS/DISTS backbones, CLIP, DINO, RAFT, RoBERTa): searched here first, then
    # $VISPHY_WEIGHTS and $TORCH_HOME/hub/checkpoints (visphy_core.api.weights). Never
    # downloaded.
    weights_dir: Optional[str] = None
    # The spec track: the model's S simulated by visphy and replayed by the engine's reference
    # program, scored under the same protocol (``spec.`` columns; visphy_core.spec.spec_track).
    spec_track: bool = True
    # Variance-normalised columns (``norm.<metric>``: 0 = the frozen first frame, 1 = the ground
    # truth re-simulated with an imperceptible nudge; visphy_core.scoring.normalisation). Off by
    # default: the twin's render and every metric on it and on the still clip were half of a
    # first run's time (docs/performance.md); the headline needs only its components' floors.
    variance_norm: bool = False
    device: str = "cpu"           # torch device of the learned metrics (cpu, cuda, cuda:1…)
    max_pairs: dict[str, int] = field(default_factory=dict)  # per metric: pairs scored at most
    # The headline physics score (visphy_core.scoring.headline): its components, each between the
    # still clip (0) and the twin or the ideal value (1), clipped, averaged per scene.
    headline: HeadlineConfig = field(default_factory=HeadlineConfig)


@dataclass
class TrackingConfig:
    backend: TrackingBackend = TrackingBackend.mlflow
    experiment: str = "visphy"
    uri: Optional[str] = None
    artifact_root: Optional[str] = None
    log_videos: bool = False   # also log each scene's generated clip (videos/<scene>/video.mp4)


@dataclass
class SandboxConfig:
    # Untrusted (model-written) programs run only inside namespaces (bubblewrap); where the kernel
    # refuses them visphy refuses to run such programs unless this is set.
    allow_unisolated: bool = False
    # Per-page memory cap of the browser engines (renderer/GPU process RSS; JS heap gets 3/4).
    browser_memory_mb: int = field(default=2048, metadata={"min": 64})


@dataclass
class RootConfig:
    dataset: Any = MISSING
    model: Any = MISSING
    engine: Any = MISSING
    metrics: Any = MISSING
    judge: Any = field(default_factory=dict)
    tracking: Any = MISSING
    paths: PathsConfig = field(default_factory=PathsConfig)
    prompt: PromptConfig = field(default_factory=PromptConfig)
    run: RunConfig = field(default_factory=RunConfig)
    sandbox: SandboxConfig = field(default_factory=SandboxConfig)
    reference: ReferenceConfig = field(default_factory=ReferenceConfig)
    render: RenderConfig = field(default_factory=RenderConfig)


GROUP_SCHEMAS = {
    "dataset": DatasetConfig, "model": ModelConfig, "engine": EngineConfig,
    "metrics": MetricsConfig, "judge": JudgeConfig, "tracking": TrackingConfig,
}


@hookimpl
def visphy_register_configs(config_store):
    config_store.store(name="schema_root", node=RootConfig)
    for group, schema in GROUP_SCHEMAS.items():
        config_store.store(group=group, name=f"schema_{group}", node=schema)
