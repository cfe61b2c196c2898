"""The one switch both sandboxes share: may untrusted programs run without isolation?

Untrusted (model-written) programs run only inside namespaces. Where the kernel refuses them,
the process sandbox and the browser sandbox refuse such programs, unless the user opted out
explicitly: config key ``sandbox.allow_unisolated=true`` (the run loop calls `set_allow_unisolated`)
or the environment variable ``VISPHY_ALLOW_UNISOLATED=1``.
"""

from __future__ import annotations

import os

ALLOW_UNISOLATED_ENV = "VISPHY_ALLOW_UNISOLATED"

_allow_unisolated: bool | None = None


def set_allow_unisolated(value: bool | None) -> None:
    """True/False decides for this process; None defers to ``$VISPHY_ALLOW_UNISOLATED``."""
    global _allow_unisolated
    _allow_unisolated = None if value is None else bool(value)


def unisolated_allowed() -> bool:
    """True when the user opted out of isolation (config or environment variable)."""
    if _allow_unisolated is not None:
        return _allow_unisolated
    return os.environ.get(ALLOW_UNISOLATED_ENV, "").strip().lower() in ("1", "true", "yes", "on")
