"""What a model adapter receives and returns.

Privilege is structural. A `ModelRequest` holds exactly what the paper gives a model: the prompt
text, the key frames the prompt mode allows, the detection context (already pasted into the
prompt; kept apart for adapters that send it as structured data), and the clip contract the
output must meet (fps, frame count, size: the same numbers every render gets). It has no field
for the scene's ground truth. Only a model that declares ``privileged = True`` (one answering
from the ground truth) is handed a `PrivilegedRequest`, which adds the `Scene` and the `Engine`;
the pipeline builds one or the other from that flag (`build_model_request`), so an API adapter
cannot reach a spec, a trajectory or a later frame even by mistake.
"""

from __future__ import annotations

import asyncio
import hashlib
import json
from abc import ABC
from dataclasses import dataclass, field
from typing import Any

from visphy_core.api.engine import Engine
from visphy_core.api.scene import Scene


@dataclass(frozen=True)
class ImageInput:
    """One key frame as PNG bytes, with the name the prompt uses for it."""

    name: str
    png: bytes


@dataclass(frozen=True)
class OutputContract:
    """The clip every output must match (public: the renderer gets the same numbers)."""

    fps: float
    n_frames: int
    width: int
    height: int


@dataclass
class ModelRequest:
    """What an unprivileged model may see. Adapters send ``prompt`` and ``images`` only."""

    scene_id: str
    prompt: str
    images: list[ImageInput]
    detection: dict | None
    engine_name: str
    language: str
    output: OutputContract
    attempt: int = 1            # 1 = first call, 2 = repair call
    prompt_version: str = ""
    stage: str = "generate"     # generate | repair (for usage accounting)

    def cache_key(self, model_identity: str) -> str:
        """Hash of everything a model sees plus the model's identity and settings.

        The prompt version is part of it, so an edited template never replays an old reply.
        """
        h = hashlib.sha256()
        h.update(model_identity.encode())
        h.update(json.dumps([self.scene_id, self.prompt, self.prompt_version, self.engine_name,
                             self.language, self.attempt, self.detection,
                             [self.output.fps, self.output.n_frames, self.output.width,
                              self.output.height]], sort_keys=True).encode())
        for img in self.images:
            h.update(img.name.encode())
            h.update(hashlib.sha256(img.png).digest())
        return h.hexdigest()


@dataclass
class PrivilegedRequest(ModelRequest):
    """A request for a model that declares ``privileged = True``: adds the ground truth."""

    scene: Scene | None = field(default=None, repr=False)
    engine: Engine | None = field(default=None, repr=False)


@dataclass
class ModelResponse:
    """One reply. ``error`` marks a call that failed after the adapter's retries."""

    text: str
    usage: dict[str, int] = field(default_factory=dict)   # input_tokens, output_tokens, ...
    cost_usd: float | None = None
    latency_s: float = 0.0
    raw: dict[str, Any] = field(default_factory=dict)
    error: str | None = None        # provider failed (network, quota, server): model_error
    error_kind: str | None = None   # rate_limit, server, timeout, auth, ... (calls.CallErrorKind)
    finish_reason: str | None = None  # stop | length | refusal | content_filter | ...
    refusal: str | None = None      # the provider's refusal text, when the model refused
    transport_attempts: int = 1     # HTTP attempts the call took (retries included)
    prompt_version: str = ""
    model_id: str = ""              # what the provider says answered
    #: Pixel-space models hand over a video instead of a program: a file name inside the
    #: response's cache entry (set by the pipeline) or an absolute path before caching.
    video_path: str | None = None

    @property
    def truncated(self) -> bool:
        return self.finish_reason == "length"


def config_identity(name: str, version: str, cfg: Any) -> str:
    """``[name, version, every setting]`` as canonical JSON: the cache identity of a configured
    model or judge."""
    settings = {}
    if cfg is not None:
        try:
            from omegaconf import OmegaConf

            settings = OmegaConf.to_container(cfg, resolve=True)
        except ValueError:
            settings = dict(cfg)
    return json.dumps([name, version, settings], sort_keys=True, default=str)


class Model(ABC):
    """Base class for model plugins (the built-in ones are in ``plugins/models/``).

    Implement ``generate`` (blocking) or ``agenerate`` (async; API adapters). Neither raises for
    a provider's failure: the response carries ``error`` and ``error_kind``.
    """

    name: str = ""
    version: str = "0"
    #: Environment variable holding the API key (None: no key needed).
    needs_key: str | None = None
    #: True only for models allowed to see the ground truth (a reference that replays it).
    privileged: bool = False
    #: "program" (a reply with code) or "video" (a pixel-space baseline hands over a clip).
    output_kind: str = "program"
    #: True for a reference point that is no model (the still clip, a flow extrapolation):
    #: its clips are counted as the baseline's, never as a model's successes.
    baseline: bool = False

    def __init__(self, cfg: Any = None):
        self.cfg = cfg

    def generate(self, request: ModelRequest) -> ModelResponse:
        """One call to the model (blocking)."""
        return asyncio.run(self.agenerate(request))

    async def agenerate(self, request: ModelRequest) -> ModelResponse:
        """One call to the model (async); defaults to ``generate`` in a worker thread."""
        if type(self).generate is Model.generate:
            raise NotImplementedError(f"model {self.name!r} implements neither generate nor "
                                      "agenerate")
        return await asyncio.to_thread(self.generate, request)

    def check_ready(self) -> None:
        """Raise a `UserError` (one line) when the model cannot run here: a missing key, a
        missing weight directory. Called before any work starts."""

    def identity(self) -> str:
        """Cache identity: name, version and every setting that changes the reply."""
        return config_identity(self.name, self.version, self.cfg)

    def describe(self) -> dict:
        """What the run manifest records about the model."""
        return {"name": self.name, "version": self.version, "privileged": self.privileged,
                "output": self.output_kind, "baseline": self.baseline}

    async def aclose(self) -> None:
        """Release clients (called once, on the generation service's loop)."""


def build_model_request(model: Model, *, scene: Scene, engine: Engine, **fields: Any
                        ) -> ModelRequest:
    """The request ``model`` may receive: privileged fields only for a privileged model."""
    if model.privileged:
        return PrivilegedRequest(**fields, scene=scene, engine=engine)
    return ModelRequest(**fields)
