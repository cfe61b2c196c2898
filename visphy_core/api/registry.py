"""The plugin manager: every plugin, built-in or third-party, is a ``visphy`` entry point.

Environment switches:
  VISPHY_LOAD_PLUGINS     comma-separated allow-list (entry-point or distribution names); "" = none
  VISPHY_DISABLE_PLUGINS  comma-separated deny-list, applied after the allow-list
  VISPHY_TRACE_PLUGINS    set to 1 to print every hook call and its result to stderr
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass, field
from functools import lru_cache
from importlib.metadata import EntryPoint, entry_points
from typing import Any, Callable

import pluggy

from visphy_core.api import hookspecs

ENTRY_POINT_GROUP = "visphy"
KINDS = ("configs", "models", "engines", "metrics", "judges", "datasets", "physics")


class PluginError(RuntimeError):
    """A plugin could not be loaded or registered something invalid."""


@dataclass
class PluginInfo:
    """What one plugin is and what it registered (for `visphy plugins`)."""

    name: str
    distribution: str
    version: str
    hooks: list[str] = field(default_factory=list)
    registers: dict[str, list[str]] = field(default_factory=dict)


@dataclass
class Registry:
    """Name → (factory or object, plugin name) tables built from the registration hooks."""

    models: dict[str, tuple[Callable[..., Any], str]] = field(default_factory=dict)
    engines: dict[str, tuple[Callable[..., Any], str]] = field(default_factory=dict)
    metrics: dict[str, tuple[Any, str]] = field(default_factory=dict)
    judges: dict[str, tuple[Callable[..., Any], str]] = field(default_factory=dict)
    configs: dict[str, tuple[Any, str]] = field(default_factory=dict)
    datasets: dict[str, tuple[Callable[..., Any], str]] = field(default_factory=dict)
    physics: dict[str, tuple[Callable[..., Any], str]] = field(default_factory=dict)

    def get(self, kind: str, name: str) -> Any:
        table = getattr(self, kind)
        if name not in table:
            valid = ", ".join(sorted(table)) or "none installed"
            raise KeyError(f"unknown {_singular(kind)} {name!r}; installed: {valid}")
        return table[name][0]


def _singular(kind: str) -> str:
    return {"physics": "physics engine", "datasets": "dataset"}.get(kind, kind[:-1])


def _env_list(var: str) -> set[str] | None:
    raw = os.environ.get(var)
    if raw is None:
        return None
    return {item.strip() for item in raw.split(",") if item.strip()}


def _selected(ep: EntryPoint) -> bool:
    names = {ep.name}
    if ep.dist is not None:
        names.add(ep.dist.name)
    allow = _env_list("VISPHY_LOAD_PLUGINS")
    deny = _env_list("VISPHY_DISABLE_PLUGINS") or set()
    if allow is not None and not names & allow:
        return False
    return not names & deny


def _trace(pm: pluggy.PluginManager) -> None:
    def before(hook_name: str, hook_impls: list, kwargs: dict) -> None:
        print(f"[visphy trace] {hook_name}({', '.join(kwargs)}) -> "
              f"{[impl.plugin_name for impl in hook_impls]}", file=sys.stderr)

    def after(outcome: Any, hook_name: str, hook_impls: list, kwargs: dict) -> None:
        print(f"[visphy trace] {hook_name} returned {outcome.get_result()!r}", file=sys.stderr)

    pm.add_hookcall_monitoring(before, after)


def build_plugin_manager() -> pluggy.PluginManager:
    """A fresh manager with every selected ``visphy`` entry point registered under its name."""
    pm = pluggy.PluginManager("visphy")
    pm.add_hookspecs(hookspecs)
    for ep in sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda e: e.name):
        if not _selected(ep) or pm.get_plugin(ep.name) is not None:
            continue
        try:
            plugin = ep.load()
        except Exception as exc:  # a broken third-party plugin must say which one it is
            raise PluginError(f"plugin {ep.name!r} ({ep.value}) failed to load: {exc}") from exc
        pm.register(plugin, name=ep.name)
        dist = ep.dist
        _DISTS[ep.name] = (dist.name, dist.version) if dist is not None else ("?", "?")
    if os.environ.get("VISPHY_TRACE_PLUGINS"):
        _trace(pm)
    return pm


_DISTS: dict[str, tuple[str, str]] = {}


@lru_cache(maxsize=1)
def get_plugin_manager() -> pluggy.PluginManager:
    """The process-wide plugin manager (tests may register inline plugins on it)."""
    return build_plugin_manager()


class _RecordingConfigStore:
    """Forwards ``store`` to Hydra's ConfigStore and remembers who stored what."""

    def __init__(self, plugin_name: str, sink: dict[str, tuple[Any, str]]):
        from hydra.core.config_store import ConfigStore

        self._cs = ConfigStore.instance()
        self._plugin = plugin_name
        self._sink = sink

    def store(self, name: str, node: Any, group: str | None = None, **kwargs: Any) -> None:
        self._cs.store(name=name, node=node, group=group, **kwargs)
        self._sink[f"{group}/{name}" if group else name] = (node, self._plugin)


def build_registry(pm: pluggy.PluginManager | None = None) -> Registry:
    """Call each plugin's registration hooks one plugin at a time, so every entry is attributed."""
    pm = pm or get_plugin_manager()
    registry = Registry()
    for kind in KINDS:
        caller = getattr(pm.hook, f"visphy_register_{kind}")
        table = getattr(registry, kind)
        for impl in caller.get_hookimpls():
            plugin_name = impl.plugin_name
            if kind == "configs":
                impl.function(config_store=_RecordingConfigStore(plugin_name, table))
                continue

            def register(name: Any, factory: Any = None, _kind=kind, _table=table,
                         _plugin=plugin_name) -> None:
                if _kind == "metrics":  # metrics register objects that carry their own name
                    obj, key = name, getattr(name, "name", None)
                    if not key:
                        raise PluginError(f"plugin {_plugin!r} registered a metric without a name")
                else:
                    obj, key = factory, name
                    if not callable(obj):
                        raise PluginError(
                            f"plugin {_plugin!r}: {_singular(_kind)} {key!r} needs a factory")
                if key in _table and _table[key][1] != _plugin:
                    raise PluginError(f"{_singular(_kind)} {key!r} registered twice: by "
                                      f"{_table[key][1]!r} and by {_plugin!r}")
                _table[key] = (obj, _plugin)

            impl.function(register=register)
    return registry


@lru_cache(maxsize=1)
def get_registry() -> Registry:
    """The registry of the process-wide plugin manager."""
    return build_registry(get_plugin_manager())


def describe_plugins(pm: pluggy.PluginManager | None = None) -> list[PluginInfo]:
    """Every loaded plugin with its distribution, implemented hooks and registered names."""
    pm = pm or get_plugin_manager()
    registry = build_registry(pm)
    infos: dict[str, PluginInfo] = {}
    for name, plugin in pm.list_name_plugin():
        if plugin is None:
            continue
        dist, version = _DISTS.get(name, ("(inline)", "-"))
        hooks = sorted(c.name for c in pm.get_hookcallers(plugin) or [])
        infos[name] = PluginInfo(name=name, distribution=dist, version=version, hooks=hooks)
    for kind in KINDS:
        for key, (_obj, plugin_name) in getattr(registry, kind).items():
            if plugin_name in infos:
                infos[plugin_name].registers.setdefault(kind, []).append(key)
    return sorted(infos.values(), key=lambda i: i.name)
