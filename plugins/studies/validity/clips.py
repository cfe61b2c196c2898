"""The validity ordering's clips and records (issues 21, 32).

A scene's ground truth X (`Truth`: its spec, poses and raw frames, drawn by a `Renderer`:
Box2D and the ground-truth rasteriser in 2D, cannon-es and the three.js replay page in 3D) is
what every variant is made from. The kinds of clip the study scores against it:

* ``right`` (i): the physics of X drawn differently (`restyles`);
* ``wrong`` (ii): the physics changed and re-simulated (`interventions`);
* ``static`` (iii) and ``flow`` (iv): the two baselines (`study`);
* ``truth``: X itself, and ``dose``: a dose series' clip (`dose`).

Here: the kinds, the renderers, `Truth`, the clip record (`Clip`), `ClipCache` (rendered clips
kept on disk), `made` (a variant's clip, or why it does not apply: `NotApplicable`) and the
scored records a study returns and a checkpoint holds (`ClipScore`, `SceneOrder`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path
from typing import Callable, Protocol

import numpy as np

RIGHT, WRONG, STATIC, FLOW = "right", "wrong", "static", "flow"
TRUTH, DOSE = "truth", "dose"  # the truth clip itself (`SceneOrder.truth`); a dose series' clip
KINDS = {RIGHT: "(i) physics right, drawn differently", WRONG: "(ii) physics wrong",
         STATIC: "(iii) static", FLOW: "(iv) flow_extrapolate"}


# ------------------------------------------------------------------------------ rendering
class Renderer(Protocol):
    """Simulates a spec and draws poses the way the scene's ground truth is made."""

    def simulate(self, spec: dict) -> np.ndarray:
        """Per-frame poses (frames × bodies × 3 in 2D / 7 in 3D), bodies in the spec's order."""

    def draw(self, spec: dict, poses: np.ndarray) -> np.ndarray:
        """The clip (frames × H × W × 3, uint8) of ``spec``'s bodies at ``poses``."""


class Renderer2D:
    """Box2D and the ground-truth rasteriser (`raster2d.render_clip_2d`)."""

    def simulate(self, spec: dict) -> np.ndarray:
        return np.asarray(self.rollout(spec).frame_poses, dtype=np.float64)

    def rollout(self, spec: dict):
        """The engine's whole rollout (``step_poses``, ``frame_steps``: every 1/60 s step)."""
        from visphy_plugins.physics.box2d import simulate_2d

        return simulate_2d(spec)

    def draw(self, spec: dict, poses: np.ndarray) -> np.ndarray:
        from visphy_plugins.datasets.visphybench.raster2d import render_clip_2d

        return render_clip_2d(spec, poses)


class Renderer3D:
    """cannon-es and the three.js replay page in Chromium (`render3d.render_clip_3d`)."""

    def __init__(self, pool):
        self.pool = pool

    def simulate(self, spec: dict) -> np.ndarray:
        return np.asarray(self.rollout(spec).frame_poses, dtype=np.float64)

    def rollout(self, spec: dict):
        """The engine's whole rollout (``step_poses``, ``frame_steps``)."""
        from visphy_plugins.physics.cannon import simulate_3d

        return simulate_3d(spec)

    def draw(self, spec: dict, poses: np.ndarray) -> np.ndarray:
        from visphy_plugins.datasets.visphybench.render3d import render_clip_3d

        return render_clip_3d(spec, poses, self.pool)


@dataclasses.dataclass
class Truth:
    """A scene's ground truth: its spec, per-frame poses and frames, and how it was made;
    ``steps``: the rollout's every step (``step_poses``, ``frame_steps``) where the renderer
    keeps them (the playback-speed dose series reads them)."""

    spec: dict
    poses: np.ndarray
    frames: np.ndarray
    renderer: Renderer
    steps: tuple[np.ndarray, np.ndarray] | None = None

    @classmethod
    def of(cls, spec: dict, renderer: Renderer, cache: "ClipCache | None" = None) -> "Truth":
        if cache is not None:
            hit = cache.truth(spec, renderer)
            if hit is not None:
                return hit
        steps = None
        if hasattr(renderer, "rollout"):
            rollout = renderer.rollout(spec)
            poses = np.asarray(rollout.frame_poses, dtype=np.float64)
            steps = (np.asarray(rollout.step_poses, dtype=np.float64),
                     np.asarray(rollout.frame_steps, dtype=np.int64))
        else:
            poses = renderer.simulate(spec)
        truth = cls(spec, poses, renderer.draw(spec, poses), renderer, steps)
        if cache is not None:
            cache.put_truth(truth)
        return truth

    @property
    def dim(self) -> str:
        return self.spec["dim"]

    def rollout(self, spec: dict) -> np.ndarray:
        """``spec`` simulated and drawn like the truth."""
        return self.renderer.draw(spec, self.renderer.simulate(spec))


class NotApplicable(Exception):
    """Raised by a variant that does not apply to a scene (its message says why: the variant
    goes into the scene's ``skipped``)."""


# ---------------------------------------------------------------------------- the clips
@dataclasses.dataclass
class Clip:
    name: str
    kind: str
    what: str
    frames: np.ndarray
    changed: float | None = None  # share of the truth's pixels it changes (over the clip)
    deviation: float | None = None  # (ii), dose: `deviation` (px)
    missing: list[str] | None = None  # (ii): bodies of the truth the clip does not draw
    series: str | None = None  # dose: its series (`dose.SERIES`)
    dose: float | None = None  # dose: how far from the truth, in the series' own unit
    missing_px: float | None = None  # (ii): how far the missing bodies move in the truth (px)


#: what a cached clip must record besides its frames (`ClipCache.get`)
_RECORDED = frozenset(f.name for f in dataclasses.fields(Clip)) - {"frames"}


def changed_share(frames: np.ndarray, truth: np.ndarray) -> float:
    return float(np.any(frames != truth, axis=-1).mean()) if frames.shape == truth.shape \
        else 1.0


class ClipCache:
    """Rendered clips kept on disk (``--clips-cache DIR``) so that scoring the same clips
    again (other metrics, another headline) skips simulating and drawing them: one compressed
    ``.npz`` per (scene, spec, kind, variant) under ``DIR/<scene_id>/`` holding the frames and
    what the `Clip` records (a variant that does not apply: its reason, no frames); the truth
    keeps its poses and steps too, and the twin's clip is kept (kind ``twin``). Keyed by the
    spec's digest, not by the variants' code: empty the folder when a variant's definition
    changes."""

    def __init__(self, root: Path | str):
        self.root = Path(root)

    @staticmethod
    def digest(spec: dict) -> str:
        return hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()[:12]

    def path(self, spec: dict, kind: str, name: str) -> Path:
        safe = "".join(ch if ch.isalnum() or ch in "+-._" else "_" for ch in name)
        return self.root / spec["scene_id"] / f"{self.digest(spec)}-{kind}-{safe}.npz"

    def get(self, spec: dict, kind: str, name: str) -> "Clip | str | None":
        """The cached clip, the reason it was skipped, or None (not cached)."""
        path = self.path(spec, kind, name)
        if not path.is_file():
            return None
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            if meta.get("skipped") is not None:
                return str(meta["skipped"])
            if not _RECORDED <= meta.keys():  # written before a field was recorded: make it
                return None                   # again, so every clip records the same
            return Clip(frames=z["frames"], **meta)

    def put(self, spec: dict, kind: str, name: str, clip: "Clip | str") -> None:
        path = self.path(spec, kind, name)
        path.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(clip, str):
            arrays = {"meta": np.array(json.dumps({"skipped": clip}))}
        else:
            meta = {f.name: getattr(clip, f.name) for f in dataclasses.fields(clip)
                    if f.name != "frames"}
            arrays = {"meta": np.array(json.dumps(meta)), "frames": clip.frames}
        tmp = path.with_suffix(".tmp.npz")
        np.savez_compressed(tmp, **arrays)
        tmp.replace(path)

    def truth(self, spec: dict, renderer: Renderer) -> "Truth | None":
        path = self.path(spec, "truth", "truth")
        if not path.is_file():
            return None
        with np.load(path, allow_pickle=False) as z:
            steps = (z["step_poses"], z["frame_steps"]) if "step_poses" in z else None
            return Truth(spec, z["poses"], z["frames"], renderer, steps)

    def put_truth(self, truth: "Truth") -> None:
        path = self.path(truth.spec, "truth", "truth")
        path.parent.mkdir(parents=True, exist_ok=True)
        arrays = {"poses": truth.poses, "frames": truth.frames}
        if truth.steps is not None:
            arrays["step_poses"], arrays["frame_steps"] = truth.steps
        tmp = path.with_suffix(".tmp.npz")
        np.savez_compressed(tmp, **arrays)
        tmp.replace(path)


def made(truth: Truth, kind: str, name: str, make: Callable[[], "Clip | str"],
         skipped: dict[str, str], key: str | None = None,
         cache: ClipCache | None = None) -> Clip | None:
    """``make()``'s clip, or None with the reason in ``skipped[key or name]`` (``make``
    returned a reason or raised `NotApplicable`); through ``cache`` when one is given."""
    hit = cache.get(truth.spec, kind, name) if cache is not None else None
    if hit is None:
        try:
            hit = make()
        except NotApplicable as exc:
            hit = str(exc)
        if cache is not None:
            cache.put(truth.spec, kind, name, hit)
    if isinstance(hit, str):
        skipped[key or name] = hit
        return None
    return hit


# ------------------------------------------------------------------------ scored records
@dataclasses.dataclass
class ClipScore:
    name: str
    kind: str
    what: str
    scores: dict[str, float | None]
    headline: float | None
    changed: float | None = None
    deviation: float | None = None
    missing: list[str] | None = None
    series: str | None = None
    dose: float | None = None
    missing_px: float | None = None

    def visible(self, min_px: float) -> bool:
        """A (ii) clip whose trajectories differ from the truth's by at least ``min_px``: the
        bodies it draws depart that far (``deviation``), or a body it leaves out moved that far
        in the truth (``missing_px``: its whole motion is lost; a left-out body that never
        moves changes no trajectory, only what is drawn; a clip scored before ``missing_px``
        was recorded counts whenever it leaves a body out); other kinds always."""
        if self.kind != WRONG or min_px <= 0:
            return True
        if self.missing and (self.missing_px is None or self.missing_px >= min_px):
            return True
        return self.deviation is not None and self.deviation >= min_px


@dataclasses.dataclass
class SceneOrder:
    """One scene's clips and scores. ``floor``: the static clip's values, ``twin``: the twin's
    (every metric scored: any headline can be recomputed, `order.rescored_headline`);
    ``truth``: the truth clip itself scored (the reference of the invariance and drop
    summaries, dose 0 of every series); ``doses``: the dose series' clips (`dose`);
    ``options``: what was asked (`study.study_options`: a checkpoint line is reused only for
    the same)."""

    scene_id: str
    dim: str
    clips: list[ClipScore]
    floor: dict[str, float | None]
    twin: dict[str, float | None]
    skipped: dict[str, str]
    seconds: float
    truth: ClipScore | None = None
    doses: list[ClipScore] = dataclasses.field(default_factory=list)
    options: dict = dataclasses.field(default_factory=dict)

    def to_json(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_json(cls, d: dict) -> "SceneOrder":
        truth = d.get("truth")
        return cls(**{**d, "clips": [ClipScore(**c) for c in d["clips"]],
                      "truth": ClipScore(**truth) if truth else None,
                      "doses": [ClipScore(**c) for c in d.get("doses") or []]})
