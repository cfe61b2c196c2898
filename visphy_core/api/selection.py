"""Which scenes of a split a run takes: ``dataset.scenes``, then ``dataset.limit``, then
``dataset.shard`` (`select_scenes`).

The core applies the selection to what a dataset plugin's ``load`` returns. A plugin that can
list its scenes before building them (the generated benchmark, whose catalogue knows every
scene's template, dimension and difficulty before any clip is rendered) applies it itself to
that listing, builds only what it chose, and sets `visphy_core.api.dataset.Dataset.selects`.

``dataset.limit=N`` takes N scenes spread over the split (`spread`), not the split's first N:
a split lists a template's variants together, so its first N scenes are often N variants of one
template. The rule, deterministic and the same for every dataset:

1. **2D / 3D** in proportion to the split: each pick goes to the dimension furthest below its
   share of the picks so far (share × picks − picked), ties to the one whose next scene comes
   first in the split;
2. **difficulty**, within that dimension, the same way (a scene without a label is its own
   group);
3. **template**, within that group: the scene, in split order, whose template has been picked
   the fewest times so far, so N scenes come from N templates while the group has templates
   left (a scene without a template is a template of its own).

The N scenes are returned in split order, so the rule is idempotent (N scenes limited to N are
themselves) and shards still split the limited selection. A split whose scenes are each of their
own template and whose difficulties come in proportion along it (``mini``: easy, easy, medium,
easy) keeps its own order: ``dataset=mini dataset.limit=2`` is its first two scenes.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from typing import Any, Callable, Sequence, TypeVar

from visphy_core.api.settings import cfg_get
from visphy_core.infra.shard import parse_shard, select_shard

T = TypeVar("T")


@dataclass(frozen=True)
class Traits:
    """What the selection knows of a scene."""

    scene_id: str
    dim: str | None = None
    difficulty: str | None = None
    template: str | None = None


def scene_traits(scene: Any) -> Traits:
    """The traits of a `visphy_core.api.scene.Scene`."""
    template = getattr(scene, "template_id", None)
    return Traits(scene_id=str(scene.scene_id), dim=getattr(scene, "dim", None),
                  difficulty=getattr(scene, "difficulty", None),
                  template=None if template is None else str(template))


def spread(items: Sequence[T], n: int, traits: Callable[[T], Traits]) -> list[T]:
    """``n`` of ``items`` (a split, in its order) spread over dimension, difficulty and
    template (the rule in this module's docstring), in the items' order."""
    if n >= len(items):
        return list(items)
    infos = [traits(item) for item in items]
    # dimension -> difficulty -> positions still free, in split order
    groups: dict[Any, dict[Any, list[int]]] = {}
    for pos, info in enumerate(infos):
        groups.setdefault(info.dim, {}).setdefault(info.difficulty, []).append(pos)
    size = {dim: sum(len(p) for p in by.values()) for dim, by in groups.items()}
    sizes = {(dim, d): len(p) for dim, by in groups.items() for d, p in by.items()}
    template = [("template", i.dim, i.template) if i.template is not None
                else ("scene", i.scene_id) for i in infos]
    picked_dim: Counter = Counter()
    picked_group: Counter = Counter()
    used: Counter = Counter()
    chosen: list[int] = []
    for k in range(n):
        # each deficit is share × picks − picked, scaled by the share's denominator
        dim = max((d for d, by in groups.items() if any(by.values())),
                  key=lambda d: (size[d] * (k + 1) - picked_dim[d] * len(items),
                                 -min(p[0] for p in groups[d].values() if p)))
        m = picked_dim[dim]
        label = max((d for d, p in groups[dim].items() if p),
                    key=lambda d: (sizes[dim, d] * (m + 1) - picked_group[dim, d] * size[dim],
                                   -groups[dim][d][0]))
        free = groups[dim][label]
        pos = min(free, key=lambda p: (used[template[p]], p))
        free.remove(pos)
        chosen.append(pos)
        picked_dim[dim] += 1
        picked_group[dim, label] += 1
        used[template[pos]] += 1
    return [items[pos] for pos in sorted(chosen)]


def select_scenes(items: Sequence[T], traits: Callable[[T], Traits], *,
                  scenes: Sequence[str] | None = None, limit: int | None = None,
                  shard: str | None = None, name: str = "", split: str | None = None) -> list[T]:
    """``items`` (a split, in its order) narrowed to the scenes named, then ``limit`` of them
    (`spread`), then shard ``"i/n"`` of those. ``ValueError`` (one line) for a named scene the
    split does not have and for an empty selection."""
    selected = list(items)
    if scenes:
        have = {traits(item).scene_id for item in selected}
        missing = sorted(set(scenes) - have)
        if missing:
            raise ValueError(f"dataset {name!r} has no scene(s) {', '.join(missing)}")
        wanted = set(scenes)
        selected = [item for item in selected if traits(item).scene_id in wanted]
    if limit is not None:
        selected = spread(selected, int(limit), traits)
    part = parse_shard(shard)
    if part is not None:  # after the limit: the shards together are the unsharded selection
        selected = select_shard(selected, *part)
    if not selected:
        raise ValueError(f"dataset {name!r} selected no scenes (split={split!r}"
                         f"{f', shard={shard}' if part else ''})")
    return selected


def select_for(cfg: Any, items: Sequence[T], traits: Callable[[T], Traits]) -> list[T]:
    """`select_scenes` with the ``dataset`` config node's ``scenes``, ``limit`` and ``shard``."""
    scenes = cfg_get(cfg, "scenes", None)
    limit = cfg_get(cfg, "limit", None)
    return select_scenes(items, traits, scenes=[str(s) for s in scenes] if scenes else None,
                         limit=None if limit is None else int(limit),
                         shard=cfg_get(cfg, "shard", None), name=cfg_get(cfg, "name", ""),
                         split=cfg_get(cfg, "split", None))
