"""Where model weights come from (a configured weight directory, then the usual caches) and the
device the loaded models run on (``metrics.device``: ``cpu`` by default, ``cuda`` when asked).

Nothing is ever downloaded by visphy. A metric that needs weights asks `find` for the files it
knows by name (torchvision's checkpoint names, an open_clip ``.bin``/``.safetensors``, a Hugging
Face model directory…); when none is found, `missing` writes the ``unavailable`` reason that says
what is missing and exactly where to put it.

Search order (first hit wins):

1. ``metrics.weights_dir`` (config; `configure` sets it for the process), then every directory
   of ``$VISPHY_WEIGHTS`` (``os.pathsep``-separated);
2. ``$TORCH_HOME/hub/checkpoints`` (default ``~/.cache/torch/hub/checkpoints``): torchvision's
   and piq's own download cache, so weights a machine already has are used as they are;
3. ``$HF_HOME/hub`` snapshots (default ``~/.cache/huggingface/hub``) for Hugging Face repo ids
   (``find_hf``).

A name may contain ``/`` (a file in a sub-directory, or a model directory).
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

_configured: list[Path] = []
_device: list[str] = ["cpu"]
_digests: dict[tuple[str, int, int], str] = {}


def configure(weights_dir: str | os.PathLike | None, device: str | None = None) -> None:
    """Set the configured weight directory (``metrics.weights_dir``; None: only the env/caches)
    and the device models run on (``metrics.device``)."""
    _configured.clear()
    if weights_dir:
        _configured.append(Path(weights_dir).expanduser())
    _device[0] = device or "cpu"


def device() -> str:
    """The torch device string loaded models run on."""
    return _device[0]


def torch_hub_checkpoints() -> Path:
    home = os.environ.get("TORCH_HOME") or os.path.join(
        os.environ.get("XDG_CACHE_HOME", os.path.expanduser("~/.cache")), "torch")
    return Path(home).expanduser() / "hub" / "checkpoints"


def hf_hub_cache() -> Path:
    if os.environ.get("HF_HUB_CACHE"):
        return Path(os.environ["HF_HUB_CACHE"]).expanduser()
    home = os.environ.get("HF_HOME") or os.path.join(
        os.environ.get("XDG_CACHE_HOME", os.path.expanduser("~/.cache")), "huggingface")
    return Path(home).expanduser() / "hub"


def search_dirs() -> list[Path]:
    """The directories searched for weight files, in order."""
    env = [Path(p).expanduser() for p in os.environ.get("VISPHY_WEIGHTS", "").split(os.pathsep)
           if p]
    return [*_configured, *env, torch_hub_checkpoints()]


def find(*names: str) -> Path | None:
    """The first existing file or directory called one of ``names`` in the search dirs."""
    for d in search_dirs():
        for name in names:
            p = d / name
            if p.exists():
                return p
    return None


def find_hf(repo_id: str) -> Path | None:
    """A local copy of a Hugging Face model: ``<weights dir>/<repo_id>`` (or its last part), or
    the newest snapshot in the HF hub cache."""
    for d in search_dirs():
        for name in (repo_id, repo_id.split("/")[-1]):
            hit = d / name
            if hit.is_dir() and any(p.is_file() for p in hit.iterdir()):
                return hit  # an empty directory of that name never hides a real copy
    snaps = hf_hub_cache() / ("models--" + repo_id.replace("/", "--")) / "snapshots"
    if snaps.is_dir():
        found = sorted((p for p in snaps.iterdir() if p.is_dir()), key=lambda p: p.stat().st_mtime)
        if found:
            return found[-1]
    return None


def missing(what: str, names: list[str] | tuple[str, ...], extra: str = "") -> str:
    """The ``unavailable`` reason of a metric whose weights were not found."""
    where = ", ".join(str(d) for d in search_dirs())
    return (f"weights not found: {what} — put {' or '.join(names)} in metrics.weights_dir "
            f"(or $VISPHY_WEIGHTS or $TORCH_HOME/hub/checkpoints); searched {where}"
            + (f". {extra}" if extra else ""))


def digest(path: Path) -> str:
    """A short content digest of a weight file or directory (part of a metric's identity, so a
    different checkpoint never reuses cached scores). Cached per path, size and mtime."""
    path = Path(path)
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    h = hashlib.sha256()
    for f in files:
        st = f.stat()
        key = (str(f.resolve()), st.st_size, st.st_mtime_ns)
        if key not in _digests:
            fh = hashlib.sha256()
            with open(f, "rb") as fp:
                for block in iter(lambda: fp.read(1 << 20), b""):
                    fh.update(block)
            _digests[key] = fh.hexdigest()
        h.update(f.name.encode() + b"\0" + _digests[key].encode())
    return h.hexdigest()[:16]
