"""The JavaScript libraries of the browser engines, installed from npm into a local cache.

`visphy_core/infra/js_vendor/package-lock.json` pins every library with its integrity hash; `npm ci`
installs exactly those files into ``$VISPHY_ASSETS`` (default ``~/.cache/visphy/js``), in a folder
named after the lock file's hash, so a changed pin never mixes with an old install. Pages load
them from the fake origin ``/vendor/<package>/<file>`` and never from a CDN.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
from collections.abc import Mapping
from pathlib import Path
from typing import Iterator

ASSETS_SRC = Path(__file__).with_name("js_vendor")

#: Short names the engines' templates use, and the package file each one is.
LIBRARIES = {
    "three.min.js": "three/build/three.min.js",            # r160 UMD: global THREE
    "three.module.js": "three-esm/build/three.module.js",  # r187 ES module
    "cannon.min.js": "cannon/build/cannon.min.js",        # cannon.js 0.6.2 UMD: global CANNON
    "cannon-es.js": "cannon-es/dist/cannon-es.js",          # cannon-es ES module
    "p5.min.js": "p5/lib/p5.min.js",
    "matter.min.js": "matter-js/build/matter.min.js",
}


class AssetsMissing(RuntimeError):
    """The vendored JavaScript libraries are not installed."""


def lock_digest() -> str:
    return hashlib.sha256((ASSETS_SRC / "package-lock.json").read_bytes()).hexdigest()[:16]


def assets_root() -> Path:
    base = Path(os.environ.get("VISPHY_ASSETS", Path.home() / ".cache" / "visphy" / "js"))
    return base / lock_digest()


def node_modules() -> Path:
    return assets_root() / "node_modules"


def assets_installed() -> bool:
    nm = node_modules()
    return all((nm / rel).is_file() for rel in LIBRARIES.values())


def install_assets(quiet: bool = True) -> Path:
    """Run `npm ci` on the pinned lock file into the cache; return node_modules."""
    if assets_installed():
        return node_modules()
    npm = shutil.which("npm")
    if npm is None:
        raise AssetsMissing("npm not found: install Node.js (Debian `nodejs npm`) to vendor the "
                            "browser engines' libraries")
    root = assets_root()
    root.mkdir(parents=True, exist_ok=True)
    for name in ("package.json", "package-lock.json"):
        shutil.copyfile(ASSETS_SRC / name, root / name)
    cmd = [npm, "ci", "--ignore-scripts", "--no-audit", "--no-fund"]
    proc = subprocess.run(cmd, cwd=root, capture_output=quiet, text=True)
    if proc.returncode != 0 or not assets_installed():
        tail = (proc.stderr or "").strip().splitlines()[-3:] if quiet else []
        raise AssetsMissing(f"`npm ci` in {root} failed: {' | '.join(tail)}")
    return node_modules()


def require_assets() -> Path:
    if not assets_installed():
        raise AssetsMissing(
            f"browser engine libraries are not installed in {assets_root()}: run "
            "`python -m visphy_core setup` (or `make setup`)"
        )
    return node_modules()


class VendorFiles(Mapping[str, Path]):
    """URL path → file for the fake origin: ``vendor/<name>`` (short names) and
    ``vendor/npm/<package>/<file>`` (any file inside a pinned package, for ES module imports)."""

    def __init__(self, root: Path | None = None):
        self.root = (root or require_assets()).resolve()

    def _resolve(self, key: str) -> Path | None:
        if not key.startswith("vendor/"):
            return None
        rel = key[len("vendor/"):]
        if rel in LIBRARIES:
            rel = LIBRARIES[rel]
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
        return (f"vendor/{name}" for name in LIBRARIES)

    def __len__(self) -> int:
        return len(LIBRARIES)
