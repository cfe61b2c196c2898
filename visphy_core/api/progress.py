"""Progress for plugins' long loops (a dataset build): `track` shows rich's transient bar on a
terminal and plain, paced lines in a log (`visphy_core.infra.progress`)."""

from __future__ import annotations

from visphy_core.infra.progress import track

__all__ = ["track"]
