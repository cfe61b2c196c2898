"""One way for plugins to read an optional setting from their config node."""

from __future__ import annotations

from typing import Any


def cfg_get(cfg: Any, key: str, default: Any = None) -> Any:
    """``cfg[key]`` from an OmegaConf node, a dict or any object with the attribute; ``default``
    when ``cfg`` is None, the key is absent (a struct config's unknown key included) or its
    value is None."""
    if cfg is None:
        return default
    try:
        value = cfg.get(key, default) if hasattr(cfg, "get") else getattr(cfg, key, default)
    except Exception:  # noqa: BLE001 - struct configs raise on unknown keys
        return default
    return default if value is None else value
