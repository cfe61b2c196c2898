"""Content-addressed store for model replies, renders and scores.

A key is the SHA-256 of everything that determines a stage's output (inputs + plugin identity and
version). Entries are written to a temp dir and renamed into place, so a crash never leaves a half
entry, and an interrupted run resumes exactly where it stopped.

Integrity: the ``.complete`` marker of an entry holds the SHA-256 of every payload file
(``{"format": 1, "files": {name: digest}}``). Every read verifies them; an entry whose digests do
not match, that misses a file, that predates digests, or whose payload does not parse (see
`Cache.load`) is reported once as a warning naming its path, deleted and treated as a miss, so the
stage recomputes it. A corrupt entry is never served.

Sharing: any number of processes may use one cache (runs and studies sharing a home). Readers
take no lock. Whatever changes the name of an entry — `Cache.put` swapping a new entry in,
`Cache.drop` taking a bad one out — holds the ``flock`` of its bucket, ``<root>/<kind>/<ab>.lock``
(beside the ``<ab>`` folder, so the folder holds entries only). A drop re-verifies (and, for
`Cache.load`, re-parses) under the lock and keeps an entry that passes: a reader whose view
straddled a concurrent swap never deletes the good entry another process just wrote. One lock per
bucket, not per entry: at most 256 lock files per kind however large the cache grows (a lock
file cannot be deleted safely while others may wait on it, so per-entry locks would stay behind,
one per entry ever dropped), and the lock is held only for renames (payloads are written and
hashed before it is taken), so unrelated keys of one bucket wait on each other for microseconds.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import secrets
import shutil
import tempfile
from collections import Counter
from contextlib import AbstractContextManager
from pathlib import Path
from typing import Any, Callable, TypeVar

from visphy_core.infra import files as files_mod
from visphy_core.infra.locks import exclusive

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
        try:  # a concurrent writer's swap may move the entry away while it is read
            present = {p.name for p in entry.iterdir() if p.name != MARKER}
        except OSError as exc:
            return f"unreadable entry ({exc.strerror or exc})"
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

    def drop(self, kind: str, entry: Path, reason: str) -> bool:
        """Delete a bad entry, report it once (naming its path) and count it; False when it was
        kept instead: under the bucket's lock it verifies (a concurrent writer replaced it
        after the caller judged it, or the caller's reads straddled that writer's swap)."""
        return self._drop(kind, entry, reason, lambda e: self.verify(e) is None)

    def _drop(self, kind: str, entry: Path, reason: str, good: Callable[[Path], bool]) -> bool:
        """`drop`, keeping the entry when ``good(entry)`` holds under the lock (where no writer
        can change it); True when it was dropped, or was gone already."""
        with self._bucket_lock(entry):
            if good(entry):
                return False
            trash = self._move_aside(entry, "drop")
        if trash is None:  # gone already: whoever removed it has reported it
            return True
        if entry not in self._reported:
            self._reported.add(entry)
            message = f"cache entry {entry} is corrupt ({reason}): dropped, recomputing"
            self.warnings.append(message)
            log.warning(message)
        self.dropped[kind] += 1
        _remove(trash)
        return True

    # ------------------------------------------------------------------ reads
    def get(self, kind: str, key: str) -> Path | None:
        """The entry's directory if it exists and verifies (a hit), else None (a miss)."""
        entry = self.path(kind, key)
        if self.enabled and entry.is_dir():
            reason = self.verify(entry)
            if reason is None or not self.drop(kind, entry, reason):
                self.hits[kind] += 1
                return entry
        self.misses[kind] += 1
        return None

    def load(self, kind: str, key: str, parse: Callable[[Path], T]) -> T | None:
        """``parse(entry)`` of a verified entry, or None (a miss).

        The one place cached payloads are decoded: any exception ``parse`` raises (a
        `CorruptEntry`, a decode error, a missing key) drops the entry and makes it a miss —
        unless, under the bucket's lock, the entry verifies and parses: its first reading met a
        concurrent writer's swap, and what that reading returns under the lock is served.
        """
        entry = self.get(kind, key)
        if entry is None:
            return None
        try:
            return parse(entry)
        except Exception as exc:  # noqa: BLE001 - anything unparseable is a corrupt entry
            reason = f"{type(exc).__name__}: {' '.join(str(exc).split())[:300]}"
        parsed: list[T] = []

        def good(path: Path) -> bool:
            if self.verify(path) is not None:
                return False
            try:
                parsed.append(parse(path))
            except Exception:  # noqa: BLE001 - still unparseable: corrupt
                return False
            return True

        if not self._drop(kind, entry, reason, good):
            return parsed[0]
        self.hits[kind] -= 1
        self.misses[kind] += 1
        return None

    # ------------------------------------------------------------------ writes
    def put(self, kind: str, key: str, files: dict[str, bytes | str | Path]) -> Path:
        """Store named files atomically with their digests, replacing any existing entry (a
        fresh result always wins: ``run.cache=false`` recomputes and replaces); returns the
        entry directory. The payload is written and hashed in a temporary folder; only the
        swap (old entry aside, new one in) holds the bucket's lock, so concurrent writers of
        one key end with one whole entry, the last one's."""
        entry = self.path(kind, key)
        entry.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{key[:8]}.", dir=entry.parent))
        try:
            self._fill(tmp, files)
            with self._bucket_lock(entry):
                old = self._move_aside(entry, "old")
                try:
                    os.replace(tmp, entry)
                except BaseException:
                    if old is not None:  # put the previous entry back
                        os.replace(old, entry)
                    raise
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        _remove(old)
        return entry

    @staticmethod
    def _fill(tmp: Path, files: dict[str, bytes | str | Path]) -> None:
        """Write the payload files into ``tmp``, then the marker with their digests. Nothing is
        fsynced: every read verifies the digests (`verify`), so an entry torn by a power cut is
        dropped and computed again, never served (an fsync per entry cost 8 % of the
        ground-truth stage, which writes one small entry per anchor)."""
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

    @staticmethod
    def _move_aside(entry: Path, why: str) -> Path | None:
        """Rename whatever is at ``entry`` to an unused hidden name in its bucket, for the
        caller to delete outside the lock; None when nothing is there. Caller holds the lock."""
        if not os.path.lexists(entry):
            return None
        aside = entry.with_name(f".{why}.{entry.name[:8]}.{os.getpid()}.{secrets.token_hex(6)}")
        os.replace(entry, aside)
        return aside

    @staticmethod
    def _bucket_lock(entry: Path) -> AbstractContextManager[None]:
        """The lock of ``entry``'s bucket: ``<root>/<kind>/<ab>.lock``."""
        bucket = entry.parent
        return exclusive(bucket.with_name(f"{bucket.name}.lock"), f"the cache folder {bucket}")

    def stats(self) -> dict[str, dict[str, int]]:
        kinds = sorted(set(self.hits) | set(self.misses) | set(self.dropped))
        out = {k: {"hits": self.hits[k], "misses": self.misses[k]} for k in kinds}
        for k in kinds:
            if self.dropped[k]:
                out[k]["dropped"] = self.dropped[k]
        return out


def _remove(path: Path | None) -> None:
    """Delete a moved-aside entry: a folder's tree, or the file or link planted in its place."""
    if path is None:
        return
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)
