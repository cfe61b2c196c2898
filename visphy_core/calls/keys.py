"""API keys: from the environment, else from a ``.env`` file; never a default, never a log line.

Lookup order for a variable such as ``ANTHROPIC_API_KEY``: the process environment, then
``$VISPHY_ENV_FILE`` when set, else ``.env`` in the working directory, then ``.env`` in
``$VISPHY_HOME``. A key read from a file is registered with `visphy_core.infra.secrets`, so
redaction
covers it exactly like an exported one. The key never enters ``os.environ``: the sandboxes start
from allow-listed environments anyway, and a key that is not exported cannot leak through one.
"""

from __future__ import annotations

import io
import os
from pathlib import Path

from visphy_core.infra.errors import UserError
from visphy_core.infra.secrets import SECRET_ENV_LIST, is_secret_name, register_secret


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


_PARSED: dict[tuple[str, int, int], dict[str, str]] = {}
MAX_ENV_FILE = 1 << 20


def read_env_file(path: Path) -> dict[str, str]:
    """The non-empty ``NAME=value`` entries of a ``.env`` file; a file that is not UTF-8 text
    (binary, another encoding) or cannot be read is a `UserError` naming the file, one line."""
    try:
        st = path.stat()
        key = (str(path), st.st_mtime_ns, st.st_size)
        if key in _PARSED:
            return _PARSED[key]
        if st.st_size > MAX_ENV_FILE:
            raise UserError(f"{path}: a .env file of {st.st_size} bytes is too large (over "
                            f"{MAX_ENV_FILE}); it should hold lines NAME=value")
        data = path.read_bytes()
    except OSError as exc:
        raise UserError(f"{path}: the .env file cannot be read ({exc.strerror or exc})") \
            from None
    try:
        text = data.decode("utf-8")
        if "\x00" in text:
            raise UnicodeDecodeError("utf-8", data, text.index("\x00"), text.index("\x00") + 1,
                                     "NUL byte")
    except UnicodeDecodeError:
        raise UserError(f"{path}: the .env file is not UTF-8 text (binary or another encoding); "
                        "it should hold lines NAME=value") from None
    from dotenv import dotenv_values

    values = {k: v for k, v in dotenv_values(stream=io.StringIO(text)).items() if k and v}
    _PARSED[key] = values
    return values


def register_env_files() -> None:
    """Register every secret of the ``.env`` files (by name, or listed in
    ``VISPHY_SECRET_ENV`` of the environment or of the file) with `visphy_core.infra.secrets`, so
    redaction covers them even when no key is looked up. The CLI calls it first: a bad ``.env``
    is one line before any work."""
    for path in env_files():
        if not path.is_file():
            continue
        values = read_env_file(path)
        listed = {n.strip() for raw in (os.environ.get(SECRET_ENV_LIST, ""),
                                        values.get(SECRET_ENV_LIST, ""))
                  for n in raw.split(",") if n.strip()}
        for name, value in values.items():
            if name != SECRET_ENV_LIST and is_secret_name(name, listed):
                register_secret(name, value)


def _from_files(var: str) -> tuple[str | None, Path | None]:
    for path in env_files():
        if path.is_file():
            value = read_env_file(path).get(var)
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
