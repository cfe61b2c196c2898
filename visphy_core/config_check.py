"""Compose the config before a run and turn Hydra's multi-line errors into one line that lists
the valid choices: ``engine=threejz`` or ``engine.timout_s=3`` fail before anything starts."""

from __future__ import annotations

from omegaconf import DictConfig, OmegaConf

CONFIG_MODULE = "visphy_conf"


class ConfigError(ValueError):
    """A config option or key that does not exist."""


def _hidden(option: str) -> bool:
    return option.startswith("schema_")


def group_options(group: str) -> list[str]:
    """Options of a config group (YAML files and plugin-stored configs), schemas excluded."""
    from hydra.core.global_hydra import GlobalHydra

    loader = GlobalHydra.instance().config_loader()
    return sorted(o for o in loader.get_group_options(group) if not _hidden(o))


def _first_values(overrides: list[str]) -> list[str]:
    """Replace sweeps (``a,b`` / ``range()``) by their first value so one compose checks them."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    parsed = OverridesParser.create().parse_overrides(overrides)
    out = []
    for text, ov in zip(overrides, parsed):
        if ov.is_sweep_override():
            first = next(iter(ov.sweep_string_iterator()))
            out.append(f"{ov.get_key_element()}={first}")
        else:
            out.append(text)
    return out


def _check_groups(overrides: list[str]) -> None:
    from hydra.core.override_parser.overrides_parser import OverridesParser

    parsed = OverridesParser.create().parse_overrides(overrides)
    groups = {"dataset", "model", "engine", "metrics", "judge", "tracking", "experiment",
              "hydra/launcher"}
    for ov in parsed:
        key = ov.key_or_group
        if key not in groups or ov.is_delete():
            continue
        valid = group_options(key)
        values = list(ov.sweep_string_iterator()) if ov.is_sweep_override() else [ov.value()]
        for value in values:
            if value is not None and str(value) not in valid:
                raise ConfigError(f"{key}={value} is not an option of '{key}'; valid: "
                                  f"{', '.join(valid)}")


def _keys_of(cfg: DictConfig, path: str) -> list[str]:
    node = OmegaConf.select(cfg, path) if path else cfg
    return sorted(node.keys()) if isinstance(node, DictConfig) else []


def compose(overrides: list[str]) -> DictConfig:
    """Compose the run config as the CLI would, raising `ConfigError` with one line."""
    from hydra import compose as hydra_compose
    from hydra import initialize_config_module
    from hydra.core.global_hydra import GlobalHydra
    from hydra.errors import HydraException

    from visphy_core.plugins import get_registry

    get_registry()
    GlobalHydra.instance().clear()
    with initialize_config_module(config_module=CONFIG_MODULE, version_base="1.3"):
        _check_groups(overrides)
        try:
            return hydra_compose(config_name="config", overrides=_first_values(overrides),
                                 return_hydra_config=False)
        except (HydraException, Exception) as exc:  # noqa: B014 - Hydra wraps OmegaConf errors
            base = hydra_compose(config_name="config")
            raise ConfigError(_one_line(exc, overrides, base)) from None


def _one_line(exc: Exception, overrides: list[str], base: DictConfig) -> str:
    text = str(exc)
    for ov in overrides:
        key = ov.split("=", 1)[0].lstrip("+~")
        if "." in key and OmegaConf.select(base, key, default="__missing__") == "__missing__":
            parent = key.rsplit(".", 1)[0]
            valid = _keys_of(base, parent)
            if valid:
                return f"unknown key '{key}'; valid keys of '{parent}': {', '.join(valid)}"
            return f"unknown key '{key}': '{parent}' is not a config section"
        if "." not in key and key not in base and key not in {
                "dataset", "model", "engine", "metrics", "judge", "tracking", "experiment"}:
            return f"unknown key '{key}'; valid top-level keys: {', '.join(_keys_of(base, ''))}"
    first = " ".join(line.strip() for line in text.splitlines() if line.strip())
    return first[:400]


def check_overrides(overrides: list[str]) -> None:
    """Raise `ConfigError` unless the overrides compose into a valid config."""
    from hydra.core.global_hydra import GlobalHydra

    try:
        compose([o for o in overrides if not o.startswith("hydra.") and
                 not o.startswith("hydra/")] + [o for o in overrides if o.startswith("hydra/")])
    finally:
        GlobalHydra.instance().clear()
