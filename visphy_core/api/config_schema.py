"""The config schemas a plugin extends: a model, engine or judge plugin with settings of its own
registers a subclass of `ModelConfig`, `EngineConfig` or `JudgeConfig` (hook
``visphy_register_configs``) and its YAML names it in ``defaults``. The value conventions (ranges
in field metadata, `StrEnum` choices) are those of the core schema (`visphy_core.config.schema`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from omegaconf import MISSING


@dataclass
class ModelConfig:
    name: str = MISSING


@dataclass
class EngineConfig:
    name: str = MISSING
    timeout_s: float = field(default=60.0, metadata={"min": 1, "max": 3600})  # per scene


@dataclass
class JudgeConfig:
    """One selected judge: ``judge=<name>`` puts it at ``judge.<name>``; several judges with
    ``judge=[<name>,<other>]``; none with ``judge=none`` (the default)."""

    name: str = MISSING
