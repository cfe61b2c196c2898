"""The JavaScript assets of the registered engines: what ``visphy setup`` installs.

An engine class declares its npm packages in `Engine.js_assets` (a
`visphy_core.infra.js_assets.JsAssets`); engines that share one lock file share one install.
The core knows no library by name: it installs and checks what the registry's engines declare.
"""

from __future__ import annotations

from pathlib import Path

from visphy_core.infra.js_assets import AssetsMissing, JsAssets


def engine_assets(registry=None) -> list[JsAssets]:
    """Every asset set a registered engine class declares, each lock file once, in engine-name
    order (an engine registered through a factory function declares none)."""
    if registry is None:
        from visphy_core.api.registry import get_registry

        registry = get_registry()
    found: dict[Path, JsAssets] = {}
    for name in sorted(registry.engines):
        assets = getattr(registry.engines[name][0], "js_assets", None)
        if isinstance(assets, JsAssets):
            found.setdefault(assets.source.resolve(), assets)
    return list(found.values())


def assets_installed(registry=None) -> bool:
    """Whether every registered engine's assets are installed."""
    return all(assets.installed() for assets in engine_assets(registry))


def install_assets(quiet: bool = True, registry=None) -> list[Path]:
    """`npm ci` of every registered engine's lock file into the cache; their node_modules."""
    return [assets.install(quiet) for assets in engine_assets(registry)]


def vendored_file(rel: str, registry=None) -> Path:
    """A file inside ``node_modules`` (``<package>/dist/<file>.js``) from the registered
    engines' installed assets; `AssetsMissing` when none of them has it."""
    sets = engine_assets(registry)
    for assets in sets:
        path = assets.node_modules() / rel
        if assets.installed() and path.is_file():
            return path
    for assets in sets:
        assets.require()
    raise AssetsMissing(f"no registered engine vendors {rel}")


def require_assets(registry=None) -> Path:
    """The node_modules folder of the registered engines' one asset set (the built-in browser
    engines share theirs); `AssetsMissing` when it is not installed. With several sets, ask for
    a file with `vendored_file`."""
    sets = engine_assets(registry)
    if len(sets) != 1:
        raise AssetsMissing(f"{len(sets)} JavaScript asset sets are registered: name the file "
                            "with vendored_file")
    return sets[0].require()
