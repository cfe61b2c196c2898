"""``dataset.shard="i/n"``: one of n disjoint parts of a run's scenes, so that one large run can
be split across machines and merged back (``python -m visphy_core merge``).

Shard i (0-based) takes every n-th scene of the selection starting at position i, after the
dataset's own order and ``dataset.limit``: the n shards are disjoint, together they are exactly
the unsharded selection, their sizes differ by at most one, and each mixes the whole dataset's
templates and difficulties. Interleaving the shards' scenes back (shard 0's first scene, shard
1's first, …) gives the unsharded order, which is how `visphy_core.execute.merge` orders a merged
run.
"""

from __future__ import annotations

import re
from typing import Sequence, TypeVar

from visphy_core.infra.errors import ConfigError

T = TypeVar("T")

_FORM = re.compile(r"^\s*(\d+)\s*/\s*(\d+)\s*$")


def parse_shard(text: str | None) -> tuple[int, int] | None:
    """``"i/n"`` → (i, n), None for no sharding; `ConfigError` with one line otherwise."""
    if text is None or str(text).strip() == "":
        return None
    match = _FORM.match(str(text))
    if not match:
        raise ConfigError(f"dataset.shard={text!r} is not of the form i/n (e.g. 0/4: the first "
                          "of 4 shards)")
    index, count = int(match.group(1)), int(match.group(2))
    if count < 1:
        raise ConfigError(f"dataset.shard={text}: the number of shards must be at least 1")
    if index >= count:
        raise ConfigError(f"dataset.shard={text}: shard indices are 0-based, 0/{count} … "
                          f"{count - 1}/{count}")
    return index, count


def select_shard(items: Sequence[T], index: int, count: int) -> list[T]:
    """Shard ``index`` of ``count`` of ``items``: positions index, index + count, …"""
    return list(items[index::count])


def interleave(shards: Sequence[Sequence[T]]) -> list[T]:
    """The inverse of `select_shard` over shards 0 … n-1 given in order: the original order."""
    out: list[T] = []
    longest = max((len(s) for s in shards), default=0)
    for position in range(longest):
        out.extend(shard[position] for shard in shards if position < len(shard))
    return out
