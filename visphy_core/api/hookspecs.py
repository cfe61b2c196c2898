"""Every visphy hook, in the order the framework calls them. No logic lives here.

Registration hooks receive a ``register`` callback so that one plugin can add several things; the
built-in plugins use exactly this path (they are entry points in the ``visphy`` group like any
third-party package). Lifecycle hooks are for observers: tracking, progress, custom reporting.
"""

from __future__ import annotations

from typing import Any, Callable

import pluggy

hookspec = pluggy.HookspecMarker("visphy")
hookimpl = pluggy.HookimplMarker("visphy")


# ---------------------------------------------------------------- registration (at start-up)


@hookspec
def visphy_register_configs(config_store: Any) -> None:
    """Store structured configs (Hydra ``ConfigStore``) for the plugin's config-group entries.

    :param config_store: ``hydra.core.config_store.ConfigStore.instance()``; call
        ``config_store.store(group=..., name=..., node=...)`` so ``model=<name>`` composes.
    """


@hookspec
def visphy_register_models(register: Callable[..., None]) -> None:
    """Register model adapters: ``register(name, factory)``.

    :param register: callback taking a unique model name and a factory ``factory(cfg) -> Model``.
    """


@hookspec
def visphy_register_engines(register: Callable[..., None]) -> None:
    """Register execution engines: ``register(name, factory)``.

    :param register: callback taking a unique engine name and a factory ``factory(cfg) -> Engine``.
    """


@hookspec
def visphy_register_metrics(register: Callable[..., None]) -> None:
    """Register metrics: ``register(metric)`` with a ``visphy_core.api.metrics.Metric`` instance.

    :param register: callback taking one metric object (name, direction, range, needs, compute).
    """


@hookspec
def visphy_register_judges(register: Callable[..., None]) -> None:
    """Register video judges: ``register(name, factory)``.

    :param register: callback taking a unique judge name and a factory ``factory(cfg) -> Judge``.
    """


@hookspec
def visphy_register_datasets(register: Callable[..., None]) -> None:
    """Register dataset sources: ``register(name, factory)``; ``dataset.source=<name>`` selects
    one.

    :param register: callback taking a unique source name and a factory ``factory() ->
        visphy_core.api.dataset.Dataset``.
    """


@hookspec
def visphy_register_physics(register: Callable[..., None]) -> None:
    """Register ground-truth simulators: ``register(world_engine, factory)``.

    :param register: callback taking the ``world.engine`` name a scene spec uses (any
        non-empty string; the built-in simulators are listed in docs/extending/physics.md)
        and a factory ``factory() -> visphy_core.api.physics.Physics``.
    """


# ---------------------------------------------------------------- lifecycle (during a run)


@hookspec
def visphy_run_start(run: Any) -> None:
    """Called once before the first scene, after the run directory exists.

    :param run: the ``visphy_core.api.run_context.RunContext`` (config, run directory, scenes,
        metrics).
    """


@hookspec
def visphy_scene_done(run: Any, scene: Any, result: Any) -> None:
    """Called after each scene is scored (or has failed): one call per scene, failures included.

    :param run: the ``visphy_core.api.run_context.RunContext``.
    :param scene: the ``visphy_core.api.scene.Scene`` that was processed.
    :param result: the ``visphy_core.results.row.SceneResult`` row (status, failure class,
    scores).
    """


@hookspec
def visphy_run_end(run: Any, summary: Any) -> None:
    """Called once after the last scene, after results and summary are written.

    :param run: the ``visphy_core.api.run_context.RunContext``.
    :param summary: the summary dict written to ``summary.json``.
    """
