"""What a model adapter receives and returns.

A `ModelRequest` holds exactly what the paper gives a model (prompt text, key frames, detection
context). It also points at the scene and engine, which only privileged models (the oracle) may
read: API adapters must send nothing but ``prompt`` and ``images``.
"""

from __future__ import annotations

import hashlib
import json
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any

from visphy_core.engine import Engine
from visphy_core.scene import Scene


@dataclass(frozen=True)
class ImageInput:
    """One key frame as PNG bytes, with the name the prompt uses for it."""

    name: str
    png: bytes


@dataclass
class ModelRequest:
    scene_id: str
    prompt: str
    images: list[ImageInput]
    detection: dict | None
    engine_name: str
    attempt: int = 1  # 1 = first call, 2 = repair call
    scene: Scene | None = field(default=None, repr=False)   # privileged (oracle only)
    engine: Engine | None = field(default=None, repr=False)  # privileged (oracle only)

    def cache_key(self, model_identity: str) -> str:
        """Hash of everything a model sees plus the model's identity and settings."""
        h = hashlib.sha256()
        h.update(model_identity.encode())
        h.update(json.dumps([self.scene_id, self.prompt, self.engine_name, self.attempt,
                             self.detection], sort_keys=True).encode())
        for img in self.images:
            h.update(img.name.encode())
            h.update(hashlib.sha256(img.png).digest())
        return h.hexdigest()


@dataclass
class ModelResponse:
    text: str
    usage: dict[str, int] = field(default_factory=dict)
    cost_usd: float | None = None
    latency_s: float = 0.0
    raw: dict[str, Any] = field(default_factory=dict)
    error: str | None = None  # the call failed (network, quota, refusal): a counted failure


class Model(ABC):
    """Base class for model plugins (see `plugins/models/oracle.py`)."""

    name: str = ""
    needs_key: str | None = None  # environment variable with the API key, if any
    version: str = "0"

    def __init__(self, cfg: Any = None):
        self.cfg = cfg

    @abstractmethod
    def generate(self, request: ModelRequest) -> ModelResponse:
        """One call to the model; never raises for provider errors (set ``error``)."""

    def identity(self) -> str:
        """Cache identity: name, version and every setting that changes the reply."""
        settings = {}
        if self.cfg is not None:
            try:
                from omegaconf import OmegaConf

                settings = OmegaConf.to_container(self.cfg, resolve=True)
            except ValueError:
                settings = dict(self.cfg)
        return json.dumps([self.name, self.version, settings], sort_keys=True, default=str)
