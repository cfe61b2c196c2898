"""The pre-flight of an API model or judge: what `check_ready` asks before any scene is loaded.

Every API model: ``model.model_id`` is set, and the key variable is set (`require_key`; the
provider's own SDK default endpoint, i.e. OpenAI, Anthropic, Google, is not contacted: a wrong key
there is the first call's ``auth`` error, which stops the run after that one call).

An OpenAI-compatible server named by ``model.base_url`` (``model=openai_compat``: vLLM, Ollama,
llama.cpp, LM Studio; also DashScope's compatible mode) is asked once, ``GET {base_url}/models``
through the official SDK with a short timeout and no retries:

* nothing answers (refused, unresolvable, timed out): one line naming the URL and
  ``model.base_url``, before any work (instead of every scene's call retrying for half a minute);
* the key is refused (401/403): one line naming the key variable;
* the server lists its models: ``model.model_id`` must be one of them (the line lists them);
* ``GET /models`` is not found (404): the URLs a wrong ``base_url`` usually meant are tried —
  with ``/v1`` added, and without a pasted endpoint path (``…/v1/chat/completions``) — and when
  one lists models the line names it (``set model.base_url=<that URL>``); a server that lists
  models nowhere (or answers anything else) is taken at its word.

A local endpoint (`is_local`: loopback, a private or link-local address, ``localhost``, a
single-label host name or one under ``.local``/``.lan``/``.internal``/``.home.arpa``) needs no
key: when the key variable is not set the SDK is given ``"none"``, as vLLM, Ollama and llama.cpp
accept any key unless started with one.
"""

from __future__ import annotations

import ipaddress
from typing import Any
from urllib.parse import urlsplit

from visphy_core.api.errors import UserError
from visphy_plugins.providers.base import ApiCaller, ApiModel

#: seconds the pre-flight waits for the server's model list
PREFLIGHT_TIMEOUT_S = 5.0
LOCAL_SUFFIXES = (".local", ".lan", ".internal", ".home.arpa", ".localhost")


def is_local(base_url: str | None) -> bool:
    """Whether ``base_url`` names a server on this machine or the local network."""
    if not base_url:
        return False
    host = (urlsplit(str(base_url)).hostname or "").rstrip(".").lower()
    if not host:
        return False
    if host == "localhost" or host.endswith(LOCAL_SUFFIXES):
        return True
    try:
        ip = ipaddress.ip_address(host)
    except ValueError:
        return "." not in host  # a single-label name: a machine of the local network
    return ip.is_loopback or ip.is_private or ip.is_link_local or ip.is_unspecified


class LocalKeyCaller(ApiCaller):
    """`ApiCaller` of a local endpoint: the key variable when it is set, else ``"none"``."""

    def api_key(self) -> str:
        try:
            return super().api_key()
        except UserError:
            return "none"


def served_models(base_url: str, api_key: str, timeout_s: float = PREFLIGHT_TIMEOUT_S
                  ) -> list[str] | None:
    """The model ids the OpenAI-compatible server at ``base_url`` lists (``GET /models``), or
    None when it does not list them. Raises `UserError` (one line) when no server answers or
    the key is refused."""
    import openai

    client = openai.OpenAI(api_key=api_key, base_url=base_url, max_retries=0,
                           timeout=timeout_s)
    try:
        return [str(m.id) for m in client.models.list().data]
    except openai.APITimeoutError:
        raise UserError(f"no answer from {base_url} within {timeout_s:g} s") from None
    except openai.APIConnectionError as exc:
        cause = exc.__cause__
        reason = " ".join(str(cause or exc).split()) or type(cause or exc).__name__
        raise UserError(f"no server answers at {base_url} ({reason})") from None
    except openai.AuthenticationError as exc:
        raise _Refused(exc.status_code) from None
    except openai.PermissionDeniedError as exc:
        raise _Refused(exc.status_code) from None
    except openai.NotFoundError:
        raise _NotFound() from None
    except (openai.APIStatusError, openai.APIResponseValidationError, ValueError,
            TypeError, AttributeError):
        return None  # no model list here (an unusual answer or body): the first call will tell
    finally:
        client.close()


class _NotFound(Exception):
    """``GET {base_url}/models`` answered 404."""


#: endpoint paths a user may paste into ``base_url`` (the SDK adds them itself)
ENDPOINT_PATHS = ("/chat/completions", "/completions", "/responses", "/embeddings", "/models")


def api_roots(base_url: str) -> list[str]:
    """Where the OpenAI-compatible API probably is when ``base_url`` has no ``/models``: the
    URL without a pasted endpoint path, and with ``/v1`` added (most servers' prefix)."""
    parts = urlsplit(base_url)
    path = parts.path.rstrip("/")
    roots = []
    for suffix in ENDPOINT_PATHS:
        if path.endswith(suffix):
            path = path[:-len(suffix)].rstrip("/")
            roots.append(path)
            break
    if not path.endswith("/v1"):
        roots.append(path + "/v1")
    seen, out = {parts.path.rstrip("/")}, []
    for root in roots:
        if root not in seen:
            seen.add(root)
            out.append(parts._replace(path=root, query="", fragment="").geturl())
    return out


def _listed_elsewhere(base_url: str, api_key: str) -> tuple[str, list[str]] | None:
    """(the URL, its models) of the first of `api_roots` that lists models, if any."""
    for root in api_roots(base_url):
        try:
            ids = served_models(root, api_key)
        except (UserError, _NotFound):
            continue
        if ids:
            return root, ids
    return None


class _Refused(UserError):
    def __init__(self, status: int):
        super().__init__(f"HTTP {status}")
        self.status = status


def _listing(ids: list[str], most: int = 10) -> str:
    more = f", … ({len(ids) - most} more)" if len(ids) > most else ""
    return ", ".join(ids[:most]) + more


def preflight(settings: Any, who: str, api: ApiCaller) -> None:
    """Raise `UserError` (one line) unless the model can be called: see the module docstring."""
    model_id = str(settings.get("model_id") or "").strip()
    base_url = settings.get("base_url")
    key = api.api_key()  # MissingKey for a remote endpoint without its key
    if str(settings.get("provider") or "openai") != "openai" or not base_url:
        if not model_id:
            raise UserError(f"{who} has no model id: add model.model_id=<the provider's model "
                            "name> to the command")
        return
    base_url = str(base_url).rstrip("/")
    found = None
    try:
        try:
            ids = served_models(base_url, key)
        except _NotFound:
            ids, found = None, _listed_elsewhere(base_url, key)  # None: lists them nowhere
    except _Refused as exc:
        env = api.key_env
        raise UserError(f"{who}: the server at {base_url} refused the key (HTTP {exc.status}): "
                        + (f"set ${env} to the key the server expects" if env
                           else "set model.api_key_env to the variable holding its key")
                        ) from None
    except UserError as exc:
        raise UserError(f"{who}: {exc}: start the server (vLLM, Ollama, llama.cpp, ...) or set "
                        "model.base_url=<its OpenAI-compatible URL, e.g. "
                        "http://localhost:8000/v1>") from None
    if found is not None:
        raise UserError(f"{who}: {base_url}/models is not found (HTTP 404): model.base_url is "
                        f"not the server's OpenAI-compatible API; it answers at {found[0]}: "
                        f"set model.base_url={found[0]}")
    if not model_id:
        served = f"; it serves: {_listing(ids)}" if ids else ""
        raise UserError(f"{who} has no model id: add model.model_id=<the model the server at "
                        f"{base_url} serves>{served}")
    if ids and model_id not in ids:
        raise UserError(f"{who}: model.model_id={model_id} is not served at {base_url}; it "
                        f"serves: {_listing(ids)} (set model.model_id to one of them)")


class CheckedApiModel(ApiModel):
    """`ApiModel` with the pre-flight as its `check_ready`, and no key demanded by a local
    endpoint."""

    def __init__(self, cfg: Any):
        super().__init__(cfg)
        if is_local(cfg.get("base_url")):
            self.api = LocalKeyCaller(cfg, f"model={self.name}")
            self.needs_key = None

    def check_ready(self) -> None:
        preflight(self.cfg, f"model={self.name}", self.api)
