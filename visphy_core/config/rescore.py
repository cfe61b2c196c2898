"""The config of a re-scored run: the finished run's own config with scoring overrides applied.

Re-scoring may change only what scoring reads: the metrics (``metrics=full``,
``metrics.names=[…]``, ``+metrics.max_pairs.lpips=8``), the judges (``judge=J``,
``judge=[J,K]``, ``+judge=J`` to add one to the run's, ``judge=none``,
``judge.<key>.*``), the reference descriptions (``reference.*``), tracking (``tracking=none``,
``tracking.*``), where data and cache live (``paths.data_dir``, ``paths.cache_dir``) and
``run.progress`` / ``run.cache``. Anything else (model, engine, dataset, prompt, the other
``run.*``, sandbox, an experiment) would change what the model was asked or what its programs
rendered: refused with one line saying why.

Composition: the run's ``config.yaml`` holds resolved values without the group options they came
from, so each scoring group is composed by Hydra (the option the user selects, else the run's
own: ``metrics=default`` as the typed skeleton, ``judge=<the run's judge keys>``,
``tracking=<its backend>``) and the run's values are merged over it; the key overrides are then
applied with Hydra's own override semantics and the result is checked like any run config
(`visphy_core.config.check`): types, ranges, unknown keys, installed metric and judge names.
"""

from __future__ import annotations

from typing import Any

from omegaconf import DictConfig, OmegaConf

from visphy_core.config.check import (
    check_names,
    check_overrides,
    check_protocol,
    check_ranges,
    check_tracking,
    group_options,
)
from visphy_core.infra.errors import ConfigError

#: Groups whose option re-scoring may select.
SCORING_GROUPS = ("metrics", "judge", "tracking")
#: Key prefixes re-scoring may override.
SCORING_KEYS = ("metrics.", "judge.", "reference.", "tracking.", "paths.data_dir",
                "paths.cache_dir", "run.progress", "run.cache")
#: Why anything else is refused, by the override's first key.
REFUSED = {
    "model": "it changes who wrote the programs",
    "engine": "it changes how the programs were rendered",
    "dataset": "it changes which scenes the run holds",
    "prompt": "it changes what the model was asked",
    "run": "it changes how the scenes were generated (only run.progress and run.cache apply "
           "to scoring)",
    "sandbox": "it changes how the programs ran",
    "experiment": "an experiment is a new study",
    "paths": "only paths.data_dir and paths.cache_dir apply to scoring",
}
ACCEPTED = ("metrics=…, metrics.*, judge=…, +judge=…, judge.<key>.*, reference.*, tracking=…, "
            "tracking.*, paths.data_dir, paths.cache_dir, run.progress, run.cache")


def _parse(overrides: list[str]) -> list:
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException

    parser = OverridesParser.create()
    parsed = []
    for text in overrides:
        try:
            (ov,) = parser.parse_overrides([text])
        except HydraException as exc:
            raise ConfigError(f"cannot parse the override '{text}': "
                              f"{str(exc).splitlines()[0].strip()}") from None
        if ov.is_sweep_override():
            raise ConfigError(f"{text}: re-scoring takes one value per key, not a sweep")
        parsed.append(ov)
    return parsed


def _refuse(ov) -> None:
    key = str(ov.key_or_group)
    if key in SCORING_GROUPS or any(key == k or key.startswith(k) for k in SCORING_KEYS):
        return
    root = key.split(".")[0].split("/")[0]
    why = REFUSED.get(root, "it is not something scoring reads")
    raise ConfigError(f"score: {ov.input_line} cannot be applied to a finished run: {why}; start "
                      f"a new run for that (re-scoring accepts {ACCEPTED})")


def _as_list(value: Any) -> list[str]:
    if value is None:
        return []
    if isinstance(value, (list, tuple)):
        return [str(v) for v in value]
    return [str(value)]


def _selections(parsed: list, run_cfg: DictConfig) -> tuple[dict[str, list[str]], list]:
    """(the group option(s) chosen per scoring group, the key overrides left)."""
    chosen: dict[str, list[str]] = {}
    keys = []
    for ov in parsed:
        group = str(ov.key_or_group)
        if group not in SCORING_GROUPS:
            keys.append(ov)
            continue
        if ov.is_delete():
            chosen[group] = []
            continue
        values = _as_list(ov.value())
        if group == "judge":
            values = [v for v in values if v != "none"]
        if group != "judge" and len(values) != 1:
            raise ConfigError(f"{ov.input_line}: select one {group} option")
        if ov.is_add() and group == "judge":  # +judge=X: X besides the run's judges
            base = chosen.get("judge", [str(k) for k in (run_cfg.get("judge") or {})])
            values = base + [v for v in values if v not in base]
        chosen[group] = values
    return chosen, keys


def _compose_skeleton(chosen: dict[str, list[str]], run_cfg: DictConfig) -> DictConfig:
    """A typed config (Hydra-composed, validated) with the scoring groups selected."""
    judges = chosen.get("judge")
    if judges is None:
        judges = [str(k) for k in (run_cfg.get("judge") or {})]
    tracking = (chosen.get("tracking") or [str(OmegaConf.select(run_cfg, "tracking.backend",
                                                                default="mlflow"))])[0]
    metrics = (chosen.get("metrics") or ["default"])[0]
    overrides = [f"metrics={metrics}", f"tracking={tracking}"]
    composed_judges = judges
    if "judge" not in chosen:  # the run's judges: the keys that are options of the group
        composed_judges = [k for k in judges if k in _judge_options()]
    overrides.append(f"judge=[{','.join(composed_judges)}]" if composed_judges else "judge=none")
    return check_overrides(overrides)[0]


def _judge_options() -> list[str]:
    from hydra import initialize_config_module
    from hydra.core.global_hydra import GlobalHydra

    from visphy_core.config.check import CONFIG_MODULE

    GlobalHydra.instance().clear()
    try:
        with initialize_config_module(config_module=CONFIG_MODULE, version_base="1.3"):
            return group_options("judge")
    finally:
        GlobalHydra.instance().clear()


def _merge(typed: Any, values: Any) -> Any:
    try:
        return OmegaConf.merge(typed, values)
    except Exception as exc:  # noqa: BLE001 - the run's value no longer fits the schema
        raise ConfigError(f"the run's config does not fit this visphy's schema: "
                          f"{' '.join(str(exc).split())[:300]}") from None


def _apply(keys: list, cfg: DictConfig) -> None:
    """Hydra's own override semantics (``key=v``, ``+key=v``, ``++key=v``, ``~key``)."""
    from hydra._internal.config_loader_impl import ConfigLoaderImpl

    for ov in keys:
        key = str(ov.key_or_group)
        if key.startswith("judge.") and key.split(".")[1] not in cfg.judge:
            name = key.split(".")[1]
            raise ConfigError(f"{ov.input_line}: the run has no judge {name!r}; select it with "
                              f"judge={name} (or +judge={name} besides the run's judges)")
        try:
            ConfigLoaderImpl._apply_overrides_to_config([ov], cfg)
        except Exception as exc:  # noqa: BLE001 - Hydra's and OmegaConf's errors alike
            parent = key.rsplit(".", 1)[0]
            node = OmegaConf.select(cfg, parent, default=None) if "." in key else None
            if "Could not override" in str(exc) and isinstance(node, DictConfig):
                raise ConfigError(f"unknown key '{key}'; valid keys of '{parent}': "
                                  f"{', '.join(sorted(str(k) for k in node))}") from None
            cause = exc.__cause__ or exc
            text = " ".join(str(cause).split()).split(" full_key:")[0]
            raise ConfigError(f"{ov.input_line}: {text[:300]}") from None


def rescore_config(run_cfg: DictConfig, overrides: list[str]) -> tuple[DictConfig, dict]:
    """(the re-scored run's config, what changed: ``{key: {"before": …, "after": …}}``).

    Raises `ConfigError` (one line) for an override re-scoring refuses or a bad value."""
    parsed = _parse(overrides)
    for ov in parsed:
        _refuse(ov)
    chosen, keys = _selections(parsed, run_cfg)
    skeleton = _compose_skeleton(chosen, run_cfg)
    cfg = OmegaConf.create(OmegaConf.to_container(run_cfg, resolve=False))
    for group in SCORING_GROUPS:
        if group in chosen:
            cfg[group] = skeleton[group]
        elif group == "judge":
            node = OmegaConf.create({})
            for key, value in (run_cfg.get("judge") or {}).items():
                node[key] = (_merge(skeleton.judge[key], value) if key in skeleton.judge
                             else value)
            cfg.judge = node
        else:
            cfg[group] = _merge(skeleton[group], run_cfg[group])
    for section in ("reference", "run", "paths"):
        cfg[section] = _merge(skeleton[section], run_cfg.get(section) or {})
    OmegaConf.set_struct(cfg, True)
    _apply(keys, cfg)
    check_ranges(cfg)
    check_names(OmegaConf.masked_copy(cfg, ["metrics", "judge"]))
    check_tracking(cfg)
    check_protocol(cfg)
    return cfg, changes(run_cfg, cfg)


def _flat(node: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(node, dict):
        out: dict[str, Any] = {}
        for key, value in node.items():
            out.update(_flat(value, f"{prefix}{key}."))
        return out
    return {prefix[:-1]: node}


def changes(before: DictConfig, after: DictConfig) -> dict[str, dict[str, Any]]:
    """Every leaf key whose value differs (added and removed keys included)."""
    a = _flat(OmegaConf.to_container(before, resolve=True, enum_to_str=True))
    b = _flat(OmegaConf.to_container(after, resolve=True, enum_to_str=True))
    return {key: {"before": a.get(key), "after": b.get(key)}
            for key in sorted(set(a) | set(b)) if a.get(key) != b.get(key)}
