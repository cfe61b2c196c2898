"""What plugins import: the hook specifications, the plugin registry and the contracts a plugin
implements (engine, model, metric, judge, physics, dataset, scene, errors, settings, config
schemas). See docs/architecture.md and docs/extending/.

The public contract is re-exported here (``from visphy_core.api import Engine, hookimpl``): the
names of `__all__`, each imported from its module when first asked for, so importing one
contract does not import them all. Anything else under ``visphy_core.api`` is importable from its
module but is not part of the contract a plugin may rely on across versions; the facades
(`media`, `sandbox`, `calls`, `spec`, `storage`, `scoring`) are modules a plugin imports as such.
"""

from importlib import import_module
from typing import Any

#: Public name → the module under ``visphy_core.api`` that defines it.
_PUBLIC: dict[str, str] = {
    # plugin registration
    "hookimpl": "hookspecs", "hookspec": "hookspecs", "get_registry": "registry",
    "Registry": "registry", "PluginError": "registry",
    # engines
    "Engine": "engine", "Program": "engine", "RenderContract": "engine",
    "RenderResult": "engine", "FailureClass": "engine", "RenderFlag": "engine",
    "ProgramRejected": "engine",
    # models
    "Model": "model", "ModelRequest": "model", "ModelResponse": "model",
    "ImageInput": "model", "OutputContract": "model",
    # metrics and judges
    "Metric": "metrics", "MetricInput": "metrics", "Alignment": "metrics",
    "Judge": "judge", "JudgeInput": "judge", "Verdict": "judge",
    # physics, datasets, scenes
    "Physics": "physics", "Rollout": "physics", "trajectory_digest": "physics",
    "Dataset": "dataset", "GroundTruth": "dataset", "Scene": "scene",
    # a run, as lifecycle plugins see it
    "RunContext": "run_context",
    # errors a plugin raises
    "UserError": "errors", "ConfigError": "errors", "SceneDataError": "errors",
}

__all__ = sorted(_PUBLIC)


def __getattr__(name: str) -> Any:
    module = _PUBLIC.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(import_module(f"{__name__}.{module}"), name)
    globals()[name] = value  # asked once
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
