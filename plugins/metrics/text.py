"""text metrics (being written)."""

from __future__ import annotations

from visphy_core.hookspecs import hookimpl


@hookimpl
def visphy_register_metrics(register):
    pass
