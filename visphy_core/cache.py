"""Content-addressed store for model replies, renders and scores.

A key is the SHA-256 of everything that determines a stage's output (inputs + plugin identity and
version). Entries are written to a temp dir and renamed into place, so a crash never leaves a half
entry, and an interrupted run resumes exactly where it stopped.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
from collections import Counter
from pathlib import Path
from typing import Any


def content_key(*parts: Any) -> str:
    """Stable hash of JSON-serialisable parts (strings are hashed as-is)."""
    h = hashlib.sha256()
    for part in parts:
        data = part if isinstance(part, str) else json.dumps(part, sort_keys=True, default=str)
        h.update(hashlib.sha256(data.encode()).digest())
    return h.hexdigest()


class Cache:
    """``<root>/<kind>/<ab>/<key>/`` directories holding one stage result each.

    ``enabled=False`` (``run.cache=false``) makes every lookup a miss, so everything is recomputed;
    results are still stored, which the stages read back.
    """

    def __init__(self, root: str | Path, enabled: bool = True):
        self.root = Path(root)
        self.enabled = enabled
        self.hits: Counter[str] = Counter()
        self.misses: Counter[str] = Counter()

    def path(self, kind: str, key: str) -> Path:
        return self.root / kind / key[:2] / key

    def get(self, kind: str, key: str) -> Path | None:
        """The entry's directory if it exists (counted as a hit), else None (a miss)."""
        entry = self.path(kind, key)
        if self.enabled and (entry / ".complete").is_file():
            self.hits[kind] += 1
            return entry
        self.misses[kind] += 1
        return None

    def put(self, kind: str, key: str, files: dict[str, bytes | str | Path]) -> Path:
        """Store named files atomically; returns the entry directory."""
        entry = self.path(kind, key)  # written even when reads are disabled: one code path
        entry.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{key[:8]}.", dir=entry.parent))
        try:
            for name, content in files.items():
                target = tmp / name
                if isinstance(content, Path):
                    shutil.copyfile(content, target)
                elif isinstance(content, str):
                    target.write_text(content)
                else:
                    target.write_bytes(content)
            (tmp / ".complete").write_text("")
            if entry.exists():  # a concurrent writer won: keep its identical entry
                shutil.rmtree(tmp)
            else:
                os.replace(tmp, entry)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        return entry

    def stats(self) -> dict[str, dict[str, int]]:
        kinds = sorted(set(self.hits) | set(self.misses))
        return {k: {"hits": self.hits[k], "misses": self.misses[k]} for k in kinds}
