"""Writing a file into a run directory: atomically, never through a link
(`visphy_core.infra.files.atomic_write`), and text without any secret value
(`visphy_core.infra.secrets.redact`)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from visphy_core.infra.files import atomic_write
from visphy_core.infra.secrets import public_config, redact


def write_artifact(path: Path, content: str | bytes) -> None:
    """Atomic write, never through a link (`visphy_core.infra.files.atomic_write`); text passes
    through `redact` first (no secret value reaches the run dir)."""
    atomic_write(path, redact(content) if isinstance(content, str) else content)


def write_json(path: Path, data: Any) -> None:
    """A run file (manifest, summary) as stored: atomic, never through a link, flushed to disk,
    with no secret value and no credentials in URLs (the manifest records the command line)."""
    atomic_write(path, json.dumps(public_config(data), indent=1, default=str), fsync=True)

