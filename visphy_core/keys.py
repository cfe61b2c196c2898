"""API keys: from the environment, else from a ``.env`` file; never a default, never a log line.

Lookup order for a variable such as ``ANTHROPIC_API_KEY``: the process environment, then
``$VISPHY_ENV_FILE`` when set, else ``.env`` in the working directory, then ``.env`` in
``$VISPHY_HOME``. A key read from a file is registered with `visphy_core.secrets`, so redaction
covers it exactly like an exported one. The key never enters ``os.environ``: the sandboxes start
from allow-listed environments anyway, and a key that is not exported cannot leak through one.
"""

from __future__ import annotations

import os
from pathlib import Path

from visphy_core.errors import UserError
from visphy_core.secrets import register_secret


class MissingKey(UserError):
    """A model or judge needs a key that is nowhere to be found."""


def env_files() -> list[Path]:
    explicit = os.environ.get("VISPHY_ENV_FILE")
    if explicit:
        return [Path(explicit)]
    files = [Path.cwd() / ".env"]
    home = os.environ.get("VISPHY_HOME")
    if home:
        files.append(Path(home) / ".env")
    return files


def _from_files(var: str) -> tuple[str | None, Path | None]:
    from dotenv import dotenv_values

    for path in env_files():
        if path.is_file():
            value = dotenv_values(path).get(var)
            if value:
                return value, path
    return None, None


def find_key(var: str) -> str | None:
    """The key's value, or None when neither the environment nor a ``.env`` file has it."""
    value = os.environ.get(var)
    if value:
        return value
    value, _ = _from_files(var)
    if value:
        register_secret(var, value)
    return value


def require_key(var: str, who: str) -> str:
    """The key, or `MissingKey` with one line saying where visphy looked."""
    value = find_key(var)
    if value:
        return value
    places = ", ".join(str(p) for p in env_files())
    raise MissingKey(f"{who} needs the API key in ${var}: it is not set in the environment "
                     f"nor in {places}; export it (or put {var}=... in .env) and run again")
