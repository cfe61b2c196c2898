"""Local image-to-video models over `diffusers`: ``svd`` (Stable Video Diffusion) and ``cosmos``
(NVIDIA Cosmos-Predict2.5, ``Cosmos2_5_PredictBasePipeline``, Image2World mode).

Weights come only from a local directory (``model.weights_dir``, else ``$VISPHY_WEIGHTS/<name>``)
holding a diffusers checkpoint (``model_index.json`` and the component folders); nothing is
downloaded (``local_files_only``). `check_ready` names exactly what is missing (the packages,
the directory, the checkpoint); no canned video is ever produced in their place.

Generation: the first key frame is letterboxed (white) into the model's working size, the
pipeline runs with a fixed seed, its frames are taken as spaced 1 / ``model.fps`` seconds from
the key frame, the key frame's box is cut back out and the clip is resampled to the contract by
time (`visphy_plugins.models.video_apis.finish_frames`).
"""

from __future__ import annotations

import importlib.util
import json
import os
import time
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any, Optional

import numpy as np

from visphy_core.api.config_schema import ModelConfig
from visphy_core.api.errors import UserError
from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.model import Model, ModelRequest, ModelResponse
from visphy_plugins.models.baselines import decode_png, key_frame_index
from visphy_plugins.models.video_apis import PROMPT, PROMPT_VERSION, finish_frames, letterbox


class CosmosPipeline(StrEnum):
    Cosmos2_5_PredictBasePipeline = "Cosmos2_5_PredictBasePipeline"   # Cosmos-Predict2.5
    Cosmos2VideoToWorldPipeline = "Cosmos2VideoToWorldPipeline"       # Cosmos-Predict2


class DType(StrEnum):
    float16 = "float16"
    bfloat16 = "bfloat16"
    float32 = "float32"


@dataclass
class LocalVideoConfig(ModelConfig):
    weights_dir: Optional[str] = None       # null: $VISPHY_WEIGHTS/<name>
    device: str = "cuda"
    dtype: DType = DType.float16
    seed: int = field(default=0, metadata={"min": 0, "max": 2**32 - 1})
    width: int = field(default=1024, metadata={"min": 64, "max": 4096})   # working size
    height: int = field(default=576, metadata={"min": 64, "max": 4096})
    num_frames: int = field(default=25, metadata={"min": 2, "max": 1024})
    fps: float = field(default=7.0, metadata={"min": 1, "max": 240})       # frame spacing
    num_inference_steps: int = field(default=25, metadata={"min": 1, "max": 1000})


@dataclass
class SVDConfig(LocalVideoConfig):
    motion_bucket_id: int = field(default=127, metadata={"min": 0, "max": 1023})
    noise_aug_strength: float = field(default=0.02, metadata={"min": 0, "max": 1})
    decode_chunk_size: int = field(default=8, metadata={"min": 1, "max": 1024})
    min_guidance_scale: float = field(default=1.0, metadata={"min": 0})
    max_guidance_scale: float = field(default=3.0, metadata={"min": 0})


@dataclass
class CosmosConfig(LocalVideoConfig):
    pipeline: CosmosPipeline = CosmosPipeline.Cosmos2_5_PredictBasePipeline
    dtype: DType = DType.bfloat16
    width: int = field(default=1280, metadata={"min": 64, "max": 4096})
    height: int = field(default=704, metadata={"min": 64, "max": 4096})
    num_frames: int = field(default=93, metadata={"min": 2, "max": 1024})
    fps: float = field(default=16.0, metadata={"min": 1, "max": 240})
    num_inference_steps: int = field(default=36, metadata={"min": 1, "max": 1000})
    guidance_scale: float = field(default=7.0, metadata={"min": 0})
    negative_prompt: Optional[str] = ("camera motion, zoom, cuts, shaky footage, motion blur, "
                                      "new objects, text, people")


class LocalVideoModel(Model):
    output_kind = "video"
    version = "1"
    pipeline_class = ""
    packages: tuple[tuple[str, str], ...] = (("diffusers", "diffusers"), ("torch", "torch"))
    weights_hint = ""

    def __init__(self, cfg: Any = None):
        super().__init__(cfg)
        if cfg is not None and cfg.get("name"):
            self.name = str(cfg.name)
        self._pipe: Any = None

    # ------------------------------------------------------------------ readiness
    def weights_dir(self) -> Path | None:
        explicit = self.cfg.get("weights_dir") if self.cfg is not None else None
        if explicit:
            return Path(str(explicit)).expanduser()
        root = os.environ.get("VISPHY_WEIGHTS")
        return Path(root).expanduser() / self.name if root else None

    def missing(self) -> list[str]:
        """Every reason the model cannot run here (empty: ready)."""
        reasons = []
        absent = [pip for module, pip in self.packages if importlib.util.find_spec(module) is None]
        if absent:
            names = (absent[0] if len(absent) == 1
                     else f"{', '.join(absent[:-1])} and {absent[-1]}")
            reasons.append(f"{names} {'is' if len(absent) == 1 else 'are'} not installed "
                           f"(pip install {' '.join(absent)})")
        wanted = (f"a diffusers {self.pipeline_class} checkpoint (model_index.json and its "
                  f"component folders, e.g. {self.weights_hint})")
        where = self.weights_dir()
        if where is None:
            reasons.append(f"no weights directory: set model.weights_dir=DIR or $VISPHY_WEIGHTS "
                           f"(then $VISPHY_WEIGHTS/{self.name} is used) to {wanted}")
        elif not where.is_dir():
            reasons.append(f"weights directory {where} does not exist; it must hold {wanted}")
        elif not (where / "model_index.json").is_file():
            reasons.append(f"{where} has no model_index.json; it must hold {wanted}")
        else:
            try:
                declared = json.loads((where / "model_index.json").read_text()).get("_class_name")
            except (ValueError, OSError, AttributeError) as exc:
                reasons.append(f"{where / 'model_index.json'} is unreadable ({exc})")
            else:
                if declared != self.pipeline_class:
                    other = (f"; for it set model.pipeline={declared}"
                             if declared in self.alternatives() else "")
                    reasons.append(f"{where} holds a {declared} checkpoint, not a "
                                   f"{self.pipeline_class} one ({self.weights_hint}){other}")
        if not absent and str(self.cfg.get("device", "cuda")).startswith("cuda"):
            import torch

            if not torch.cuda.is_available():
                reasons.append(f"model.device={self.cfg.device} but torch sees no CUDA GPU "
                               "(set model.device=cpu to run, very slowly, on the CPU)")
        return reasons

    def alternatives(self) -> tuple[str, ...]:
        """Other pipeline classes ``model.pipeline`` may name."""
        return ()

    def check_ready(self) -> None:
        reasons = self.missing()
        if reasons:
            raise UserError(f"model={self.name} cannot run here: {'; '.join(reasons)}")

    def identity(self) -> str:
        from omegaconf import OmegaConf

        settings = OmegaConf.to_container(self.cfg, resolve=True) if OmegaConf.is_config(
            self.cfg) else dict(self.cfg or {})
        for transport in ("weights_dir", "device"):
            settings.pop(transport, None)
        return json.dumps([self.name, self.version, self.pipeline_class, PROMPT_VERSION,
                           settings], sort_keys=True, default=str)

    def describe(self) -> dict:
        return {**super().describe(), "pipeline": self.pipeline_class,
                "weights_dir": str(self.weights_dir())}

    # ------------------------------------------------------------------ generation
    def pipeline(self) -> Any:
        if self._pipe is None:
            import diffusers
            import torch

            cls = getattr(diffusers, self.pipeline_class)
            pipe = cls.from_pretrained(str(self.weights_dir()), local_files_only=True,
                                       torch_dtype=getattr(torch, str(self.cfg.dtype)))
            self._pipe = pipe.to(str(self.cfg.device))
        return self._pipe

    def run_pipeline(self, image: Any, generator: Any) -> np.ndarray:
        raise NotImplementedError

    def generate(self, request: ModelRequest) -> ModelResponse:
        start = time.perf_counter()
        reasons = self.missing()
        if reasons:   # never a stand-in clip
            return ModelResponse(text="", error=f"{self.name}: {'; '.join(reasons)}",
                                 error_kind="bad_request", latency_s=time.perf_counter() - start)
        if not request.images:
            return ModelResponse(text="", error=f"{self.name}: no key frame",
                                 error_kind="bad_request")
        import torch
        from PIL import Image

        cfg, first = self.cfg, request.images[0]
        try:
            first_index = key_frame_index(first)
        except ValueError:
            first_index = 1
        padded, framing = letterbox(decode_png(first.png), int(cfg.width), int(cfg.height))
        try:
            generator = torch.Generator(device=str(cfg.device)).manual_seed(int(cfg.seed))
            frames = self.run_pipeline(Image.fromarray(padded), generator)
        except Exception as exc:  # noqa: BLE001 - e.g. CUDA out of memory: this call failed
            return ModelResponse(text="", error=f"{self.name}: {type(exc).__name__}: {exc}",
                                 error_kind="server", latency_s=time.perf_counter() - start)
        frames = np.asarray(frames)
        if frames.dtype != np.uint8:
            frames = (np.clip(frames, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
        times = np.arange(len(frames)) / float(cfg.fps)
        path = finish_frames(frames, times, framing, request.output, first_index,
                             prefix=f"visphy-{self.name}-")
        c = request.output
        return ModelResponse(
            text=f"{self.name}: {self.pipeline_class} made {len(frames)} frames "
                 f"{cfg.width}x{cfg.height} (seed {cfg.seed}, taken at {float(cfg.fps):g} fps) "
                 f"from {first.name}; resampled by time to {c.n_frames} frames "
                 f"{c.width}x{c.height} @ {c.fps:g} fps",
            cost_usd=0.0, latency_s=time.perf_counter() - start, video_path=path,
            prompt_version=PROMPT_VERSION, model_id=self.pipeline_class, finish_reason="stop",
            raw={"frames": int(len(frames)), "seed": int(cfg.seed), "framing": framing.__dict__})


class SVDModel(LocalVideoModel):
    """``svd``: Stable Video Diffusion (image-to-video, no text prompt)."""

    name = "svd"
    pipeline_class = "StableVideoDiffusionPipeline"
    weights_hint = "stabilityai/stable-video-diffusion-img2vid-xt"

    def run_pipeline(self, image: Any, generator: Any) -> np.ndarray:
        cfg = self.cfg
        out = self.pipeline()(
            image, height=int(cfg.height), width=int(cfg.width), num_frames=int(cfg.num_frames),
            num_inference_steps=int(cfg.num_inference_steps), fps=round(float(cfg.fps)),
            motion_bucket_id=int(cfg.motion_bucket_id),
            noise_aug_strength=float(cfg.noise_aug_strength),
            decode_chunk_size=int(cfg.decode_chunk_size),
            min_guidance_scale=float(cfg.min_guidance_scale),
            max_guidance_scale=float(cfg.max_guidance_scale),
            generator=generator, output_type="np")
        return np.asarray(out.frames[0])


class CosmosModel(LocalVideoModel):
    """``cosmos``: Cosmos-Predict2.5 Image2World (or Predict2 Video2World with
    ``model.pipeline=Cosmos2VideoToWorldPipeline``) with the video APIs' physics prompt."""

    name = "cosmos"
    HINTS = {"Cosmos2_5_PredictBasePipeline":
             "nvidia/Cosmos-Predict2.5-2B at revision diffusers/base/post-trained",
             "Cosmos2VideoToWorldPipeline": "nvidia/Cosmos-Predict2-2B-Video2World"}

    @property
    def pipeline_class(self) -> str:  # type: ignore[override]
        return str(self.cfg.get("pipeline") or CosmosPipeline.Cosmos2_5_PredictBasePipeline)

    @property
    def weights_hint(self) -> str:  # type: ignore[override]
        return self.HINTS.get(self.pipeline_class, "")

    def alternatives(self) -> tuple[str, ...]:
        return tuple(p.value for p in CosmosPipeline)
    #: the pipeline builds its safety checker from cosmos_guardrail
    packages = LocalVideoModel.packages + (("cosmos_guardrail", "cosmos_guardrail"),)

    def run_pipeline(self, image: Any, generator: Any) -> np.ndarray:
        cfg = self.cfg
        out = self.pipeline()(
            image=image, video=None, prompt=PROMPT,
            negative_prompt=cfg.get("negative_prompt") or None,
            height=int(cfg.height), width=int(cfg.width), num_frames=int(cfg.num_frames),
            num_inference_steps=int(cfg.num_inference_steps),
            guidance_scale=float(cfg.guidance_scale), generator=generator, output_type="np",
            **({"fps": round(float(cfg.fps))}
               if self.pipeline_class == "Cosmos2VideoToWorldPipeline" else {}))
        return np.asarray(out.frames[0])


@hookimpl
def visphy_register_configs(config_store):
    config_store.store(group="model", name="schema_svd", node=SVDConfig)
    config_store.store(group="model", name="schema_cosmos", node=CosmosConfig)


@hookimpl
def visphy_register_models(register):
    register("svd", SVDModel)
    register("cosmos", CosmosModel)
