"""Check the config before a run and turn every mistake into one line that says what is valid.

Everything here runs before any work (no dataset built, no run directory made):

* group options (``engine=threejz``) and keys (``engine.timout_s=3``, ``+engine.foo=1``);
* types and choices: a choice-valued key is a `StrEnum` in its schema, so OmegaConf rejects a bad
  value when the config is composed (``tracking.backend=mlfow``);
* ranges: a dataclass field declares ``metadata={"min": X, "max": Y}`` (either optional,
  inclusive; on a list every item is checked, and ``"min_items"`` bounds its length). The walk
  reads the dataclass of every node with ``OmegaConf.get_type``, so plugin schemas get the same
  check as the core ones (``engine.timeout_s=-5``);
* names against the installed plugins: ``model.name``, ``engine.name``, ``judge.name``,
  ``metrics.names`` (``metrics.names=[psnrr]``);
* the tracking URI's scheme, and (`check_inputs`, CLI only) the files a config names;
* sweeps (``-m engine.timeout_s=10,-5``): every value of every sweep is composed and checked.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Iterator

from omegaconf import DictConfig, ListConfig, OmegaConf, open_dict

from visphy_core.infra.errors import ConfigError, UserError

__all__ = ["ConfigError", "UserError", "check_overrides", "check_inputs", "check_values",
           "compose", "compose_all", "group_options"]

CONFIG_MODULE = "visphy_conf"
GROUPS = ("dataset", "model", "engine", "metrics", "judge", "tracking", "experiment")
#: The schemes MLflow's tracking store understands (a plain path is a local file store too).
MLFLOW_SCHEMES = ("databricks", "databricks-uc", "file", "http", "https", "mssql", "mysql",
                  "postgresql", "sqlite", "uc")


def _hidden(option: str) -> bool:
    return option.startswith("schema_")


def group_options(group: str) -> list[str]:
    """Options of a config group (YAML files and plugin-stored configs), schemas excluded."""
    from hydra.core.global_hydra import GlobalHydra

    loader = GlobalHydra.instance().config_loader()
    return sorted(o for o in loader.get_group_options(group) if not _hidden(o))


# ------------------------------------------------------------------------------ overrides


def _parse(overrides: list[str]) -> list:
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException

    parsed = []
    parser = OverridesParser.create()
    for text in overrides:
        try:
            parsed.extend(parser.parse_overrides([text]))
        except HydraException as exc:
            reason = str(exc).splitlines()[0].strip()
            raise ConfigError(f"cannot parse the override '{text}': {reason} (the syntax: "
                              f"key=value, group=option, a,b sweeps; quote values with spaces)"
                              ) from None
    return parsed


def _sweep_values(ov) -> list[str]:
    try:
        return [str(v) for v in ov.sweep_string_iterator()]
    except Exception:  # noqa: BLE001 - interval() and friends: only an optimiser can expand them
        return []


def _variants(overrides: list[str]) -> Iterator[list[str]]:
    """The overrides with every sweep at its first value, then once per other value of each
    sweep (the others at their first value): every swept value is composed at least once."""
    parsed = _parse(overrides)
    firsts = []
    for text, ov in zip(overrides, parsed):
        values = _sweep_values(ov) if ov.is_sweep_override() else []
        firsts.append(f"{ov.get_key_element()}={values[0]}" if values else text)
    yield firsts
    for i, (ov, first) in enumerate(zip(parsed, firsts)):
        if not ov.is_sweep_override():
            continue
        for value in _sweep_values(ov)[1:]:
            variant = list(firsts)
            variant[i] = f"{ov.get_key_element()}={value}"
            yield variant


def _first_values(overrides: list[str]) -> list[str]:
    """Replace sweeps (``a,b`` / ``range()``) by their first value so one compose checks them."""
    return next(_variants(overrides))


def _check_groups(overrides: list[str]) -> None:
    groups = set(GROUPS) | {"hydra/launcher"}
    for ov in _parse(overrides):
        key = ov.key_or_group
        if key not in groups or ov.is_delete():
            continue
        valid = group_options(key)
        values = _sweep_values(ov) if ov.is_sweep_override() else [ov.value()]
        flat = []
        for value in values:  # a list value selects several options at once: judge=[a,b]
            if isinstance(value, str) and value.startswith("[") and value.endswith("]"):
                value = [v.strip() for v in value[1:-1].split(",") if v.strip()]
            flat.extend(value if isinstance(value, (list, tuple)) else [value])
        for value in flat:
            if value is not None and str(value) not in valid:
                raise ConfigError(f"{key}={value} is not an option of '{key}'; valid: "
                                  f"{', '.join(valid)}")


# ------------------------------------------------------------------------------ composition


def _keys_of(cfg: DictConfig, path: str) -> list[str]:
    node = OmegaConf.select(cfg, path) if path else cfg
    return sorted(node.keys()) if isinstance(node, DictConfig) else []


def _show(value: Any) -> str:
    if isinstance(value, bool) or value is None:
        return str(value).lower() if value is not None else "null"
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, (list, tuple, ListConfig)):
        return "[" + ", ".join(_show(v) for v in value) + "]"
    return str(value)


def _omegaconf_cause(exc: BaseException):
    from omegaconf.errors import OmegaConfBaseException

    seen = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if isinstance(exc, OmegaConfBaseException) and getattr(exc, "full_key", None):
            return exc
        exc = exc.__cause__ or exc.__context__
    return None


def _unknown_key(key: str, base: DictConfig) -> str:
    if "." not in key:
        return f"unknown key '{key}'; valid top-level keys: {', '.join(_keys_of(base, ''))}"
    parent = key.rsplit(".", 1)[0]
    valid = _keys_of(base, parent)
    if valid:
        return f"unknown key '{key}'; valid keys of '{parent}': {', '.join(valid)}"
    return f"unknown key '{key}': '{parent}' is not a config section"


def _one_line(exc: Exception, overrides: list[str], base: DictConfig) -> str:
    from omegaconf.errors import ConfigAttributeError, ConfigKeyError, ValidationError

    cause = _omegaconf_cause(exc)
    if cause is not None:
        key = str(cause.full_key)
        msg = (cause.msg or "").splitlines()[0].strip()
        if isinstance(cause, (ConfigAttributeError, ConfigKeyError)):
            return _unknown_key(key, base)
        if isinstance(cause, ValidationError):
            value = getattr(cause, "value", None)
            if "expected one of [" in msg:
                choices = msg.split("expected one of [", 1)[1].rstrip("]")
                return f"{key}={_show(value)} is not a valid choice; valid: {choices}"
            for kind in ("Float", "Integer", "Boolean", "String"):
                if f"could not be converted to {kind}" in msg:
                    return f"{key}={_show(value)} is not a valid {kind.lower()}"
            if "is not a valid bool" in msg:
                return f"{key}={_show(value)} is not a valid boolean; valid: true, false"
            if "is not a ListConfig" in msg:
                return f"{key}={_show(value)} must be a list, e.g. {key}=[1,10]"
            if "is not a DictConfig" in msg or "is not a subclass" in msg:
                return f"{key}: {msg}"
            return f"{key}={_show(value)}: {msg}"
    text = str(exc)
    for ov in overrides:
        key = ov.split("=", 1)[0].lstrip("+~")
        if "." in key and OmegaConf.select(base, key, default="__missing__") == "__missing__":
            return _unknown_key(key, base)
        if "." not in key and key not in base and key not in GROUPS and "/" not in key:
            return _unknown_key(key, base)
    first = " ".join(line.strip() for line in text.splitlines() if line.strip())
    return first[:400]


#: ``hydra.mode`` of the last config `compose_all` composed (None: the config leaves it to the
#: command line's ``-m``), read by the CLI so Hydra need not compose the config once more only
#: to learn it (`visphy_core.cli.main.run_hydra`).
LAST_HYDRA_MODE: list = []


def _compose_one(overrides: list[str]) -> DictConfig:
    from hydra import compose as hydra_compose

    try:
        cfg = hydra_compose(config_name="config", overrides=overrides, return_hydra_config=True)
        LAST_HYDRA_MODE[:] = [OmegaConf.select(cfg, "hydra.mode", default=None)]
        with open_dict(cfg):
            del cfg["hydra"]
        return cfg
    except Exception as exc:  # noqa: BLE001 - Hydra wraps OmegaConf's errors in its own
        groups_only = [o for o in overrides if o.split("=", 1)[0].lstrip("+~") in GROUPS]
        try:
            base = hydra_compose(config_name="config", overrides=groups_only)
        except Exception:  # noqa: BLE001
            base = hydra_compose(config_name="config")
        raise ConfigError(_one_line(exc, overrides, base)) from None


def compose_all(overrides: list[str]) -> list[DictConfig]:
    """Every config a run (or a sweep) would use, each checked by `check_values`; the first is
    the sweep's first point. Raises `ConfigError` with one line."""
    from hydra import initialize_config_module
    from hydra.core.global_hydra import GlobalHydra

    from visphy_core.api.registry import get_registry

    get_registry()
    GlobalHydra.instance().clear()
    configs = []
    with initialize_config_module(config_module=CONFIG_MODULE, version_base="1.3"):
        _check_groups(overrides)
        for variant in _variants(overrides):
            cfg = _compose_one(variant)
            check_values(cfg)
            configs.append(cfg)
    return configs


def compose(overrides: list[str]) -> DictConfig:
    """Compose the run config as the CLI would, raising `ConfigError` with one line."""
    return compose_all(overrides)[0]


def _split_hydra(overrides: list[str]) -> list[str]:
    return ([o for o in overrides if not o.startswith("hydra.") and not o.startswith("hydra/")]
            + [o for o in overrides if o.startswith("hydra/")])


def check_overrides(overrides: list[str], inputs: bool = False) -> list[DictConfig]:
    """Raise `ConfigError` unless the overrides (every point of a sweep) compose into valid
    configs; with ``inputs``, also check the files they name (`check_inputs`)."""
    from hydra.core.global_hydra import GlobalHydra

    try:
        configs = compose_all(_split_hydra(overrides))
    finally:
        GlobalHydra.instance().clear()
    for cfg in configs:  # what a run needs that composing alone does not ask
        check_required(cfg)
        if any(o.lstrip("+").startswith("prompt.frames=") for o in overrides):
            check_frames_with_forecast(cfg)
    if inputs:
        for cfg in configs:
            check_inputs(cfg)
    return configs


# ------------------------------------------------------------------------------ values


def _children(node: DictConfig) -> Iterator[tuple[str, Any]]:
    for key in node.keys():
        yield str(key), node._get_node(key)


def _walk(node: DictConfig, path: str = "") -> Iterator[tuple[str, DictConfig]]:
    yield path, node
    for key, child in _children(node):
        if isinstance(child, DictConfig) and not child._is_none() and not child._is_missing():
            yield from _walk(child, f"{path}.{key}" if path else key)


def _bounds(meta: dict) -> str:
    lo, hi = meta.get("min"), meta.get("max")
    if lo is not None and hi is not None:
        return f"≥ {_show(lo)} and ≤ {_show(hi)}"
    return f"≥ {_show(lo)}" if lo is not None else f"≤ {_show(hi)}"


def _out_of_range(value: Any, meta: dict) -> bool:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    if isinstance(value, float) and math.isnan(value):
        return True
    lo, hi = meta.get("min"), meta.get("max")
    return (lo is not None and value < lo) or (hi is not None and value > hi)


def _range_meta(schema: type, name: str) -> dict:
    """The range metadata of field ``name``: the most derived dataclass that declares one, so a
    plugin schema that redefines a core field (``timeout_s: float = 120.0``) keeps its range."""
    for cls in schema.__mro__:
        if not dataclasses.is_dataclass(cls):
            continue
        for f in dataclasses.fields(cls):
            if f.name == name and any(k in f.metadata for k in ("min", "max", "min_items")):
                return dict(f.metadata)
    return {}


def check_ranges(cfg: DictConfig) -> None:
    """Every field with ``metadata={"min", "max", "min_items"}`` in every node's dataclass (core
    and plugin schemas), and no key that the node's dataclass lacks (``+engine.foo=1``)."""
    for path, node in _walk(cfg):
        schema = OmegaConf.get_type(node)
        if schema is None or not dataclasses.is_dataclass(schema):
            continue
        fields = {f.name: f for f in dataclasses.fields(schema)}
        for key in node.keys():
            if str(key) not in fields:
                full = f"{path}.{key}" if path else str(key)
                where = f"valid keys of '{path}'" if path else "valid top-level keys"
                raise ConfigError(f"unknown key '{full}'; {where}: {', '.join(sorted(fields))}")
        for name in fields:
            meta = _range_meta(schema, name)
            if not meta:
                continue
            full = f"{path}.{name}" if path else name
            try:
                value = node[name]
            except Exception:  # noqa: BLE001 - MISSING or an unresolvable interpolation
                continue
            if value is None:
                continue
            if isinstance(value, ListConfig):
                items = list(value)
                if "min_items" in meta and len(items) < meta["min_items"]:
                    raise ConfigError(f"{full}={_show(items)} needs at least {meta['min_items']} "
                                      f"item{'s' if meta['min_items'] != 1 else ''}")
                if any(_out_of_range(v, meta) for v in items):
                    raise ConfigError(f"{full}={_show(items)} is out of range: each item must "
                                      f"be {_bounds(meta)}")
            elif ("min" in meta or "max" in meta) and _out_of_range(value, meta):
                raise ConfigError(f"{full}={_show(value)} is out of range: must be "
                                  f"{_bounds(meta)}")


def check_names(cfg: DictConfig) -> None:
    """``model.name``, ``engine.name``, every selected judge's ``name`` and ``metrics.names``
    name installed plugins (see ``python -m visphy_core plugins``)."""
    from visphy_core.api.registry import get_registry

    registry = get_registry()

    def installed(kind: str, extra: tuple[str, ...] = ()) -> list[str]:
        return sorted(set(getattr(registry, kind)) | set(extra))

    for key, kind in (("model.name", "models"), ("engine.name", "engines")):
        value = OmegaConf.select(cfg, key, default=None)
        valid = installed(kind)
        if value is not None and str(value) not in valid:
            raise ConfigError(f"{key}={value} is not an installed {kind[:-1]}; installed: "
                              f"{', '.join(valid) or 'none'}")
    judges = OmegaConf.select(cfg, "judge", default=None)
    if isinstance(judges, DictConfig):
        valid = installed("judges")
        for entry, node in judges.items():
            value = node.get("name") if isinstance(node, DictConfig) else None
            if value is not None and str(value) not in valid:
                raise ConfigError(f"judge.{entry}.name={value} is not an installed judge; "
                                  f"installed: {', '.join(valid) or 'none'}")
    names = OmegaConf.select(cfg, "metrics.names", default=None)
    if names is not None:
        valid = installed("metrics")
        unknown = [str(n) for n in names if str(n) not in valid]
        if unknown:
            what = ("is not an installed metric" if len(unknown) == 1
                    else "are not installed metrics")
            raise ConfigError(f"metrics.names={_show(list(names))}: {', '.join(unknown)} {what}; "
                              f"installed: {', '.join(valid) or 'none'}")
        if not names:
            raise ConfigError(f"metrics.names=[] names no metric; installed: {', '.join(valid)}")


def _mlflow_schemes() -> list[str]:
    from importlib.metadata import entry_points

    plugins = {ep.name for ep in entry_points(group="mlflow.tracking_store")}
    return sorted(set(MLFLOW_SCHEMES) | plugins)


def check_tracking(cfg: DictConfig) -> None:
    """With the MLflow backend, ``tracking.uri`` is a path or a URI of a scheme MLflow knows."""
    from urllib.parse import urlparse

    if str(OmegaConf.select(cfg, "tracking.backend", default="none")) != "mlflow":
        return
    try:
        uri = OmegaConf.select(cfg, "tracking.uri", default=None)
    except Exception:  # noqa: BLE001 - an interpolation that only resolves at run time
        return
    if not uri:
        return
    uri = str(uri)
    if "://" not in uri and ":" not in uri.split("/", 1)[0]:
        return  # a local path: MLflow's file store
    parsed = urlparse(uri)
    scheme = parsed.scheme.split("+", 1)[0].lower()
    valid = _mlflow_schemes()
    if scheme not in valid:
        raise ConfigError(f"tracking.uri={uri} has an unknown scheme {scheme or '(none)'!r}; "
                          f"valid: a local path or {', '.join(s + ':' for s in valid)}")
    if scheme == "sqlite" and (parsed.netloc or not parsed.path.strip("/")):
        raise ConfigError(f"tracking.uri={uri} is not a sqlite URI; use sqlite:///relative.db "
                          f"or sqlite:////absolute/path.db")
    if scheme in ("http", "https") and not parsed.netloc:
        raise ConfigError(f"tracking.uri={uri} names no host; e.g. http://localhost:5000")


def check_values(cfg: DictConfig) -> None:
    """Ranges, unknown keys, plugin names and the tracking URI of a composed config."""
    check_ranges(cfg)
    check_names(cfg)
    check_tracking(cfg)
    check_protocol(cfg)
    from visphy_core.infra.shard import parse_shard

    parse_shard(OmegaConf.select(cfg, "dataset.shard", default=None))  # "i/n", 0 <= i < n


PROTOCOLS = ("visphy", "paper")


def check_frames_with_forecast(cfg: DictConfig) -> None:
    """``prompt.frames`` given on the command line with ``prompt.forecast_only=true``: only
    the first frame would be shown, silently; say so instead."""
    frames = list(OmegaConf.select(cfg, "prompt.frames", default=None) or [])
    if OmegaConf.select(cfg, "prompt.forecast_only", default=False) and len(frames) > 1:
        raise ConfigError(f"prompt.forecast_only=true shows only the first of "
                          f"prompt.frames={_show(frames)} (frame {frames[0]}): drop "
                          "prompt.frames, or set prompt.forecast_only=false to show them all")


def check_required(cfg: DictConfig) -> None:
    """Every value a config leaves open (``???``: e.g. a model config's ``model.source``, left
    to the command line) is set; else one line naming the key and how to set it."""
    missing = sorted(k for k in OmegaConf.missing_keys(cfg) if not str(k).startswith("hydra."))
    if not missing:
        return
    first = missing[0]
    group = first.split(".")[0]
    option = OmegaConf.select(cfg, f"{group}.name", default=None) if group != first else None
    where = f" ({group}={option} leaves it open)" if option else ""
    raise ConfigError(f"{', '.join(missing)} must be set{where}: add {first}=<value> to the "
                      "command")


def check_protocol(cfg: DictConfig) -> None:
    """``metrics.protocol``: a non-empty list of scoring protocols."""
    value = OmegaConf.select(cfg, "metrics.protocol", default=None)
    if value is None:
        return
    items = [str(v) for v in value]
    if not items:
        raise ConfigError(f"metrics.protocol=[] names no protocol; valid: {', '.join(PROTOCOLS)}")
    for item in items:
        if item not in PROTOCOLS:
            raise ConfigError(f"metrics.protocol={_show(list(value))}: {item} is not a scoring "
                              f"protocol; valid: {', '.join(PROTOCOLS)}")


def check_inputs(cfg: DictConfig) -> None:
    """The files a config names exist (cheap checks only; the run loads them later): the
    dataset plugin of ``dataset.source`` checks its own node (`Dataset.check`)."""
    from visphy_core.api.registry import get_registry

    source = str(OmegaConf.select(cfg, "dataset.source", default="") or "")
    datasets = get_registry().datasets
    if source not in datasets:
        raise ConfigError(f"dataset.source={source} is not an installed dataset; valid: "
                          f"{', '.join(sorted(datasets)) or 'none installed'}")
    datasets[source][0]().check(cfg)
