"""API model adapters, one per API model config: adding an API model is adding one YAML file.

The rule: every ``conf/model/<file>.yaml`` whose ``defaults`` list holds ``schema_api_model``
(the typed `ApiModelConfig` registered below) is an API model, registered under its ``name:``
(``model=<file>`` selects it; the run looks the model up by ``model.name``). Its ``provider:``
must name a provider adapter (`Provider`: ``openai``, ``anthropic``, ``gemini``; absent means
``openai``, as in the schema). Today: ``claude`` (Anthropic), ``gemini25pro``, ``gemini3pro``
(Google GenAI), ``gpt41``, ``gpt5`` (OpenAI), ``openai_compat`` (any OpenAI-compatible server)
and ``qwen3vlplus`` (DashScope, OpenAI-compatible); the other model configs (oracle, replay,
baselines, video models) use other schemas and are registered by their own plugins.

One adapter class serves them all (`visphy_plugins.providers.preflight.CheckedApiModel`: the
provider-neutral `visphy_plugins.providers.base.ApiModel` with a pre-flight before any work, and
no key demanded by a local endpoint); the provider,
model id, key variable, generation settings and prices come from the YAML file. The files are
read from the installed package ``visphy_conf`` (``visphy_conf/model/*.yaml``), so a wheel
behaves like a checkout. A model config that is not valid YAML, or an API model config without a
``name`` or with an unknown ``provider``, fails registration with a `ConfigError` naming the file.
"""

from __future__ import annotations

from importlib.resources import files
from importlib.resources.abc import Traversable

import yaml

from visphy_core.api.errors import ConfigError
from visphy_core.api.hookspecs import hookimpl
from visphy_plugins.providers.preflight import CheckedApiModel
from visphy_plugins.providers.config import ApiModelConfig, Provider

CONFIG_PACKAGE = "visphy_conf"  # the model configs are its ``model/*.yaml`` resources
API_SCHEMA = "schema_api_model"  # the ``defaults`` entry that makes a model config an API model


def api_model_names() -> tuple[str, ...]:
    """The ``name`` of every API model config in ``visphy_conf/model/``, in file-name order
    (read afresh on each call: registration happens once per registry build)."""
    names: list[str] = []
    model_dir = files(CONFIG_PACKAGE).joinpath("model")
    for entry in sorted(model_dir.iterdir(), key=lambda e: e.name):
        if entry.name.endswith(".yaml") and entry.is_file():
            name = _api_model_name(entry)
            if name is not None and name not in names:  # a variant file may reuse a name
                names.append(name)
    return tuple(names)


def _api_model_name(entry: Traversable) -> str | None:
    """The registered name if ``entry`` is an API model config, else None; `ConfigError`
    naming the file if it is malformed."""
    where = f"model config {entry}"
    try:
        data = yaml.safe_load(entry.read_text(encoding="utf-8"))
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{where} is not valid YAML: {' '.join(str(exc).split())}") from None
    if data is None:
        return None
    if not isinstance(data, dict):
        raise ConfigError(f"{where} must be a mapping, not a {type(data).__name__}")
    defaults = data.get("defaults") or []
    if not isinstance(defaults, list):
        raise ConfigError(f"{where}: 'defaults' must be a list, not {defaults!r}")
    if API_SCHEMA not in defaults:
        return None
    name = data.get("name")
    if not isinstance(name, str) or not name.strip() or name == "???":
        raise ConfigError(f"{where}: an API model config ('defaults: [{API_SCHEMA}]') needs "
                          f"'name: <model name>', got {name!r}")
    provider = data.get("provider", Provider.openai.value)
    valid = [p.value for p in Provider]
    if not (isinstance(provider, str) and (provider in valid or provider.startswith("${"))):
        raise ConfigError(f"{where}: provider={provider!r} is not a provider adapter; "
                          f"valid: {', '.join(valid)}")
    return name


@hookimpl
def visphy_register_configs(config_store):
    config_store.store(group="model", name=API_SCHEMA, node=ApiModelConfig)


@hookimpl
def visphy_register_models(register):
    for name in api_model_names():
        register(name, CheckedApiModel)
