"""JavaScript libraries a plugin's pages load, installed from npm into a local cache.

A plugin declares a `JsAssets`: a folder holding ``package.json`` and a ``package-lock.json`` that
pins every library with its integrity hash, and the short names its pages use. `npm ci` installs
exactly those files into ``$VISPHY_ASSETS`` (default ``~/.cache/visphy/js``), in a folder named
after the lock file's hash, so a changed pin never mixes with an old install. Pages load them
from the fake origin ``/vendor/<name>`` and ``/vendor/npm/<package>/<file>``, never from a CDN.
Which plugins declare assets, and so what ``visphy setup`` installs, the registry says
(`visphy_core.api.assets`).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator


class AssetsMissing(RuntimeError):
    """The vendored JavaScript libraries are not installed."""


def assets_base() -> Path:
    """Where every lock file's install lives: ``$VISPHY_ASSETS``, else ``~/.cache/visphy/js``."""
    return Path(os.environ.get("VISPHY_ASSETS", Path.home() / ".cache" / "visphy" / "js"))


@dataclass(frozen=True)
class JsAssets:
    """npm packages pinned by the lock file in ``source``; ``libraries`` maps each short name a
    page loads as ``/vendor/<name>`` to its file inside ``node_modules``."""

    source: Path
    libraries: Mapping[str, str] = field(default_factory=dict, hash=False, compare=False)

    def lock_digest(self) -> str:
        return hashlib.sha256((self.source / "package-lock.json").read_bytes()).hexdigest()[:16]

    def root(self) -> Path:
        return assets_base() / self.lock_digest()

    def node_modules(self) -> Path:
        return self.root() / "node_modules"

    def locked_versions(self) -> dict[str, str]:
        """Lock entry name (a package, or an npm alias of one) -> exact version."""
        lock = json.loads((self.source / "package-lock.json").read_text())
        return {name.removeprefix("node_modules/"): str(info.get("version", "?"))
                for name, info in lock.get("packages", {}).items()
                if name.startswith("node_modules/")}

    def installed(self) -> bool:
        nm = self.node_modules()
        return all((nm / rel).is_file() for rel in self.libraries.values())

    def install(self, quiet: bool = True) -> Path:
        """Run `npm ci` on the pinned lock file into the cache; return node_modules."""
        if self.installed():
            return self.node_modules()
        npm = shutil.which("npm")
        if npm is None:
            raise AssetsMissing("npm not found: install Node.js (Debian `nodejs npm`) to vendor "
                                "the browser engines' libraries")
        root = self.root()
        root.mkdir(parents=True, exist_ok=True)
        for name in ("package.json", "package-lock.json"):
            shutil.copyfile(self.source / name, root / name)
        cmd = [npm, "ci", "--ignore-scripts", "--no-audit", "--no-fund"]
        proc = subprocess.run(cmd, cwd=root, capture_output=quiet, text=True)
        if proc.returncode != 0 or not self.installed():
            tail = (proc.stderr or "").strip().splitlines()[-3:] if quiet else []
            raise AssetsMissing(f"`npm ci` in {root} failed: {' | '.join(tail)}")
        return self.node_modules()

    def require(self) -> Path:
        """node_modules, or `AssetsMissing` saying how to install it."""
        if not self.installed():
            raise AssetsMissing(
                f"browser engine libraries are not installed in {self.root()}: run "
                "`python -m visphy_core setup` (or `make setup`)"
            )
        return self.node_modules()


class VendorFiles(Mapping[str, Path]):
    """URL path → file for the fake origin: ``vendor/<name>`` (the short names of ``assets``)
    and ``vendor/npm/<package>/<file>`` (any file inside a pinned package, for ES module
    imports)."""

    def __init__(self, assets: JsAssets, root: Path | None = None):
        self.libraries = dict(assets.libraries)
        self.root = (root or assets.require()).resolve()

    def _resolve(self, key: str) -> Path | None:
        if not key.startswith("vendor/"):
            return None
        rel = key[len("vendor/"):]
        if rel in self.libraries:
            rel = self.libraries[rel]
        elif rel.startswith("npm/"):
            rel = rel[len("npm/"):]
        else:
            return None
        path = (self.root / rel).resolve()
        if self.root not in path.parents or not path.is_file():
            return None
        return path

    def __getitem__(self, key: str) -> Path:
        path = self._resolve(key)
        if path is None:
            raise KeyError(key)
        return path

    def __contains__(self, key: object) -> bool:
        return isinstance(key, str) and self._resolve(key) is not None

    def __iter__(self) -> Iterator[str]:
        return (f"vendor/{name}" for name in self.libraries)

    def __len__(self) -> int:
        return len(self.libraries)
