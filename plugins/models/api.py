"""API model adapters: ``gpt5``, ``gpt41`` (OpenAI), ``claude`` (Anthropic), ``gemini3pro``,
``gemini25pro`` (Google GenAI), ``qwen3vlplus`` (DashScope, OpenAI-compatible) and
``openai_compat`` (any OpenAI-compatible server). One adapter class serves them all
(`visphy_plugins.providers.base.ApiModel`); the provider, model id, key variable, generation
settings and prices come from ``conf/model/<name>.yaml``.
"""

from __future__ import annotations

from visphy_core.api.hookspecs import hookimpl
from visphy_plugins.providers.base import ApiModel
from visphy_plugins.providers.config import ApiModelConfig

API_MODELS = ("gpt5", "gpt41", "claude", "gemini3pro", "gemini25pro", "qwen3vlplus",
              "openai_compat")


@hookimpl
def visphy_register_configs(config_store):
    config_store.store(group="model", name="schema_api_model", node=ApiModelConfig)


@hookimpl
def visphy_register_models(register):
    for name in API_MODELS:
        register(name, ApiModel)
