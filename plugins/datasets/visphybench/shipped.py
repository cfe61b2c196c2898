"""The catalogue shipped with visphy: the default seed's catalogue, as package data.

A catalogue (every scene's annotated spec, trajectory digest, attempts and rejections, labels
and splits) is a deterministic function of the generator version and the seed, but simulating
it costs one to two minutes on two cores, before the first scene can be touched. So the seed-0
catalogue of the current generator ships with the package, as the exact bytes a build writes to
``catalogue.json``, gzipped (``data/catalogue-v<version>-seed<seed>.json.gz``), and
``data/catalogues.json`` records each file's builder, seed and the SHA-256 of those bytes.

`shipped_bytes` returns the bytes only when the file decompresses and its digest is the one
recorded; anything else raises `ShippedDamaged` naming what is wrong, and the caller simulates
the catalogue instead. ``scripts/ship_catalogue.py`` regenerates the file (run it after any
change that alters a scene; ``tests/test_shipped_catalogue.py`` fails until it is run).
"""

from __future__ import annotations

import gzip
import hashlib
import json
import zlib
from pathlib import Path

from visphy_plugins.datasets.visphybench.catalogue import GENERATOR_VERSION

DATA = Path(__file__).resolve().with_name("data")
MANIFEST_NAME = "catalogues.json"


class ShippedDamaged(Exception):
    """The shipped catalogue cannot be used: missing, truncated, altered or unlisted."""


def shipped_name(seed: int, version: int = GENERATOR_VERSION) -> str:
    return f"catalogue-v{version}-seed{seed}.json.gz"


def read_manifest(data: Path | None = None) -> dict:
    """``{file name: {"builder", "seed", "sha256", "bytes", "scenes"}}`` of the folder ``data``
    (default `DATA`); empty when there is no manifest; `ShippedDamaged` when it does not
    parse."""
    path = (data or DATA) / MANIFEST_NAME
    try:
        manifest = json.loads(path.read_bytes())
    except FileNotFoundError:
        return {}
    except (OSError, ValueError) as exc:
        raise ShippedDamaged(f"{path} is unreadable: {type(exc).__name__}") from None
    if not isinstance(manifest, dict):
        raise ShippedDamaged(f"{path} is not a manifest")
    return manifest


def shipped_bytes(seed: int, data: Path | None = None) -> bytes | None:
    """The ``catalogue.json`` bytes shipped for ``seed`` (this generator version), checked
    against the recorded digest; None when none is shipped for that seed."""
    data = data or DATA
    name = shipped_name(seed)
    path = data / name
    record = read_manifest(data).get(name)
    if record is None:
        if path.exists():
            raise ShippedDamaged(f"{path} is not listed in {data / MANIFEST_NAME}")
        return None
    try:
        packed = path.read_bytes()
    except OSError as exc:
        raise ShippedDamaged(f"{path}: {type(exc).__name__}: {exc.strerror or exc}") from None
    try:
        raw = gzip.decompress(packed)
    except (OSError, EOFError, zlib.error) as exc:
        raise ShippedDamaged(f"{path} does not decompress ({type(exc).__name__})") from None
    digest = hashlib.sha256(raw).hexdigest()
    if not isinstance(record, dict) or digest != record.get("sha256"):
        raise ShippedDamaged(f"{path} has SHA-256 {digest[:12]}…, not the recorded "
                             f"{str((record or {}).get('sha256'))[:12]}…")
    return raw


def write_shipped(raw: bytes, seed: int, builder: str, n_scenes: int,
                  data: Path | None = None) -> Path:
    """Write ``raw`` (a build's ``catalogue.json`` bytes) as the shipped catalogue of ``seed``
    and record it in the manifest; gzip without a timestamp, so equal catalogues ship as equal
    files."""
    data = data or DATA
    data.mkdir(parents=True, exist_ok=True)
    name = shipped_name(seed)
    path = data / name
    path.write_bytes(gzip.compress(raw, compresslevel=9, mtime=0))
    manifest = read_manifest(data)
    manifest[name] = {"builder": builder, "seed": seed,
                      "sha256": hashlib.sha256(raw).hexdigest(), "bytes": len(raw),
                      "scenes": n_scenes}
    (data / MANIFEST_NAME).write_text(json.dumps(dict(sorted(manifest.items())), indent=1)
                                      + "\n")
    return path
