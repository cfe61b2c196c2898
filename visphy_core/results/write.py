"""Writing a file into a run directory: atomically, never through a link
(`visphy_core.infra.files.atomic_write`), and text without any secret value
(`visphy_core.infra.secrets.redact`)."""

from __future__ import annotations

from pathlib import Path

from visphy_core.infra.files import atomic_write
from visphy_core.infra.secrets import redact


def write_artifact(path: Path, content: str | bytes) -> None:
    """Atomic write, never through a link (`visphy_core.infra.files.atomic_write`); text passes
    through `redact` first (no secret value reaches the run dir)."""
    atomic_write(path, redact(content) if isinstance(content, str) else content)
