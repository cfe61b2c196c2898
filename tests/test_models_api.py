"""API models come from their YAML files: every ``conf/model/*.yaml`` whose ``defaults`` hold
``schema_api_model`` is registered as an API model (`visphy_plugins.models.api`), so adding
one is adding one file, read from the installed ``visphy_conf`` package."""

from __future__ import annotations

import shutil
import sys

import pytest

from conftest import REPO
from visphy_core.api.errors import ConfigError
from visphy_core.api.registry import build_registry, get_plugin_manager, get_registry
from visphy_core.config.check import compose
from visphy_plugins.models.api import api_model_names
from visphy_plugins.providers.preflight import CheckedApiModel
from visphy_plugins.providers.base import ApiModel

#: the API models the shipped configs declare, in registration (file-name) order
SHIPPED = ("claude", "gemini25pro", "gemini3pro", "gpt41", "gpt5", "openai_compat",
           "qwen3vlplus")


def test_the_shipped_api_model_configs_are_the_registered_api_models():
    assert api_model_names() == SHIPPED
    registry = get_registry()
    api = [name for name, (factory, plugin) in registry.models.items() if plugin == "models_api"]
    assert api == list(SHIPPED)
    assert all(registry.models[name][0] is CheckedApiModel for name in api)
    # the other model configs (other schemas) stay with their own plugins
    for name in ("oracle", "replay", "static", "flow_extrapolate", "veo", "sora", "svd", "cosmos"):
        assert registry.models[name][1] != "models_api"


@pytest.fixture
def conf_copy(tmp_path, monkeypatch):
    """A copy of the config package imported as ``visphy_conf`` in place of the installed one;
    returns its ``model/`` folder. The registry cache is rebuilt from it, and again after."""
    shutil.copytree(REPO / "conf", tmp_path / "visphy_conf",
                    ignore=shutil.ignore_patterns("__pycache__"))
    monkeypatch.syspath_prepend(str(tmp_path))
    for module in [m for m in sys.modules if m == "visphy_conf" or m.startswith("visphy_conf.")]:
        monkeypatch.delitem(sys.modules, module)
    get_registry.cache_clear()
    yield tmp_path / "visphy_conf" / "model"
    get_registry.cache_clear()


NEW_MODEL = """\
# A new API model: this file is all it takes.
defaults:
  - schema_api_model
name: my_new_model
provider: anthropic
model_id: claude-test-1
api_key_env: MY_NEW_MODEL_KEY
price: {input_usd_per_mtok: 1.0, output_usd_per_mtok: 2.0}
"""


def test_a_new_model_yaml_is_all_a_new_api_model_needs(conf_copy):
    (conf_copy / "my_new_model.yaml").write_text(NEW_MODEL)

    cfg = compose(["model=my_new_model"])  # the CLI's path: registry, schema, name check
    registry = get_registry()
    assert registry.models["my_new_model"] == (CheckedApiModel, "models_api")
    assert api_model_names() == tuple(sorted((*SHIPPED, "my_new_model")))
    model = registry.get("models", cfg.model.name)(cfg.model)
    assert isinstance(model, ApiModel)
    assert model.describe()["provider"] == "anthropic"
    assert model.describe()["model_id"] == "claude-test-1"
    assert model.needs_key == "MY_NEW_MODEL_KEY"


@pytest.mark.parametrize("text, message", [
    ("defaults:\n  - schema_api_model\nname: [unclosed\n", "is not valid YAML"),
    ("- just\n- a list\n", "must be a mapping"),
    ("defaults: schema_api_model\nname: x\n", "'defaults' must be a list"),
    ("defaults:\n  - schema_api_model\nprovider: openai\n", "needs 'name: <model name>'"),
    ("defaults:\n  - schema_api_model\nname: x\nprovider: openia\n", "is not a provider adapter"),
], ids=["syntax", "not-a-mapping", "defaults-not-a-list", "no-name", "unknown-provider"])
def test_a_malformed_model_yaml_fails_registration_naming_the_file(conf_copy, text, message):
    (conf_copy / "broken.yaml").write_text(text)
    with pytest.raises(ConfigError, match=message) as info:
        build_registry(get_plugin_manager())
    assert str(conf_copy / "broken.yaml") in str(info.value)
