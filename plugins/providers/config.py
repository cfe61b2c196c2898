"""Typed config of API models and API judges (registered as ``schema_api_model`` and
``schema_api_judge``), so a misspelt key or a bad value fails before any work."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum
from typing import Optional

from visphy_core.api.config_schema import ModelConfig


class Provider(StrEnum):
    openai = "openai"         # OpenAI Chat Completions (also DashScope, vLLM, Ollama, llama.cpp)
    anthropic = "anthropic"   # Anthropic Messages
    gemini = "gemini"         # Google GenAI (Gemini API)


class MaxTokensParam(StrEnum):
    max_completion_tokens = "max_completion_tokens"   # OpenAI's current name
    max_tokens = "max_tokens"                         # older servers and most compatibles


@dataclass
class RetriesConfig:
    max_attempts: int = field(default=6, metadata={"min": 1, "max": 50})
    base_delay_s: float = field(default=1.0, metadata={"min": 0, "max": 600})
    max_delay_s: float = field(default=60.0, metadata={"min": 0, "max": 3600})
    max_retry_after_s: float = field(default=600.0, metadata={"min": 0, "max": 86400})


@dataclass
class ConcurrencyConfig:
    initial: int = field(default=4, metadata={"min": 1, "max": 1024})
    maximum: int = field(default=16, metadata={"min": 1, "max": 1024})


@dataclass
class PriceConfig:
    """USD per million tokens; leave null when unknown (cost is then not tracked)."""

    input_usd_per_mtok: Optional[float] = field(default=None, metadata={"min": 0})
    output_usd_per_mtok: Optional[float] = field(default=None, metadata={"min": 0})
    cached_input_usd_per_mtok: Optional[float] = field(default=None, metadata={"min": 0})


@dataclass
class ApiSettings:
    """What every API caller (model or judge) configures."""

    provider: Provider = Provider.openai
    model_id: str = ""
    api_key_env: Optional[str] = "OPENAI_API_KEY"  # null: no key (a local server)
    base_url: Optional[str] = None          # null: the SDK's default (or its *_BASE_URL env var)
    max_output_tokens: int = field(default=16384, metadata={"min": 1})
    max_tokens_param: MaxTokensParam = MaxTokensParam.max_completion_tokens
    temperature: Optional[float] = field(default=None, metadata={"min": 0, "max": 2})
    reasoning_effort: Optional[str] = None  # OpenAI reasoning models: minimal|low|medium|high
    thinking_budget: Optional[int] = field(default=None, metadata={"min": 0})  # Gemini/Claude
    seed: Optional[int] = None
    image_detail: str = "high"               # OpenAI image detail
    timeout_s: float = field(default=600.0, metadata={"min": 1, "max": 7200})  # per attempt
    retries: RetriesConfig = field(default_factory=RetriesConfig)
    concurrency: ConcurrencyConfig = field(default_factory=ConcurrencyConfig)
    price: PriceConfig = field(default_factory=PriceConfig)


@dataclass
class ApiModelConfig(ModelConfig, ApiSettings):
    pass
