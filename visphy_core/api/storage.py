"""Storage for plugins: the content-addressed cache (`visphy_core.infra.cache`), atomic,
link-refusing file access (`visphy_core.infra.files`) and the file locks that let processes
share one home (`visphy_core.infra.locks`)."""

from __future__ import annotations

from visphy_core.infra import files
from visphy_core.infra.cache import Cache
from visphy_core.infra.files import atomic_write
from visphy_core.infra.locks import exclusive, lock_path

__all__ = [
    "atomic_write", "Cache", "exclusive", "files", "lock_path",
]
