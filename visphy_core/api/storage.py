"""Storage for plugins: the content-addressed cache (`visphy_core.infra.cache`) and atomic,
link-refusing file access (`visphy_core.infra.files`)."""

from __future__ import annotations

from visphy_core.infra import files
from visphy_core.infra.cache import Cache
from visphy_core.infra.files import atomic_write

__all__ = [
    "atomic_write", "Cache", "files",
]
