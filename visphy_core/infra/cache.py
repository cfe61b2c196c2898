"""Content-addressed store for model replies, renders and scores.

A key is the SHA-256 of everything that determines a stage's output (inputs + plugin identity and
version). Entries are written to a temp dir and renamed into place, so a crash never leaves a half
entry, and an interrupted run resumes exactly where it stopped.

Integrity: the ``.complete`` marker of an entry holds the SHA-256 of every payload file
(``{"format": 1, "files": {name: digest}}``). Every read verifies them; an entry whose digests do
not match, that misses a file, that predates digests, or whose payload does not parse (see
`Cache.load`) is reported once as a warning naming its path, deleted and treated as a miss, so the
stage recomputes it. A corrupt entry is never served.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
import tempfile
from collections import Counter
from pathlib import Path
from typing import Any, Callable, TypeVar

from visphy_core.infra import files as files_mod

log = logging.getLogger("visphy.cache")

T = TypeVar("T")

MARKER = ".complete"
FORMAT = 1


class CorruptEntry(Exception):
    """A cache entry that cannot be trusted (raised by parsers given to `Cache.load`)."""


def content_key(*parts: Any) -> str:
    """Stable hash of JSON-serialisable parts (strings are hashed as-is)."""
    h = hashlib.sha256()
    for part in parts:
        data = part if isinstance(part, str) else json.dumps(part, sort_keys=True, default=str)
        h.update(hashlib.sha256(data.encode()).digest())
    return h.hexdigest()


def file_digest(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def read_json(path: Path) -> Any:
    """Parse a JSON payload file; any read or decode error is a `CorruptEntry` naming the file."""
    try:
        return json.loads(Path(path).read_bytes().decode("utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise CorruptEntry(f"{path}: {type(exc).__name__}: {exc}") from None


class Cache:
    """``<root>/<kind>/<ab>/<key>/`` directories holding one stage result each.

    ``enabled=False`` (``run.cache=false``) makes every lookup a miss, so everything is recomputed;
    the fresh results are stored, replacing any existing entry, and the stages read them back.
    """

    def __init__(self, root: str | Path, enabled: bool = True):
        self.root = Path(root)
        self.enabled = enabled
        self.hits: Counter[str] = Counter()
        self.misses: Counter[str] = Counter()
        self.dropped: Counter[str] = Counter()
        self.warnings: list[str] = []   # one line per dropped entry, path named
        self._reported: set[Path] = set()

    def path(self, kind: str, key: str) -> Path:
        return self.root / kind / key[:2] / key

    # ------------------------------------------------------------------ integrity
    def verify(self, entry: Path) -> str | None:
        """None when every payload file matches its recorded digest, else why not."""
        try:  # no link on the way to the entry or in it, only regular files (never followed)
            files_mod.entry_kind(entry, self.root)
            refused = files_mod.scan_tree(entry)
        except (OSError, files_mod.ForeignFileError) as exc:
            return f"unsafe entry ({' '.join(str(exc).split())[:300]})"
        if refused:
            first = sorted(refused)[0]
            return f"{first} is {refused[first]}"
        marker = entry / MARKER
        try:
            raw = marker.read_bytes()
        except OSError as exc:
            return f"unreadable marker ({exc.strerror or exc})"
        if not raw.strip():
            return "entry without digests (written by an older visphy)"
        try:
            manifest = json.loads(raw.decode("utf-8"))
            files = manifest["files"]
            if not isinstance(files, dict):
                raise TypeError("files is not an object")
        except (UnicodeDecodeError, ValueError, KeyError, TypeError) as exc:
            return f"unreadable marker ({type(exc).__name__})"
        present = {p.name for p in entry.iterdir() if p.name != MARKER}
        extra = present - set(files)
        if extra:
            return f"unexpected file(s) {', '.join(sorted(extra))}"
        for name, digest in files.items():
            target = entry / name
            if not target.is_file():
                return f"missing file {name}"
            try:
                actual = file_digest(target)
            except OSError as exc:
                return f"unreadable file {name} ({exc.strerror or exc})"
            if actual != digest:
                return f"digest mismatch in {name}"
        return None

    def drop(self, kind: str, entry: Path, reason: str) -> None:
        """Report a bad entry once (naming its path), delete it and count it."""
        if entry not in self._reported:
            self._reported.add(entry)
            message = f"cache entry {entry} is corrupt ({reason}): dropped, recomputing"
            self.warnings.append(message)
            log.warning(message)
        self.dropped[kind] += 1
        trash = entry.with_name(f".drop.{entry.name}.{os.getpid()}")
        try:
            os.replace(entry, trash)
        except OSError:
            trash = entry
        shutil.rmtree(trash, ignore_errors=True)

    # ------------------------------------------------------------------ reads
    def get(self, kind: str, key: str) -> Path | None:
        """The entry's directory if it exists and verifies (a hit), else None (a miss)."""
        entry = self.path(kind, key)
        if self.enabled and entry.is_dir():
            reason = self.verify(entry)
            if reason is None:
                self.hits[kind] += 1
                return entry
            self.drop(kind, entry, reason)
        self.misses[kind] += 1
        return None

    def load(self, kind: str, key: str, parse: Callable[[Path], T]) -> T | None:
        """``parse(entry)`` of a verified entry, or None (a miss).

        The one place cached payloads are decoded: any exception ``parse`` raises (a
        `CorruptEntry`, a decode error, a missing key) drops the entry and makes it a miss.
        """
        entry = self.get(kind, key)
        if entry is None:
            return None
        try:
            return parse(entry)
        except Exception as exc:  # noqa: BLE001 - anything unparseable is a corrupt entry
            self.hits[kind] -= 1
            self.misses[kind] += 1
            self.drop(kind, entry, f"{type(exc).__name__}: {' '.join(str(exc).split())[:300]}")
            return None

    # ------------------------------------------------------------------ writes
    def put(self, kind: str, key: str, files: dict[str, bytes | str | Path]) -> Path:
        """Store named files atomically with their digests, replacing any existing entry (a
        fresh result always wins: ``run.cache=false`` recomputes and replaces); returns the
        entry directory."""
        entry = self.path(kind, key)
        entry.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{key[:8]}.", dir=entry.parent))
        try:
            digests = {}
            for name, content in files.items():
                if name == MARKER or "/" in name or name.startswith("."):
                    raise ValueError(f"invalid cache file name {name!r}")
                target = tmp / name
                if isinstance(content, Path):
                    shutil.copyfile(content, target)
                elif isinstance(content, str):
                    target.write_bytes(content.encode("utf-8"))
                else:
                    target.write_bytes(content)
                digests[name] = file_digest(target)
            with open(tmp / MARKER, "w") as fh:
                json.dump({"format": FORMAT, "files": digests}, fh, sort_keys=True)
                fh.flush()
                os.fsync(fh.fileno())
            if entry.exists():
                old = entry.with_name(f".old.{entry.name}.{os.getpid()}")
                shutil.rmtree(old, ignore_errors=True)
                try:
                    os.replace(entry, old)
                except FileNotFoundError:
                    pass
                shutil.rmtree(old, ignore_errors=True)
            try:
                os.replace(tmp, entry)
            except OSError:  # a concurrent writer got there first: keep its entry
                if not (entry / MARKER).is_file():
                    raise
                shutil.rmtree(tmp, ignore_errors=True)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        return entry

    def stats(self) -> dict[str, dict[str, int]]:
        kinds = sorted(set(self.hits) | set(self.misses) | set(self.dropped))
        out = {k: {"hits": self.hits[k], "misses": self.misses[k]} for k in kinds}
        for k in kinds:
            if self.dropped[k]:
                out[k]["dropped"] = self.dropped[k]
        return out
