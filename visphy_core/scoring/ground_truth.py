"""A scene's ground-truth artefacts, computed once and kept with the data: the twin's render and
the anchors of variance normalisation and of the headline.

Normalising a scene (`visphy_core.scoring.normalisation`) needs two clips that depend on the scene
and the engine only, never on the model: the **twin** (the ground truth re-simulated after an
imperceptible nudge, replayed by the engine's reference program) and the **frozen clip** (the
first key frame held). Their scores against the ground truth — the ceiling and the floor of
every frame and sequence metric — are the same for every model and every run. They are
computed once per (scene, engine, metric) and stored in the **ground-truth store**
(``paths.ground_truth_dir``, default ``<data_dir>/ground_truth``): at build time by
``python -m visphy_core ground-truth [overrides]``, or on first use by a run (which then writes
them there, so every later run of any model reuses them, whatever its cache).

Every entry is content-addressed, like the run cache (`visphy_core.infra.cache`), by what determines
it and nothing else:

* an anchor by the reference clip's content, the scored clip's identity and the metric's
  identity (`Metric.identity`: class, version, weights, ``max_pairs``) under the unaligned
  pairing;
* the twin's identity is its render key — the engine's identity, the twin program's digest
  (which holds the twin's re-simulated trajectory) and the clip contract — since renders are
  deterministic (the render cache rests on the same fact); the frozen clip's identity is the
  key frame's content, the contract and the video codec's settings and version.

So an entry computed at build time is the entry a run would compute (tests/test_ground_truth.py
checks both ways give the same anchors), a different engine, contract, metric version or
codec is a different entry, and a stale one is never served. Entries carry SHA-256 digests
and are verified on every read (`Cache.get`).
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from visphy_core.api.metrics import SCENE, Metric
from visphy_core.infra.cache import Cache, CorruptEntry, content_key, read_json

if TYPE_CHECKING:
    from visphy_core.api.engine import RenderContract
    from visphy_core.api.scene import Scene
    from visphy_core.scoring.reference_clips import ReferenceClips

log = logging.getLogger("visphy.ground_truth")

#: The anchors' definition (bumped when what an anchor means changes).
VERSION = "anchors/1"
#: The store's folder under ``paths.data_dir`` when ``paths.ground_truth_dir`` is not set.
STORE_DIR = "ground_truth"
FLOOR, CEILING = "floor", "ceiling"


def open_store(path: str | Path | None, enabled: bool = True) -> Cache | None:
    """The ground-truth store at ``path`` (created when missing), or None when ``path`` is
    None/empty (no store: anchors go to the run cache only). A store that cannot be created is
    None too, with one warning."""
    if path is None or str(path).strip() in ("", "None", "null"):
        return None
    root = Path(path)
    try:
        root.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        log.warning("ground-truth store %s cannot be created (%s): anchors are kept in the "
                    "run cache only", root, exc.strerror or exc)
        return None
    return Cache(root, enabled=enabled)


def store_path(cfg, data_dir: str | Path) -> Path | None:
    """``paths.ground_truth_dir`` of a run config (``<data_dir>/ground_truth`` for a config
    written before the setting existed; None when set to null)."""
    from omegaconf import OmegaConf

    paths = OmegaConf.select(cfg, "paths")
    if paths is None or "ground_truth_dir" not in paths:
        return Path(data_dir).resolve() / STORE_DIR
    value = OmegaConf.select(cfg, "paths.ground_truth_dir", default=None)
    return None if value in (None, "") else Path(str(value)).resolve()


def writable(store: Cache | None) -> bool:
    """Whether entries can be added to ``store`` (its folder is made when missing)."""
    if store is None:
        return False
    try:
        store.root.mkdir(parents=True, exist_ok=True)
    except OSError:
        return False
    return os.access(store.root, os.W_OK | os.X_OK)


def frozen_identity(scene: "Scene", contract: "RenderContract") -> str:
    """What makes the frozen clip: the first key frame's pixels, the contract, the codec."""
    import av

    from visphy_core.infra.video import H264_OPTIONS

    frame = np.ascontiguousarray(scene.key_frame(1))
    return content_key("frozen/1", hashlib.sha256(frame.tobytes()).hexdigest(),
                       list(frame.shape), contract.key(), H264_OPTIONS, av.__version__)


def anchor_key(which: str, clip_identity: str, reference_digest: str, metric: Metric) -> str:
    return content_key(VERSION, which, clip_identity, reference_digest,
                       (metric.name, metric.version, metric.identity()), "pairing:unaligned")


@dataclass
class Anchors:
    """Each metric's floor (frozen clip) and ceiling (twin) on one scene; why any is missing."""

    floor: dict[str, float | None] = field(default_factory=dict)
    ceiling: dict[str, float | None] = field(default_factory=dict)
    why_floor: dict[str, str] = field(default_factory=dict)
    why_ceiling: dict[str, str] = field(default_factory=dict)
    computed: int = 0           # values scored now (the rest came from a store or the cache)
    twin_key: str | None = None


class _Values:
    """Anchor values read from / written to the ground-truth store, else the run cache."""

    def __init__(self, store: Cache | None, cache: Cache):
        self.read = [c for c in (store, cache) if c is not None]
        self.write = store if writable(store) else cache

    def get(self, key: str) -> dict | None:
        for c in self.read:  # an unparseable entry is dropped and missed (`Cache.load`)
            value = c.load("anchor", key, _parse)
            if value is not None:
                return value
        return None

    def put(self, key: str, value: float | None, why: str | None) -> None:
        self.write.put("anchor", key, {"value.json": json.dumps({"value": value, "why": why})})


def _parse(entry: Path) -> dict:
    value = read_json(entry / "value.json")
    if not isinstance(value, dict) or "value" not in value:
        raise CorruptEntry(f"{entry / 'value.json'}: no value")
    return value


def scene_anchors(scene: "Scene", reference: np.ndarray, metrics: list[Metric],
                  clips: "ReferenceClips", contract: "RenderContract", cache: Cache,
                  store: Cache | None, scene_dir: Path | None, *, ceiling: bool = True,
                  frozen: np.ndarray | None = None) -> Anchors:
    """Every frame/sequence metric's floor (and, with ``ceiling``, its ceiling) on ``scene``:
    read from the store (or the run cache) where present, else scored now and stored.

    The twin is rendered (or read back) only when a ceiling is missing; with a ``scene_dir`` it
    gets ``twin_video.mp4`` either way (a copy of the stored render when every ceiling was
    found: no decoding), so a run directory keeps what re-scoring needs. Raises
    `ReferenceClipUnavailable` when a ceiling is needed and the twin cannot be had.
    ``frozen``: the frozen clip when the caller already has it (a scene that fell back)."""
    from visphy_core.scoring.reference_clips import frozen_frames
    from visphy_core.scoring.score import ScoringProtocol, clip_digest, score_scene

    out = Anchors()
    frame_metrics = [m for m in metrics if m.kind != SCENE]
    metrics = []
    for m in frame_metrics:
        reason = m.unavailable_reason()
        if reason:  # never stored: it may be available on the next run
            out.floor[m.name] = out.ceiling[m.name] = None
            out.why_floor[m.name] = out.why_ceiling[m.name] = reason
        else:
            metrics.append(m)
    ref = clip_digest(reference)
    values = _Values(store, cache)
    plain = ScoringProtocol(unaligned=True, aligned=False, paper=False)

    def lookup(which: str, identity: str, got: dict, why: dict) -> list[Metric]:
        todo = []
        for m in metrics:
            value = values.get(anchor_key(which, identity, ref, m))
            if value is None:
                todo.append(m)
                continue
            got[m.name] = value["value"]
            if value.get("why"):
                why[m.name] = value["why"]
        return todo

    def score(which: str, identity: str, frames: np.ndarray, todo: list[Metric], got: dict,
              why: dict) -> None:
        scores, reasons = score_scene(scene, reference, frames, todo, None, None, cache,
                                      protocol=plain)
        for m in todo:
            value = scores.get(m.name)
            value = value if value is not None and math.isfinite(value) else None
            got[m.name] = value
            if reasons.get(m.name):
                why[m.name] = reasons[m.name]
            values.put(anchor_key(which, identity, ref, m), value, reasons.get(m.name))
            out.computed += 1

    identity = frozen_identity(scene, contract)
    todo = lookup(FLOOR, identity, out.floor, out.why_floor)
    if todo:
        frames = frozen if frozen is not None else frozen_frames(scene, contract)
        score(FLOOR, identity, frames, todo, out.floor, out.why_floor)
    if not ceiling:
        return out
    out.twin_key = clips.twin_identity(scene, contract)
    twin = None
    if out.twin_key is None:  # a twin known by its content only (read back from a run dir)
        twin = clips.twin(scene, contract, scene_dir)
        out.twin_key = "clip:" + clip_digest(twin)
    todo = lookup(CEILING, out.twin_key, out.ceiling, out.why_ceiling)
    if todo and twin is None:
        twin = clips.twin(scene, contract, scene_dir)
    elif not todo and twin is None and scene_dir is not None:
        clips.copy_twin(scene, contract, scene_dir)
    if todo:
        score(CEILING, out.twin_key, twin, todo, out.ceiling, out.why_ceiling)
    return out
