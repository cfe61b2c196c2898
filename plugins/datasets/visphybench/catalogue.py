"""The benchmark's catalogue: which scenes exist, their simulated ground truth, labels and splits.

Building the catalogue simulates every candidate (cheap) but renders nothing (expensive), so a
subset such as ``mini`` can be rendered without rendering the rest, while labels and splits are
still computed over the whole benchmark:

- each (template, variant) draws candidates from ``scene_seed(seed, template, variant, attempt)``
  until one passes the validity filters; rejections are counted by reason;
- difficulty labels come from each rollout's features: scenes are ranked by their difficulty
  score and the paper's counts (114 easy / 67 medium / 28 hard over 209) are assigned in rank
  order, so the label is relative to the benchmark, as human ratings are;
- the ``test`` split takes, per label, the paper's counts (29 / 17 / 3) in a seeded order;
- the ``mini`` split is the first variant of four fixed templates.
"""

from __future__ import annotations

import copy
import hashlib
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Iterable

from visphy_plugins.datasets.visphybench.identifiable import identifiable_params

#: The generator's version: part of every scene id and of the builder version; bump when a
#: change alters any scene (older builds stay loadable by version, `dataset.version`).
GENERATOR_VERSION = 3
PAPER_DIFFICULTY = {"sub": {"easy": 114, "medium": 67, "hard": 28},
                    "test": {"easy": 29, "medium": 17, "hard": 3}}
LABELS = ("easy", "medium", "hard")
MAX_ATTEMPTS = 60
#: (template_id, variant) of the scenes in the ``mini`` split: three 2D combinatorial scenes
#: and one 2D law-probing scene (set in `mini_keys` once the templates are known).
MINI_SIZE = 4


def scene_id(dim: str, template_id: int, variant: int, seed: int,
             version: int = GENERATOR_VERSION) -> str:
    """visphy's own scene id: ``vpb<version>-s<seed>-<dim>-t<template>-v<variant>`` (2D templates
    10001.. are numbered from 1), e.g. ``vpb3-s0-2d-t001-v00``. Never a published VisPhyBench
    id (``taskNNNNN_NNN``, ``NN_tmpl_NN``): those name other scenes."""
    number = template_id - 10000 if dim == "2d" else template_id
    return f"vpb{version}-s{seed}-{dim}-t{number:03d}-v{variant:02d}"


def scene_seed(seed: int, template_id: int, variant: int, attempt: int) -> int:
    """A 63-bit seed that depends on nothing but its four inputs."""
    digest = hashlib.sha256(f"visphybench:{seed}:{template_id}:{variant}:{attempt}".encode())
    return int.from_bytes(digest.digest()[:8], "big") >> 1


@dataclass
class Unit:
    """One (template, variant) slot of the benchmark."""

    dim: str
    template_id: int
    variant: int


@dataclass
class Entry:
    """One accepted scene: its annotated spec, trajectory digest and how it was found."""

    spec: dict
    digest: str
    attempts: int
    rejected: dict[str, int]


@dataclass
class Catalogue:
    seed: int
    entries: list[Entry]
    rejected: dict[str, int] = field(default_factory=dict)
    splits: dict[str, list[str]] = field(default_factory=dict)

    def by_id(self) -> dict[str, Entry]:
        return {e.spec["scene_id"]: e for e in self.entries}


def _templates(dim: str) -> list:
    if dim == "2d":
        from visphy_plugins.datasets.visphybench.templates_2d import TEMPLATES_2D

        return TEMPLATES_2D
    from visphy_plugins.datasets.visphybench.templates_3d import TEMPLATES_3D

    return TEMPLATES_3D


def units() -> list[Unit]:
    """Every (template, variant) slot, 2D first, in template order."""
    out = []
    for dim in ("2d", "3d"):
        for template in _templates(dim):
            out.extend(Unit(dim, template.template_id, v) for v in range(template.n_variants))
    return out


def _simulate(dim: str, spec: dict):
    if dim == "2d":
        from visphy_plugins.physics.box2d import simulate_2d, trajectory_digest

        rollout = simulate_2d(spec)
        return rollout, trajectory_digest(rollout)
    from visphy_plugins.physics.cannon import simulate_3d, trajectory_digest_3d

    rollout = simulate_3d(spec)
    return rollout, trajectory_digest_3d(rollout)


def _validate(dim: str, spec: dict) -> None:
    if dim == "2d":
        from visphy_core.api.spec import validate_spec

        validate_spec(spec)
    else:
        from visphy_core.api.spec import validate_spec_3d

        validate_spec_3d(spec)


def _problems(dim: str, spec: dict, rollout) -> list[str]:
    if dim == "2d":
        from visphy_plugins.datasets.visphybench.filters import validity_problems

        return validity_problems(spec, rollout)
    from visphy_plugins.datasets.visphybench.screening3d import validity_problems_3d

    return validity_problems_3d(spec, rollout)


def _features(dim: str, spec: dict, rollout) -> tuple[dict, float]:
    from visphy_plugins.datasets.visphybench.features import difficulty_score

    if dim == "2d":
        from visphy_plugins.datasets.visphybench.features import difficulty_features

        features = difficulty_features(spec, rollout)
    else:
        from visphy_plugins.datasets.visphybench.screening3d import difficulty_features_3d

        features = difficulty_features_3d(spec, rollout)
    return features, float(difficulty_score(features))


def draw_scene(unit: Unit, seed: int) -> Entry:
    """The first valid candidate of a slot, annotated: events, features, identifiability."""
    import numpy as np

    template = next(t for t in _templates(unit.dim) if t.template_id == unit.template_id)
    rejected: Counter[str] = Counter()
    for attempt in range(MAX_ATTEMPTS):
        s = scene_seed(seed, unit.template_id, unit.variant, attempt)
        spec = template.make(np.random.default_rng(s), unit.variant)
        spec["scene_id"] = scene_id(unit.dim, unit.template_id, unit.variant, seed)
        spec["seed"] = s
        spec.setdefault("family", template.family)
        _validate(unit.dim, spec)
        rollout, digest = _simulate(unit.dim, spec)
        problems = _problems(unit.dim, spec, rollout)
        if problems:
            rejected.update(problems)
            continue
        spec = copy.deepcopy(spec)
        features, score = _features(unit.dim, spec, rollout)
        spec["difficulty"] = {"label": None, "score": score, "features": features}
        gt = spec.setdefault("ground_truth", {})
        gt["events"] = rollout.events
        gt["identifiable"] = identifiable_params(spec, rollout)
        spec["digest_sha256"] = digest
        return Entry(spec=spec, digest=digest, attempts=attempt + 1, rejected=dict(rejected))
    raise RuntimeError(f"template {unit.template_id} variant {unit.variant}: no valid candidate "
                       f"in {MAX_ATTEMPTS} attempts (rejected: {dict(rejected)})")


def _draw(args: tuple[Unit, int]) -> Entry:
    return draw_scene(*args)


def assign_labels(entries: list[Entry]) -> None:
    """Rank by difficulty score (ties by scene id) and cut at the paper's proportions."""
    n = len(entries)
    paper = PAPER_DIFFICULTY["sub"]
    total = sum(paper.values())
    n_easy = round(n * paper["easy"] / total)
    n_medium = round(n * paper["medium"] / total)
    ranked = sorted(entries, key=lambda e: (e.spec["difficulty"]["score"], e.spec["scene_id"]))
    for rank, entry in enumerate(ranked):
        label = "easy" if rank < n_easy else "medium" if rank < n_easy + n_medium else "hard"
        entry.spec["difficulty"]["label"] = label


def assign_splits(entries: list[Entry], seed: int) -> dict[str, list[str]]:
    """``sub`` = every scene; ``test`` = per label the paper's count in a seeded order;
    ``mini`` = the first variant of the first three 2D combinatorial and first 2D law template."""
    ids = [e.spec["scene_id"] for e in entries]
    n = len(entries)
    test: list[str] = []
    paper_sub = sum(PAPER_DIFFICULTY["sub"].values())
    for label in LABELS:
        pool = [e.spec["scene_id"] for e in entries if e.spec["difficulty"]["label"] == label]
        want = round(PAPER_DIFFICULTY["test"][label] * n / paper_sub)
        pool.sort(key=lambda sid: hashlib.sha256(f"test:{seed}:{sid}".encode()).hexdigest())
        test.extend(pool[:want])
    mini = mini_ids(entries)
    splits = {"sub": ids, "test": sorted(test, key=ids.index), "mini": mini}
    for entry in entries:
        sid = entry.spec["scene_id"]
        entry.spec["splits"] = [name for name, members in splits.items() if sid in members]
    return splits


def mini_ids(entries: Iterable[Entry]) -> list[str]:
    first = [e for e in entries if e.spec["dim"] == "2d" and e.spec.get("variant", 0) == 0]
    combinatorial = [e for e in first if e.spec.get("family") == "combinatorial"][:3]
    law = [e for e in first if e.spec.get("family") == "law"][:1]
    return [e.spec["scene_id"] for e in combinatorial + law][:MINI_SIZE]


def build_catalogue(seed: int = 0, workers: int = 2, progress: bool = True,
                    only: list[Unit] | None = None) -> Catalogue:
    """Draw, simulate and annotate every scene (in parallel), then label and split."""
    todo = only if only is not None else units()
    args = [(u, seed) for u in todo]
    if workers > 1 and len(args) > 1:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            results: Iterable[Any] = pool.map(_draw, args, chunksize=2)
            entries = list(_track(results, len(args), "simulating scenes", progress))
    else:
        entries = list(_track(map(_draw, args), len(args), "simulating scenes", progress))
    rejected: Counter[str] = Counter()
    for e in entries:
        rejected.update(e.rejected)
    catalogue = Catalogue(seed=seed, entries=entries, rejected=dict(sorted(rejected.items())))
    assign_labels(entries)
    catalogue.splits = assign_splits(entries, seed)
    return catalogue


def _track(iterable: Iterable, total: int, description: str, progress: bool) -> Iterable:
    """A bar on a terminal, paced plain lines in a log (`visphy_core.api.progress.track`)."""
    from visphy_core.api.progress import track

    return track(iterable, total=total, description=description, enabled=progress)
