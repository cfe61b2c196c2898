"""Which values are secrets, and how to keep them out of everything visphy writes.

Containment (the sandboxes) keeps secrets away from model-written programs; this module is the
second line: before a log, a failure detail, a repair prompt or cached metadata is written, every
configured secret value in it is replaced by ``[REDACTED:<NAME>]``.

A secret is the value of an environment variable whose name contains one of `SECRET_MARKERS`
(``OPENAI_API_KEY``, ``HF_TOKEN``, ``DB_PASSWORD``…), or whose name is listed in
``VISPHY_SECRET_ENV`` (comma-separated, for secrets with innocent names). Values shorter than
`MIN_SECRET_LEN` characters are not treated as secrets (redacting "1" would shred every log).
"""

from __future__ import annotations

import os
import re
from typing import Any, Mapping

#: Substrings (upper case) of environment variable names whose values are secrets.
SECRET_MARKERS = ("KEY", "TOKEN", "SECRET", "PASSWORD", "PASSWD", "CREDENTIAL", "AUTH")
#: Extra variable names to treat as secrets: ``VISPHY_SECRET_ENV=MY_VAR,OTHER_VAR``.
SECRET_ENV_LIST = "VISPHY_SECRET_ENV"
MIN_SECRET_LEN = 6
#: Secrets that are not in the environment (API keys read from a ``.env`` file): name -> value.
_REGISTERED: dict[str, str] = {}


def register_secret(name: str, value: str) -> None:
    """Treat ``value`` as a secret named ``name`` from now on (keys read from ``.env``)."""
    if value and len(value) >= MIN_SECRET_LEN:
        _REGISTERED[name] = value


def is_secret_name(name: str, extra: set[str] | None = None) -> bool:
    """True for a variable name that holds a secret (by marker, or listed explicitly)."""
    upper = name.upper()
    if extra and name in extra:
        return True
    return any(marker in upper for marker in SECRET_MARKERS)


def _listed(environ: Mapping[str, str]) -> set[str]:
    raw = environ.get(SECRET_ENV_LIST, "")
    return {n.strip() for n in raw.split(",") if n.strip()}


def secret_values(environ: Mapping[str, str] | None = None) -> dict[str, str]:
    """{value: variable name} of every secret in ``environ`` (default: ``os.environ``)."""
    env = os.environ if environ is None else environ
    listed = _listed(env)
    out: dict[str, str] = {}
    for name, value in env.items():
        if name == SECRET_ENV_LIST or not value or len(value) < MIN_SECRET_LEN:
            continue
        if is_secret_name(name, listed):
            out[value] = name
    if environ is None:
        for name, value in _REGISTERED.items():
            out.setdefault(value, name)
    return out


def redact(text: str | None, environ: Mapping[str, str] | None = None) -> str | None:
    """``text`` with every secret value replaced by ``[REDACTED:<NAME>]`` (None stays None)."""
    if not text:
        return text
    values = secret_values(environ)
    if not values:
        return text
    # Longest first, so a secret that contains another is replaced whole.
    pattern = re.compile("|".join(re.escape(v) for v in sorted(values, key=len, reverse=True)))
    return pattern.sub(lambda m: f"[REDACTED:{values[m.group(0)]}]", text)


def redact_obj(obj: Any, environ: Mapping[str, str] | None = None) -> Any:
    """`redact` applied to every string inside lists, tuples and dicts (keys included)."""
    if isinstance(obj, str):
        return redact(obj, environ)
    if isinstance(obj, dict):
        return {redact_obj(k, environ): redact_obj(v, environ) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return type(obj)(redact_obj(v, environ) for v in obj)
    return obj
