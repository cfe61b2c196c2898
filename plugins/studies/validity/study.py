"""The validity ordering study (issues 21, 32): does a score put physics above drawing, and
both above "nothing moves"? Each scene's clips made and scored, scene after scene.

For each scene of the generated benchmark four kinds of clip are made and scored against the
ground truth X (the raw render, no codec) under visphy's unaligned pairing (`make_clips`):

(i) ``right`` — the physics of X, drawn differently (`restyles.APPEARANCES`);
(ii) ``wrong`` — the physics changed and re-simulated, drawn like the truth
    (`interventions.INTERVENTIONS`; `resimulated`);
(iii) ``static`` — the first frame held for the whole clip (the ``static`` baseline,
    `static_clip`);
(iv) ``flow`` — the ``flow_extrapolate`` baseline's own function on key frames 1 and 10
    (`flow_clip`).

Besides these: the truth clip itself (`SceneOrder.truth`: the reference of the invariance and
drop summaries, and dose 0) and, with ``dose``, the dose series (`dose`: gravity,
restitution, launch angle and playback speed in three growing steps each;
`SceneOrder.doses`).

Scores (`score_truth`, `run_order_study`): every frame and sequence metric of the suite
(`visphy_core.api.scoring.score_scene`, ``ScoringProtocol(unaligned=True, aligned=False,
paper=False)``) and the headline (`visphy_core.api.scoring.scene_headline`): floor = the static
clip's component values, ceiling = the twin's (`visphy_core.api.scoring.twin_spec`, simulated
and drawn like the truth), so the static clip scores exactly 0 on the headline. The twin and
the static clip are scored with every metric, not only the headline's components, so any other
headline (`order.rescored_headline`, `order.headline_alternatives`) is recomputed from a
checkpoint without scoring a clip again. ``clips_cache`` (`clips.ClipCache`) keeps the
rendered clips as compressed npz so that scoring them again with other metrics skips simulating
and drawing. How the scores order the kinds: `order`; the validity goals: `goals`.
"""

from __future__ import annotations

import copy
import tempfile
import time
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from visphy_core.api.metrics import SCENE, Metric
from visphy_core.api.scoring import Headline, ScoringProtocol, scene_headline, score_scene
from visphy_core.api.storage import Cache
from visphy_plugins.studies.validity.clips import (
    DOSE,
    FLOW,
    RIGHT,
    STATIC,
    TRUTH,
    WRONG,
    Clip,
    ClipCache,
    ClipScore,
    Renderer,
    Renderer2D,
    Renderer3D,
    SceneOrder,
    Truth,
    changed_share,
    made,
)
from visphy_plugins.studies.validity.dose import SERIES, dose_clips
from visphy_plugins.studies.validity.interventions import (
    INTERVENTIONS,
    Intervention,
    deviation,
    displacements,
)
from visphy_plugins.studies.validity.perturbation import scene_of
from visphy_plugins.studies.validity.restyles import APPEARANCES, Appearance

UNALIGNED = ScoringProtocol(unaligned=True, aligned=False, paper=False)
KEY_FRAMES = (1, 10)       # the flow_extrapolate baseline's key frames (1-based)


# ------------------------------------------------------------------------- (iii), (iv)
def static_clip(frames: np.ndarray) -> np.ndarray:
    """The first frame held for the whole clip (the ``static`` baseline)."""
    return np.repeat(frames[:1], len(frames), axis=0)


def flow_clip(frames: np.ndarray, fps: float, key_frames: tuple[int, int] = KEY_FRAMES
              ) -> np.ndarray:
    """The ``flow_extrapolate`` baseline's clip from the truth's key frames (1-based)."""
    from visphy_core.api.model import OutputContract
    from visphy_plugins.models.baselines import extrapolate

    a, b = key_frames
    n, height, width = frames.shape[:3]
    contract = OutputContract(fps=float(fps), n_frames=int(n), width=int(width),
                              height=int(height))
    return extrapolate(frames[a - 1], frames[b - 1], a, b, contract)[0]


# ---------------------------------------------------------------------------- the clips
def resimulated(truth: Truth, spec: dict, what: str) -> Clip | str:
    """``spec`` simulated and drawn like the truth, as a clip that records its deviation; a
    reason instead when it fails or its clip equals the truth's."""
    try:
        poses = truth.renderer.simulate(spec)
        frames = truth.renderer.draw(spec, poses)
    except Exception as exc:  # noqa: BLE001 - a failed variant is reported, not fatal
        return f"{what}: failed: {str(exc).splitlines()[0][:200]}"
    if frames.shape == truth.frames.shape and np.array_equal(frames, truth.frames):
        return f"{what}: the clip equals the truth"
    ids = {b["id"] for b in spec["bodies"]}
    missing = [b["id"] for b in truth.spec["bodies"] if b["id"] not in ids]
    far = displacements(truth) if missing else {}
    return Clip("", WRONG, what, frames, changed_share(frames, truth.frames),
                deviation(truth, spec, poses), missing,
                missing_px=max((far.get(b, 0.0) for b in missing), default=None))


def make_clips(truth: Truth, kinds: Iterable[str] = (RIGHT, WRONG, STATIC, FLOW),
               skipped: dict[str, str] | None = None,
               appearances: list[Appearance] | None = None,
               interventions: list[Intervention] | None = None,
               cache: ClipCache | None = None) -> Iterable[Clip]:
    """The scene's clips of the asked kinds, one at a time (3D clips are large); a variant that
    does not apply, fails, or (ii) gives the truth's own clip goes into ``skipped``: why."""
    skipped = {} if skipped is None else skipped
    kinds = tuple(kinds)
    fps = float(truth.spec["world"]["video_fps"])
    if RIGHT in kinds:
        for a in appearances if appearances is not None else APPEARANCES:
            if truth.dim not in a.dims:
                continue

            def right(a: Appearance = a) -> Clip:
                frames = a.make(truth)
                return Clip(a.name, RIGHT, a.what, frames, changed_share(frames, truth.frames))

            clip = made(truth, RIGHT, a.name, right, skipped, cache=cache)
            if clip is not None:
                yield clip
    if WRONG in kinds:
        for iv in interventions if interventions is not None else INTERVENTIONS:
            def wrong(iv: Intervention = iv) -> Clip | str:
                spec, what = iv.edit(copy.deepcopy(truth.spec), truth)
                if spec is None:
                    return what
                out = resimulated(truth, spec, what)
                if isinstance(out, Clip):
                    out.name = iv.name
                return out

            clip = made(truth, WRONG, iv.name, wrong, skipped, cache=cache)
            if clip is not None:
                yield clip
    if STATIC in kinds:
        frames = static_clip(truth.frames)
        yield Clip("static", STATIC, "the first frame held", frames,
                   changed_share(frames, truth.frames))
    if FLOW in kinds:
        def flow() -> Clip:
            frames = flow_clip(truth.frames, fps)
            return Clip("flow_extrapolate", FLOW,
                        f"DIS flow between key frames {KEY_FRAMES[0]} and {KEY_FRAMES[1]}, "
                        "extrapolated", frames, changed_share(frames, truth.frames))

        clip = made(truth, FLOW, "flow_extrapolate", flow, skipped, cache=cache)
        if clip is not None:
            yield clip


def twin_clip(truth: Truth) -> np.ndarray:
    """The ground truth's twin (`visphy_core.scoring.normalisation.twin_spec`), drawn like the
    truth."""
    from visphy_core.api.scoring import twin_spec

    return truth.rollout(twin_spec(truth.spec))


# ----------------------------------------------------------------------------- scoring
def frame_metrics(metrics: Iterable[Metric]) -> list[Metric]:
    """The frame and sequence metrics that can run here (scene metrics read a model's text,
    spec or program: the clips of this study have none)."""
    return [m for m in metrics if m.kind != SCENE and m.unavailable_reason() is None]


def study_options(metrics: Iterable[Metric], kinds: Iterable[str] = (RIGHT, WRONG, STATIC, FLOW),
                  appearances: list[Appearance] | None = None,
                  interventions: list[Intervention] | None = None,
                  series: list | None = None, dose: bool = False, twin: bool = True) -> dict:
    """What a scene's scores were asked with (kept in `SceneOrder.options`)."""
    return {"metrics": [m.name for m in metrics], "kinds": sorted(kinds), "twin": bool(twin),
            "appearances": sorted({a.name for a in (APPEARANCES if appearances is None
                                                    else appearances)}),
            "interventions": [iv.name for iv in (INTERVENTIONS if interventions is None
                                                 else interventions)],
            "series": [x.name for x in (SERIES if series is None else series)] if dose else []}


def variants_named(names: Iterable[str]) -> tuple[list[Appearance], list[Intervention], list]:
    """The (i) variants, (ii) variants and dose series (`dose.SERIES`) among
    ``names`` (``--variants``): each a variant's or a series' name, or ``right``, ``wrong``,
    ``dose`` for a whole group; a group none of whose names is given is left out. An unknown
    name: ``ValueError`` listing the known ones."""
    names = [n.strip() for n in names if n.strip()]
    groups = {RIGHT: [a.name for a in APPEARANCES], WRONG: [iv.name for iv in INTERVENTIONS],
              DOSE: [s.name for s in SERIES]}
    known = {n for v in groups.values() for n in v} | set(groups)
    bad = [n for n in names if n not in known]
    if bad:
        raise ValueError(f"unknown variant(s) {', '.join(bad)}; known: "
                         + "; ".join(f"{g}: {', '.join(dict.fromkeys(v))}"
                                     for g, v in groups.items()))

    def keep(group: str, name: str) -> bool:
        return group in names or name in names

    return ([a for a in APPEARANCES if keep(RIGHT, a.name)],
            [iv for iv in INTERVENTIONS if keep(WRONG, iv.name)],
            [s for s in SERIES if keep(DOSE, s.name)])


def score_truth(truth: Truth, metrics: list[Metric], headline: Headline | None = None,
                progress: Callable[[str], None] | None = None,
                kinds: Iterable[str] = (RIGHT, WRONG, STATIC, FLOW),
                appearances: list[Appearance] | None = None,
                interventions: list[Intervention] | None = None,
                twin: bool = True, dose: bool = False, series: list | None = None,
                clips_cache: ClipCache | None = None) -> SceneOrder:
    """Every clip of one scene scored by every one of ``metrics``: the twin (``twin=False``:
    none; the headline's ceilings are then the components' ideal values), the static clip
    (the headline's floor), the truth clip itself, the clips of ``kinds``, and with ``dose``
    the dose series (`dose.SERIES`, or ``series``)."""
    headline = headline or Headline()
    start = time.perf_counter()
    spec = truth.spec
    scene = scene_of(spec)
    components = headline.metrics_of(metrics)
    skipped: dict[str, str] = {}
    rows: list[ClipScore] = []
    doses: list[ClipScore] = []
    reference: ClipScore | None = None
    kinds = tuple(kinds)
    options = study_options(metrics, kinds, appearances, interventions, series, dose, twin)
    with tempfile.TemporaryDirectory(prefix="visphy-order-") as scratch:
        cache = Cache(Path(scratch), enabled=False)

        def score(frames: np.ndarray, which: list[Metric]) -> dict[str, float | None]:
            return score_scene(scene, truth.frames, frames, which, None, None, cache,
                               protocol=UNALIGNED)[0]

        twin_values: dict[str, float | None] = {}
        if twin:
            if progress:
                progress(f"{spec['scene_id']} twin")
            made_twin = made(truth, "twin", "twin", lambda: Clip(
                "twin", "twin", "the ground truth's twin", twin_clip(truth)), skipped,
                cache=clips_cache)
            twin_values = score(made_twin.frames, metrics)
        floor: dict[str, float | None] = {}

        def scored(clip: Clip) -> ClipScore:
            if progress:
                progress(f"{spec['scene_id']} {clip.kind} {clip.name}")
            values = score(clip.frames, metrics)
            value = scene_headline(headline, metrics, values, floor, twin_values)[0] \
                if components else None
            return ClipScore(clip.name, clip.kind, clip.what, values, value, clip.changed,
                             clip.deviation, clip.missing, clip.series, clip.dose,
                             clip.missing_px)

        # the static clip first: it is every other clip's floor
        (still,) = make_clips(truth, (STATIC,))
        still_score = scored(still)
        floor.update({m.name: still_score.scores.get(m.name) for m in metrics})
        still_score.headline = scene_headline(headline, metrics, still_score.scores, floor,
                                              twin_values)[0] if components else None
        reference = scored(Clip("truth", TRUTH, "the ground truth itself", truth.frames, 0.0,
                                0.0, []))
        for kind in (k for k in (STATIC, RIGHT, WRONG, FLOW) if k in kinds):
            if kind == STATIC:
                rows.append(still_score)
                continue
            for clip in make_clips(truth, (kind,), skipped, appearances, interventions,
                                   clips_cache):
                rows.append(scored(clip))
        if dose:
            for clip in dose_clips(truth, series, skipped, clips_cache):
                doses.append(scored(clip))
    return SceneOrder(spec["scene_id"], spec["dim"], rows, floor, twin_values, skipped,
                      round(time.perf_counter() - start, 2), reference, doses, options)


def run_order_study(specs: list[dict], metrics: list[Metric], headline: Headline | None = None,
                    progress: Callable[[str], None] | None = None,
                    dims: Iterable[str] = ("2d", "3d"), pool=None,
                    done: dict[str, SceneOrder] | None = None,
                    on_scene: Callable[[SceneOrder], None] | None = None,
                    twin: bool = True, kinds: Iterable[str] = (RIGHT, WRONG, STATIC, FLOW),
                    appearances: list[Appearance] | None = None,
                    interventions: list[Intervention] | None = None,
                    dose: bool = False, series: list | None = None,
                    clips_cache: ClipCache | None = None) -> list[SceneOrder]:
    """Every scene of ``specs`` in ``dims``: its truth rendered like the benchmark's, its clips
    of ``kinds`` ((i)–(iv); ``appearances``, ``interventions``: subsets of (i), (ii)) and with
    ``dose`` its dose series scored by the frame and sequence ``metrics`` available here and by
    the headline (`score_truth`). ``done``: scenes already scored (by id; reused, not scored
    again, when asked with the same `study_options`); ``on_scene``: called with each newly
    scored scene (a checkpoint); ``clips_cache``: rendered clips kept and reused
    (`ClipCache`). A 3D scene needs Chromium: ``pool`` (a `BrowserPool`), else one is opened
    for the study."""
    usable = frame_metrics(metrics)
    dims = tuple(dims)
    kinds = tuple(kinds)
    todo = [s for s in specs if s["dim"] in dims]
    done = done or {}
    options = study_options(usable, kinds, appearances, interventions, series, dose, twin)
    out: list[SceneOrder] = []
    own_pool = None
    try:
        for spec in todo:
            old = done.get(spec["scene_id"])
            if old is not None and old.options == options:
                out.append(old)
                continue
            if spec["dim"] == "2d":
                renderer: Renderer = Renderer2D()
            else:
                if pool is None:
                    from visphy_core.api.sandbox import BrowserPool

                    own_pool = pool = BrowserPool(untrusted=False).__enter__()
                renderer = Renderer3D(pool)
            truth = Truth.of(_clean(spec), renderer, clips_cache)
            result = score_truth(truth, usable, headline, progress, kinds, appearances,
                                 interventions, twin, dose, series, clips_cache)
            out.append(result)
            if on_scene:
                on_scene(result)
    finally:
        if own_pool is not None:
            own_pool.__exit__(None, None, None)
    return out


def _clean(spec: dict) -> dict:
    out = copy.deepcopy(spec)
    out.pop("splits", None)
    return out
