"""What plugins import: the hook specifications, the plugin registry and the contracts a plugin
implements (engine, model, metric, judge, physics, dataset, scene, errors, settings, config
schemas).
(See docs/architecture.md.)"""

from typing import Any

__all__ = ["RunContext"]


def __getattr__(name: str) -> Any:
    """``RunContext`` (`visphy_core.api.run_context`), imported when first asked for, so
    importing one contract module does not import them all."""
    if name == "RunContext":
        from visphy_core.api.run_context import RunContext

        return RunContext
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
