"""Which values are secrets, and how to keep them out of everything visphy writes.

Containment (the sandboxes) keeps secrets away from model-written programs; this module is the
second line: before a log, a failure detail, a repair prompt or cached metadata is written, every
configured secret value in it is replaced by ``[REDACTED:<NAME>]``.

A secret is, by name, the value of an environment variable whose name contains one of
`SECRET_MARKERS` (``OPENAI_API_KEY``, ``HF_TOKEN``, ``DB_PASSWORD``…), or whose name is listed in
``VISPHY_SECRET_ENV`` (comma-separated, for secrets with innocent names), and every such entry of
a ``.env`` file visphy reads keys from (`register_secret`); values shorter than `MIN_SECRET_LEN`
characters are not treated as secrets (redacting "1" would shred every log). And, by value,
whatever has the shape of a credential wherever it comes from (`VALUE_PATTERNS`): the user
information of a URL (``postgres://u:pw@db/x`` → ``postgres://[REDACTED]@db/x``), a
``Bearer`` token, a ``?key=``/``token=``/``password=`` query value, and the well-known key
prefixes (``sk-…``, ``AIza…``, ``hf_…``, ``ghp_…``, ``github_pat_…``, ``AKIA…``, ``xox?-…``,
``glpat-…``, JSON Web Tokens).

`public_url` and `public_config` give the form of a URL and of a config that may be stored
(``config.yaml``, MLflow params): no credentials in URLs, no secret values.
"""

from __future__ import annotations

import logging
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


#: Credentials recognised by their shape: (pattern, replacement). A pattern's group ``keep``
#: (when present) is kept, the rest of the match becomes ``[REDACTED]``.
VALUE_PATTERNS: tuple[tuple[re.Pattern, str], ...] = (
    # URL user information: scheme://user:password@host, scheme://token@host
    (re.compile(r"(?P<keep>\b[A-Za-z][A-Za-z0-9+.-]{0,30}://)[^\s/?#@'\"<>]+@"),
     "[REDACTED]@"),
    (re.compile(r"(?P<keep>\b(?:Bearer|Basic|Token)\s+)[A-Za-z0-9._~+/=-]{8,}", re.IGNORECASE),
     "[REDACTED]"),
    (re.compile(r"(?P<keep>[?&;](?:api[_-]?key|key|token|access[_-]?token|secret|password|"
                r"passwd|sig|signature)=)[^&#\s'\"<>]{4,}", re.IGNORECASE), "[REDACTED]"),
    (re.compile(r"\b(?:sk|rk|pk)[-_](?:live[-_]|test[-_]|proj[-_]|ant[-_]|svcacct[-_])?"
                r"[A-Za-z0-9_-]{20,}"), "[REDACTED]"),
    (re.compile(r"\bAIza[0-9A-Za-z_-]{30,}"), "[REDACTED]"),
    (re.compile(r"\bhf_[A-Za-z0-9]{24,}"), "[REDACTED]"),
    (re.compile(r"\b(?:gh[pousr]_[A-Za-z0-9]{30,}|github_pat_[A-Za-z0-9_]{22,})"),
     "[REDACTED]"),
    (re.compile(r"\b(?:AKIA|ASIA)[0-9A-Z]{16}\b"), "[REDACTED]"),
    (re.compile(r"\bxox[abposr]-[A-Za-z0-9-]{10,}"), "[REDACTED]"),
    (re.compile(r"\bglpat-[A-Za-z0-9_-]{20,}"), "[REDACTED]"),
    (re.compile(r"\beyJ[A-Za-z0-9_-]{10,}\.eyJ[A-Za-z0-9_-]{10,}\.[A-Za-z0-9_-]{10,}"),
     "[REDACTED]"),
)


def _redact_shapes(text: str) -> str:
    for pattern, replacement in VALUE_PATTERNS:
        if "keep" in pattern.groupindex:
            text = pattern.sub(lambda m, r=replacement: m.group("keep") + r, text)
        else:
            text = pattern.sub(replacement, text)
    return text


def redact(text: str | None, environ: Mapping[str, str] | None = None) -> str | None:
    """``text`` with every secret value replaced by ``[REDACTED:<NAME>]`` and every credential
    recognised by its shape by ``[REDACTED]`` (None stays None)."""
    if not text:
        return text
    values = secret_values(environ)
    if values:
        # Longest first, so a secret that contains another is replaced whole.
        pattern = re.compile("|".join(re.escape(v)
                                      for v in sorted(values, key=len, reverse=True)))
        text = pattern.sub(lambda m: f"[REDACTED:{values[m.group(0)]}]", text)
    return _redact_shapes(text)


def public_url(url: str) -> str:
    """``url`` without the user information (``https://u:p@host/v1`` → ``https://host/v1``)."""
    return VALUE_PATTERNS[0][0].sub(lambda m: m.group("keep"), url)


def public_config(obj: Any) -> Any:
    """A config container (dicts, lists, scalars) as it may be stored: URLs without user
    information, then `redact_obj` (secret values, credential shapes)."""
    if isinstance(obj, str):
        return redact(public_url(obj))
    if isinstance(obj, dict):
        return {k: public_config(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return type(obj)(public_config(v) for v in obj)
    return obj


def redact_obj(obj: Any, environ: Mapping[str, str] | None = None) -> Any:
    """`redact` applied to every string inside lists, tuples and dicts (keys included)."""
    if isinstance(obj, str):
        return redact(obj, environ)
    if isinstance(obj, dict):
        return {redact_obj(k, environ): redact_obj(v, environ) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return type(obj)(redact_obj(v, environ) for v in obj)
    return obj


def public_yaml(cfg: Any) -> str:
    """A resolved OmegaConf config as the YAML a run directory stores (`public_config`)."""
    from omegaconf import OmegaConf

    return OmegaConf.to_yaml(OmegaConf.create(
        public_config(OmegaConf.to_container(cfg, resolve=True))))


class _RedactedRecord(logging.LogRecord):
    def getMessage(self) -> str:  # noqa: N802 (logging's name)
        return redact(super().getMessage()) or ""


def install_log_redaction() -> None:
    """Every log record of every logger (visphy's, the SDKs', httpx's request lines with a
    URL's user information) passes through `redact` when it is formatted. Idempotent."""
    if logging.getLogRecordFactory() is not _RedactedRecord:
        logging.setLogRecordFactory(_RedactedRecord)
