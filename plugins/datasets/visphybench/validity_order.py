"""Validity ordering (issues 21, 32): does a score put physics above drawing, and both above
"nothing moves"?

For each scene of the generated benchmark four kinds of clip are made and scored against the
ground truth X (the raw render, no codec) under visphy's unaligned pairing:

(i) ``right`` — the physics of X, drawn differently (`APPEARANCES`; each one line in
    ``what``):

    * ``pale``: every body colour blended `PALE` (40 %) toward white;
    * ``tint+20`` / ``tint-20``: every body colour's hue turned by ±`TINT_DEG` degrees (HSV; a
      grey or black body barely changes, as it would in a real drawing);
    * ``outline`` (2D): a `OUTLINE_PX`-px dark outline (`OUTLINE_RGB`) drawn inside every body's
      edge (the silhouette keeps its size);
    * ``antialias`` (2D): every frame rendered at `SUPERSAMPLE`× the size and area-averaged down
      (coverage anti-aliasing, what a canvas does); ``aliased`` (3D, whose truth is
      multisampled): the same page with multisampling off;
    * ``grow`` / ``shrink``: every body drawn `SIZE` (10 %) larger or smaller about its own
      origin at the truth's poses (a dilated or eroded body; the motion is the truth's);

    and, issue 32:

    * ``dark``: every body colour blended `DARK` (40 %) toward black (with ``pale``: colour
      ±40 %);
    * ``swapped``: the distinct dynamic-body colours rotated among the dynamic bodies (spec
      order: the first colour's bodies take the second's, …, the last's the first's), so each
      wears another body's colour and no new colour appears; static bodies keep theirs; skipped
      where the dynamic bodies have fewer than two colours;
    * line width (2D; the 3D bodies are shaded solids with no drawn line): ``outline1`` /
      ``outline4``: the outline at `OUTLINE_WIDTHS` (1 and 4 px) instead of 2; ``thick``: every
      bar (a box at most `THIN_PX` = 12 px thick; PHYRE's bars are 10.24 px) drawn `THICKER_PX`
      (2 px) thicker, half on each side, at the truth's poses (compound parts such as a jar's
      walls are left alone); skipped where the scene has no bar;
    * ``background``: the background `SHADE` (15 %) darker: 2D the canvas, 3D the sky (the
      replay page's clear colour, ``render.background_rgb``) and the floor
      (``world.floor.color_rgb``); the lights are kept.

    In 2D, pale, dark and tint repaint the raw raster by colour (it has the exact palette: a
    body colour maps to its new colour, the background is untouched); the others, and every 3D
    variant, draw an edited spec at the truth's own poses (the same rasteriser, or the same
    three.js replay page). A variant is a function `Truth` → clip (raising `NotApplicable`
    where it does not apply: ``skipped``): `per_frame` turns a frame → frame function into
    one, `redrawn` a spec → spec edit; add an `Appearance` to `APPEARANCES` to add a variant.
(ii) ``wrong`` — the physics changed and re-simulated (Box2D in 2D, cannon-es in 3D), drawn like
    the truth (`INTERVENTIONS`): gravity ×0.5 and ×2; restitution ±0.3 (clamped to
    [0, 0.98]); friction ×0.25 and +0.4 (every body material, the default contact and every
    explicit pair); one dynamic body removed (`removed_body`: preferably not the main mover,
    and one whose absence changes another body's motion); a different outcome for the action
    body (`action_body`: the dynamic body with the largest initial speed, else the red ball):
    initial speed ×1.5 and its horizontal direction reversed when it is thrown, a horizontal
    kick toward the middle of the scene (`KICK_PX_S` / `KICK_M_S`) when it starts at rest. A
    variant whose clip equals the truth exactly is skipped (``skipped``: why); each kept one
    records its ``deviation``: how far (image px; 3D positions projected through the camera)
    its bodies get from the truth's, so a summary may count only clearly wrong clips
    (``min_px``, `ClipScore.visible`).
(iii) ``static`` — the first frame held for the whole clip (the ``static`` baseline).
(iv) ``flow`` — the ``flow_extrapolate`` baseline's own function on key frames 1 and 10.

Besides these: the truth clip itself (`SceneOrder.truth`: the reference of the invariance and
drop summaries, and dose 0) and, with ``dose``, the dose series (`validity_dose`: gravity,
restitution, launch angle and playback speed in three growing steps each;
`SceneOrder.doses`).

Scores: every frame and sequence metric of the suite (`visphy_core.scoring.score.score_scene`,
``ScoringProtocol(unaligned=True, aligned=False, paper=False)``) and the headline
(`visphy_core.scoring.headline.scene_headline`): floor = the static clip's component values,
ceiling = the twin's (`visphy_core.scoring.normalisation.twin_spec`, simulated and drawn like
the truth), so the static clip scores exactly 0 on the headline. The twin and the static clip
are scored with every metric, not only the headline's components, so any other headline
(`rescored_headline`, `headline_alternatives`) is recomputed from a checkpoint without
scoring a clip again. ``clips_cache`` (`ClipCache`) keeps the rendered clips as compressed
npz so that scoring them again with other metrics skips simulating and drawing.

Ordering (`order_of`), per scene and score, in the score's good direction (a lower-is-better
value is negated), over the clips whose value is defined:

* **means**: mean over the (i) variants > mean over the (ii) variants > max((iii), (iv));
* **strict**: every (i) variant > every (ii) variant, and every (ii) variant > both (iii) and
  (iv) (min (i) > max (ii) and min (ii) > max((iii), (iv))).

Ties are not ordered. A scene counts for a score only when at least one (i) and one (ii) value
and both (iii) and (iv) are defined. A **family** row pools its metrics: its cases are (scene,
metric) pairs and its shares are the shares of those cases (no mean value: its metrics have
different units). Issue 32's goals (strict with the (ii) clips departing ≥ 20 px, appearance
invariance, physics drop, monotonicity in the dose, discriminative power) are summarised by
`validity_goals`.
"""
# size: one study: its clip variants, scoring loop and table are read together

from __future__ import annotations

import colorsys
import copy
import dataclasses
import hashlib
import json
import math
import tempfile
import time
from pathlib import Path
from typing import Any, Callable, Iterable, Protocol

import numpy as np

from visphy_core.api.metrics import HIGHER, SCENE, Metric
from visphy_core.api.scoring import Headline, ScoringProtocol, scene_headline, score_scene
from visphy_core.api.storage import Cache
from visphy_plugins.datasets.visphybench.validity import _materials, scene_of

RIGHT, WRONG, STATIC, FLOW = "right", "wrong", "static", "flow"
TRUTH, DOSE = "truth", "dose"  # the truth clip itself (`SceneOrder.truth`); a dose series' clip
KINDS = {RIGHT: "(i) physics right, drawn differently", WRONG: "(ii) physics wrong",
         STATIC: "(iii) static", FLOW: "(iv) flow_extrapolate"}
UNALIGNED = ScoringProtocol(unaligned=True, aligned=False, paper=False)

PALE = 0.4                 # blend toward white
TINT_DEG = 20.0            # hue turn, degrees
OUTLINE_PX = 2
OUTLINE_RGB = (40, 40, 40)
SUPERSAMPLE = 4            # 2D anti-aliasing: render at 4x, area-average down
SIZE = 0.10                # grow / shrink
DARK = 0.4                 # blend toward black
OUTLINE_WIDTHS = (1, 4)    # the outline at other line widths (besides `OUTLINE_PX`)
THIN_PX = 12.0             # a 2D box this thin or thinner is a bar (PHYRE's are W/50 = 10.24 px)
THICKER_PX = 2.0           # ``thick``: bars drawn this much thicker (half on each side)
SHADE = 0.15               # ``background``: the background (3D: sky and floor) this much darker
GRAVITY = (0.5, 2.0)
RESTITUTION_DELTA = 0.3
RESTITUTION_RANGE = (0.0, 0.98)
FRICTION_SCALE = 0.25
FRICTION_DELTA = 0.4
SPEED = 1.5
KICK_PX_S = 40.0           # 2D: 40 px/s (the clip shows one simulated second per frame)
KICK_M_S = 1.5             # 3D
MOVING_PX = 1.0           # a body whose image moves at least this far "moves"
VISIBLE_PX = 2.0          # a change of motion anyone can see (`removed_body`, `visible`)
KEY_FRAMES = (1, 10)       # the flow_extrapolate baseline's key frames (1-based)


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


# ------------------------------------------------------------------------ (i) appearance
ClipFn = Callable[[Truth], np.ndarray]


class NotApplicable(Exception):
    """Raised by a variant that does not apply to a scene (its message says why: the variant
    goes into the scene's ``skipped``)."""


@dataclasses.dataclass(frozen=True)
class Appearance:
    """One physics-right variant: ``make(truth)`` is the clip (or raises `NotApplicable`);
    ``dims`` where it applies."""

    name: str
    what: str
    make: ClipFn
    dims: tuple[str, ...] = ("2d", "3d")


def per_frame(fn: Callable[[np.ndarray, dict], np.ndarray]) -> ClipFn:
    """A frame → frame function (``fn(frame, spec)``) as a variant: applied to every frame of
    the truth."""
    def make(truth: Truth) -> np.ndarray:
        return np.stack([fn(f, truth.spec) for f in truth.frames])
    return make


def redrawn(edit: Callable[[dict], dict]) -> ClipFn:
    """A spec → spec edit of the drawing (colours, sizes, render settings) as a variant: the
    edited spec drawn at the truth's own poses (same physics)."""
    def make(truth: Truth) -> np.ndarray:
        return truth.renderer.draw(edit(copy.deepcopy(truth.spec)), truth.poses)
    return make


def pale_rgb(rgb: Iterable[int], amount: float = PALE) -> tuple[int, int, int]:
    """``rgb`` blended ``amount`` of the way toward white."""
    return tuple(int(round(c + amount * (255.0 - c))) for c in rgb)


def dark_rgb(rgb: Iterable[int], amount: float = DARK) -> tuple[int, int, int]:
    """``rgb`` blended ``amount`` of the way toward black."""
    return tuple(int(round(c * (1.0 - amount))) for c in rgb)


def tint_rgb(rgb: Iterable[int], degrees: float) -> tuple[int, int, int]:
    """``rgb`` with its hue turned by ``degrees`` (HSV; saturation and value kept)."""
    h, s, v = colorsys.rgb_to_hsv(*(c / 255.0 for c in rgb))
    r, g, b = colorsys.hsv_to_rgb((h + degrees / 360.0) % 1.0, s, v)
    return tuple(int(round(c * 255.0)) for c in (r, g, b))


def body_colours(spec: dict) -> list[tuple[int, int, int]]:
    """The distinct body colours (spec order), the background's excluded."""
    bg = tuple(int(c) for c in spec["render"]["background_rgb"])
    out: list[tuple[int, int, int]] = []
    for b in spec["bodies"]:
        c = tuple(int(v) for v in b["color_rgb"])
        if c != bg and c not in out:
            out.append(c)
    return out


def _codes(frame: np.ndarray) -> np.ndarray:
    f = frame.astype(np.int32)
    return (f[..., 0] << 16) | (f[..., 1] << 8) | f[..., 2]


def repaint(frame: np.ndarray, mapping: dict[tuple, tuple]) -> np.ndarray:
    """``frame`` with every pixel of exactly colour ``src`` painted ``dst`` (all at once, so a
    chain a→b, b→c does not become a→c); other pixels untouched."""
    out = frame.copy()
    codes = _codes(frame)
    for src, dst in mapping.items():
        if tuple(src) != tuple(dst):
            out[codes == ((int(src[0]) << 16) | (int(src[1]) << 8) | int(src[2]))] = dst
    return out


def recoloured(fn: Callable[[tuple], tuple]) -> Callable[[np.ndarray, dict], np.ndarray]:
    """A frame → frame repaint of every body colour by ``fn`` (2D: exact palette raster)."""
    def paint(frame: np.ndarray, spec: dict) -> np.ndarray:
        return repaint(frame, {c: fn(c) for c in body_colours(spec)})
    return paint


def recolour_spec(fn: Callable[[tuple], tuple]) -> Callable[[dict], dict]:
    """A spec edit: every body colour through ``fn`` (the floor and sky untouched)."""
    def edit(spec: dict) -> dict:
        for b in spec["bodies"]:
            b["color_rgb"] = list(fn(tuple(int(c) for c in b["color_rgb"])))
        return spec
    return edit


def outline_frame(frame: np.ndarray, spec: dict, width: int = OUTLINE_PX,
                  rgb: tuple[int, int, int] = OUTLINE_RGB) -> np.ndarray:
    """Every body colour region's ``width``-px inner edge painted ``rgb`` (2D raw raster: a
    region is the pixels of one exact body colour; the background is untouched)."""
    import cv2

    out = frame.copy()
    codes = _codes(frame)
    kernel = np.ones((2 * width + 1, 2 * width + 1), np.uint8)
    for c in body_colours(spec):
        mask = (codes == ((c[0] << 16) | (c[1] << 8) | c[2])).astype(np.uint8)
        if not mask.any():
            continue
        inner = cv2.erode(mask, kernel, borderType=cv2.BORDER_REPLICATE)
        out[(mask > 0) & (inner == 0)] = rgb
    return out


def _scale_numbers(value: Any, k: float) -> Any:
    if isinstance(value, (list, tuple)):
        return [_scale_numbers(v, k) for v in value]
    return float(value) * k


def scaled_shape(shape: dict, k: float) -> dict:
    """A shape (2D or 3D) scaled by ``k`` about its body's origin: every length (``*_px``,
    ``*_m``: radii, sizes, vertices, parts, part offsets) times ``k``."""
    out = {}
    for key, value in shape.items():
        if key == "parts":
            out[key] = [{**p, **{pk: (scaled_shape(pv, k) if pk == "shape" else
                                      _scale_numbers(pv, k) if pk.endswith("_m") else pv)
                                 for pk, pv in p.items()}} for p in value]
        elif key.endswith("_px") or key.endswith("_m"):
            out[key] = _scale_numbers(value, k)
        else:
            out[key] = value
    return out


def resized_spec(k: float) -> Callable[[dict], dict]:
    def edit(spec: dict) -> dict:
        for b in spec["bodies"]:
            b["shape"] = scaled_shape(b["shape"], k)
        return spec
    return edit


def supersampled_2d(truth: Truth, k: int = SUPERSAMPLE) -> np.ndarray:
    """The truth drawn at ``k``× the canvas and area-averaged down: coverage anti-aliasing."""
    import cv2

    from visphy_plugins.datasets.visphybench.raster2d import render_frame_2d

    spec = copy.deepcopy(truth.spec)
    width, height = spec["world"]["units"]["canvas_px"]
    spec["world"]["units"]["canvas_px"] = [int(width) * k, int(height) * k]
    for b in spec["bodies"]:
        b["shape"] = scaled_shape(b["shape"], float(k))
    poses = np.asarray(truth.poses, dtype=np.float64).copy()
    poses[..., :2] *= k
    return np.stack([cv2.resize(render_frame_2d(spec, p), (int(width), int(height)),
                                interpolation=cv2.INTER_AREA) for p in poses])


def _aliased(spec: dict) -> dict:
    spec["render"]["antialias"] = False
    return spec


def swapped_spec(spec: dict) -> dict:
    """Every dynamic body painted the next distinct dynamic-body colour (spec order, the last
    one the first's): the colours rotate among the bodies, so each dynamic body wears another
    body's colour and no new colour appears; static bodies keep theirs. `NotApplicable` with
    fewer than two distinct dynamic-body colours."""
    colours: list[tuple[int, ...]] = []
    for b in spec["bodies"]:
        c = tuple(int(v) for v in b["color_rgb"])
        if b.get("dynamic") and c not in colours:
            colours.append(c)
    if len(colours) < 2:
        raise NotApplicable(f"{len(colours)} distinct dynamic-body colour(s): nothing to swap")
    turn = {c: colours[(i + 1) % len(colours)] for i, c in enumerate(colours)}
    for b in spec["bodies"]:
        if b.get("dynamic"):
            b["color_rgb"] = list(turn[tuple(int(v) for v in b["color_rgb"])])
    return spec


def thickened_spec(spec: dict, extra: float = THICKER_PX, thin: float = THIN_PX) -> dict:
    """2D: every box at most ``thin`` px thick (a bar; compound parts are left alone) drawn
    ``extra`` px thicker about its own axis (half on each side; its length kept).
    `NotApplicable` where the scene has no bar."""
    n = 0
    for b in spec["bodies"]:
        shape = b["shape"]
        if shape.get("type") == "box":
            key = "thickness_px" if shape["thickness_px"] <= shape["length_px"] else "length_px"
            if float(shape[key]) <= thin:
                shape[key] = float(shape[key]) + extra
                n += 1
    if not n:
        raise NotApplicable(f"no bar (a box at most {thin:g} px thick)")
    return spec


def shaded_spec(spec: dict, amount: float = SHADE) -> dict:
    """The background ``amount`` darker (toward black): 2D the canvas
    (``render.background_rgb``); 3D the sky (the same field: the replay page's clear colour)
    and the floor (``world.floor.color_rgb``). The lights are kept."""
    spec["render"]["background_rgb"] = list(dark_rgb(spec["render"]["background_rgb"], amount))
    floor = spec["world"].get("floor")
    if spec["dim"] == "3d" and floor:
        floor["color_rgb"] = list(dark_rgb(floor["color_rgb"], amount))
    return spec


APPEARANCES: list[Appearance] = [
    Appearance("pale", f"body colours {PALE:.0%} toward white (2D: repainted by colour)",
               per_frame(recoloured(pale_rgb)), ("2d",)),
    Appearance("pale", f"body colours {PALE:.0%} toward white (spec recoloured)",
               redrawn(recolour_spec(pale_rgb)), ("3d",)),
    *[Appearance(f"tint{d:+.0f}", f"body hues turned {d:+.0f}° (repainted by colour)",
                 per_frame(recoloured(lambda c, d=d: tint_rgb(c, d))), ("2d",))
      for d in (TINT_DEG, -TINT_DEG)],
    *[Appearance(f"tint{d:+.0f}", f"body hues turned {d:+.0f}° (spec recoloured)",
                 redrawn(recolour_spec(lambda c, d=d: tint_rgb(c, d))), ("3d",))
      for d in (TINT_DEG, -TINT_DEG)],
    Appearance("outline", f"a {OUTLINE_PX}-px dark outline inside every body's edge",
               per_frame(outline_frame), ("2d",)),
    Appearance("antialias", f"coverage anti-aliasing ({SUPERSAMPLE}x supersampled, area "
               "down-sampled)", supersampled_2d, ("2d",)),
    Appearance("aliased", "multisampling off (the truth is anti-aliased)", redrawn(_aliased),
               ("3d",)),
    Appearance("grow", f"every body drawn {SIZE:.0%} larger at the truth's poses",
               redrawn(resized_spec(1.0 + SIZE))),
    Appearance("shrink", f"every body drawn {SIZE:.0%} smaller at the truth's poses",
               redrawn(resized_spec(1.0 - SIZE))),
    # issue 32: more restyles
    Appearance("dark", f"body colours {DARK:.0%} toward black (2D: repainted by colour)",
               per_frame(recoloured(dark_rgb)), ("2d",)),
    Appearance("dark", f"body colours {DARK:.0%} toward black (spec recoloured)",
               redrawn(recolour_spec(dark_rgb)), ("3d",)),
    Appearance("swapped", "the distinct dynamic-body colours rotated among the bodies "
               "(each wears another's colour; redrawn)", redrawn(swapped_spec)),
    *[Appearance(f"outline{w}", f"a {w}-px dark outline inside every body's edge",
                 per_frame(lambda f, spec, w=w: outline_frame(f, spec, w)), ("2d",))
      for w in OUTLINE_WIDTHS],
    Appearance("thick", f"every bar (a box ≤ {THIN_PX:g} px thick) drawn {THICKER_PX:g} px "
               "thicker at the truth's poses", redrawn(thickened_spec), ("2d",)),
    Appearance("background", f"the background {SHADE:.0%} darker (redrawn)",
               redrawn(shaded_spec), ("2d",)),
    Appearance("background", f"the sky and the floor {SHADE:.0%} darker (redrawn)",
               redrawn(shaded_spec), ("3d",)),
]


# --------------------------------------------------------------------------- (ii) physics
Edit = Callable[[dict, Truth], "tuple[dict | None, str]"]


@dataclasses.dataclass(frozen=True)
class Intervention:
    """One physics-wrong variant: ``edit(spec, truth)`` → (the changed spec, what changed), or
    (None, why not) where it does not apply."""

    name: str
    edit: Edit


def with_material(spec: dict, key: str, fn: Callable[[float], float]) -> dict:
    """``spec`` with ``key`` (friction, restitution) of every material and contact through
    ``fn``."""
    out = copy.deepcopy(spec)
    for m in _materials(out):
        if key in m:
            m[key] = float(fn(float(m[key])))
    return out


def with_gravity(spec: dict, factor: float) -> dict:
    out = copy.deepcopy(spec)
    out["world"]["gravity_m_s2"] = [float(g) * factor for g in out["world"]["gravity_m_s2"]]
    return out


def _linear(body: dict, dim: str) -> np.ndarray:
    v = body.get("velocity") or {}
    if dim == "2d":
        return np.array([v.get("vx_px_s", 0.0), v.get("vy_px_s", 0.0)], dtype=np.float64)
    return np.asarray(v.get("linear_m_s", [0.0, 0.0, 0.0]), dtype=np.float64)


def _set_linear(body: dict, dim: str, vel: np.ndarray) -> None:
    if dim == "2d":
        body["velocity"]["vx_px_s"], body["velocity"]["vy_px_s"] = (float(vel[0]),
                                                                    float(vel[1]))
    else:
        body["velocity"]["linear_m_s"] = [float(v) for v in vel]


def action_body(spec: dict) -> str | None:
    """The body whose start decides the outcome: the dynamic body with the largest initial
    speed; when every body starts at rest, the red ball (else the first dynamic body)."""
    dynamic = [b for b in spec["bodies"] if b.get("dynamic")]
    if not dynamic:
        return None
    speeds = [float(np.linalg.norm(_linear(b, spec["dim"]))) for b in dynamic]
    if max(speeds) > 0:
        return dynamic[int(np.argmax(speeds))]["id"]
    red = [b["id"] for b in dynamic if b["id"] == "red_ball"]
    return red[0] if red else dynamic[0]["id"]


def positions_px(spec: dict, poses: np.ndarray) -> np.ndarray:
    """Every body's position in image pixels per frame (frames × bodies × 2): 2D poses are
    pixels already; 3D positions are projected through the spec's pinhole camera."""
    poses = np.asarray(poses, dtype=np.float64)
    if spec["dim"] == "2d":
        return poses[:, :, :2]
    cam = spec["camera"]
    eye = np.asarray(cam["position"], dtype=np.float64)
    fwd = np.asarray(cam["look_at"], dtype=np.float64) - eye
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, np.asarray(cam.get("up", [0.0, 1.0, 0.0]), dtype=np.float64))
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    d = poses[:, :, :3] - eye
    depth = np.maximum(d @ fwd, 1e-6)
    focal = (float(cam["height"]) / 2.0) / math.tan(math.radians(float(cam["fov_deg"])) / 2.0)
    return np.stack([float(cam["width"]) / 2.0 + focal * (d @ right) / depth,
                     float(cam["height"]) / 2.0 - focal * (d @ up) / depth], axis=-1)


def displacements(truth: Truth) -> dict[str, float]:
    """Per dynamic body, the largest distance (image px) it gets from its start in the truth."""
    pos = positions_px(truth.spec, truth.poses)
    far = np.linalg.norm(pos - pos[:1], axis=2).max(axis=0)
    return {b["id"]: float(far[i]) for i, b in enumerate(truth.spec["bodies"])
            if b.get("dynamic")}


def deviation(truth: Truth, spec: dict, poses: np.ndarray) -> float:
    """How far a re-simulated spec's dynamic bodies get from the truth's: the largest distance
    (image px) between a body's positions in the two rollouts at the same frame, over the
    bodies both have."""
    ids = [b["id"] for b in spec["bodies"]]
    mine, theirs = positions_px(spec, poses), positions_px(truth.spec, truth.poses)
    n = min(len(mine), len(theirs))
    far = 0.0
    for i, b in enumerate(truth.spec["bodies"]):
        if b.get("dynamic") and b["id"] in ids:
            j = ids.index(b["id"])
            far = max(far, float(np.linalg.norm(mine[:n, j] - theirs[:n, i], axis=1).max()))
    return far


def removed_body(truth: Truth) -> str | None:
    """Which dynamic body `remove` takes out. Candidates in order: the moving bodies other than
    the main mover (the action body if it moves, else the farthest mover; farthest first), the
    still dynamic bodies (spec order), the main mover. The first whose removal changes another
    body's motion by at least `VISIBLE_PX` is taken (the physics changes, not only the
    drawing); where none does, the first candidate."""
    far = displacements(truth)
    if not far:
        return None
    moving = sorted((b for b, d in far.items() if d >= MOVING_PX), key=far.get, reverse=True)
    action = action_body(truth.spec)
    main = action if action in moving else (moving[0] if moving else None)
    order = [b for b in moving if b != main] + [b for b in far if b not in moving]
    order += [main] if main is not None else []
    for body in order:
        spec = without_body(truth.spec, body)
        try:
            poses = truth.renderer.simulate(spec)
        except Exception:  # noqa: BLE001 - a candidate that fails is not taken
            continue
        if deviation(truth, spec, poses) >= VISIBLE_PX:
            return body
    return order[0]


def without_body(spec: dict, body_id: str) -> dict:
    """``spec`` without body ``body_id`` (and its explicit contact pairs)."""
    out = copy.deepcopy(spec)
    out["bodies"] = [b for b in out["bodies"] if b["id"] != body_id]
    out["contacts"]["pairs"] = [p for p in out["contacts"]["pairs"]
                                if body_id not in (p.get("a"), p.get("b"))]
    return out


def _gravity(factor: float) -> Edit:
    return lambda spec, truth: (with_gravity(spec, factor), f"gravity ×{factor:g}")


def _restitution(delta: float) -> Edit:
    lo, hi = RESTITUTION_RANGE
    return lambda spec, truth: (with_material(spec, "restitution",
                                              lambda e: min(hi, max(lo, e + delta))),
                                f"restitution {delta:+g} (clamped to [{lo:g}, {hi:g}])")


def _friction_scale(spec: dict, truth: Truth):
    return with_material(spec, "friction", lambda f: f * FRICTION_SCALE), \
        f"friction ×{FRICTION_SCALE:g}"


def _friction_add(spec: dict, truth: Truth):
    return with_material(spec, "friction", lambda f: f + FRICTION_DELTA), \
        f"friction {FRICTION_DELTA:+g}"


def _remove(spec: dict, truth: Truth):
    body = removed_body(truth)
    if body is None:
        return None, "no dynamic body"
    n_dynamic = sum(1 for b in spec["bodies"] if b.get("dynamic"))
    return without_body(spec, body), (f"{body} removed" + (" (the only dynamic body)"
                                                            if n_dynamic == 1 else ""))


def _thrown(spec: dict) -> tuple[dict | None, np.ndarray]:
    bid = action_body(spec)
    if bid is None:
        return None, np.zeros(2)
    body = next(b for b in spec["bodies"] if b["id"] == bid)
    return body, _linear(body, spec["dim"])


def _speed(spec: dict, truth: Truth):
    body, vel = _thrown(spec)
    if body is None or not np.any(vel):
        return None, "the action body starts at rest (see kick)"
    out = copy.deepcopy(spec)
    _set_linear(next(b for b in out["bodies"] if b["id"] == body["id"]), spec["dim"],
                vel * SPEED)
    return out, f"{body['id']}'s initial speed ×{SPEED:g}"


def _mirror(spec: dict, truth: Truth):
    body, vel = _thrown(spec)
    if body is None or not np.any(vel):
        return None, "the action body starts at rest (see kick)"
    out = copy.deepcopy(spec)
    flipped = vel.copy()
    if spec["dim"] == "2d":
        flipped[0] = -flipped[0]
    else:
        flipped[[0, 2]] = -flipped[[0, 2]]
    _set_linear(next(b for b in out["bodies"] if b["id"] == body["id"]), spec["dim"], flipped)
    return out, f"{body['id']}'s horizontal direction reversed"


def _kick(spec: dict, truth: Truth):
    body, vel = _thrown(spec)
    if body is None:
        return None, "no dynamic body"
    if np.any(vel):
        return None, "the action body is thrown (see speed, mirror)"
    out = copy.deepcopy(spec)
    target = next(b for b in out["bodies"] if b["id"] == body["id"])
    if spec["dim"] == "2d":
        width = float(spec["world"]["units"]["canvas_px"][0])
        sign = 1.0 if target["pose"]["x_px"] <= width / 2.0 else -1.0
        _set_linear(target, "2d", np.array([sign * KICK_PX_S, 0.0]))
        what = f"{body['id']} kicked {sign * KICK_PX_S:+g} px/s horizontally"
    else:
        x, _, z = target["pose"]["position_m"]
        d = np.array([-x, 0.0, -z], dtype=np.float64)
        d = d / np.linalg.norm(d) if np.linalg.norm(d) > 1e-9 else np.array([1.0, 0.0, 0.0])
        _set_linear(target, "3d", d * KICK_M_S)
        what = f"{body['id']} kicked {KICK_M_S:g} m/s horizontally toward the middle"
    return out, what


INTERVENTIONS: list[Intervention] = [
    *[Intervention(f"gravity_x{f:g}", _gravity(f)) for f in GRAVITY],
    Intervention(f"restitution{RESTITUTION_DELTA:+g}", _restitution(RESTITUTION_DELTA)),
    Intervention(f"restitution{-RESTITUTION_DELTA:+g}", _restitution(-RESTITUTION_DELTA)),
    Intervention(f"friction_x{FRICTION_SCALE:g}", _friction_scale),
    Intervention(f"friction{FRICTION_DELTA:+g}", _friction_add),
    Intervention("remove", _remove),
    Intervention(f"speed_x{SPEED:g}", _speed),
    Intervention("mirror", _mirror),
    Intervention("kick", _kick),
]


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
@dataclasses.dataclass
class Clip:
    name: str
    kind: str
    what: str
    frames: np.ndarray
    changed: float | None = None  # share of the truth's pixels it changes (over the clip)
    deviation: float | None = None  # (ii), dose: `deviation` (px)
    missing: list[str] | None = None  # (ii): bodies of the truth the clip does not draw
    series: str | None = None  # dose: its series (`validity_dose.SERIES`)
    dose: float | None = None  # dose: how far from the truth, in the series' own unit
    missing_px: float | None = None  # (ii): how far the missing bodies move in the truth (px)


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
    (every metric scored: any headline can be recomputed, `rescored_headline`); ``truth``: the
    truth clip itself scored (the reference of the invariance and drop summaries, dose 0 of
    every series); ``doses``: the dose series' clips (`validity_dose`); ``options``: what was
    asked (`study_options`: a checkpoint line is reused only for the same)."""

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


def frame_metrics(metrics: Iterable[Metric]) -> list[Metric]:
    """The frame and sequence metrics that can run here (scene metrics read a model's text,
    spec or program: the clips of this study have none)."""
    return [m for m in metrics if m.kind != SCENE and m.unavailable_reason() is None]


def study_options(metrics: Iterable[Metric], kinds: Iterable[str] = (RIGHT, WRONG, STATIC, FLOW),
                  appearances: list[Appearance] | None = None,
                  interventions: list[Intervention] | None = None,
                  series: list | None = None, dose: bool = False, twin: bool = True) -> dict:
    """What a scene's scores were asked with (kept in `SceneOrder.options`)."""
    from visphy_plugins.datasets.visphybench.validity_dose import SERIES

    return {"metrics": [m.name for m in metrics], "kinds": sorted(kinds), "twin": bool(twin),
            "appearances": sorted({a.name for a in (APPEARANCES if appearances is None
                                                    else appearances)}),
            "interventions": [iv.name for iv in (INTERVENTIONS if interventions is None
                                                 else interventions)],
            "series": [x.name for x in (SERIES if series is None else series)] if dose else []}


def variants_named(names: Iterable[str]) -> tuple[list[Appearance], list[Intervention], list]:
    """The (i) variants, (ii) variants and dose series (`validity_dose.SERIES`) among
    ``names`` (``--variants``): each a variant's or a series' name, or ``right``, ``wrong``,
    ``dose`` for a whole group; a group none of whose names is given is left out. An unknown
    name: ``ValueError`` listing the known ones."""
    from visphy_plugins.datasets.visphybench.validity_dose import SERIES

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
    the dose series (`validity_dose.SERIES`, or ``series``)."""
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
            from visphy_plugins.datasets.visphybench.validity_dose import dose_clips

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


# ----------------------------------------------------------------------------- ordering
def goodness(value: float, direction: str) -> float:
    return float(value) if direction == HIGHER else -float(value)


def order_of(right: list[float | None], wrong: list[float | None],
             baselines: list[float | None], direction: str) -> tuple[bool, bool] | None:
    """(ordered by means, ordered strictly) for one scene and score, or None when undefined
    (no (i) or (ii) value, or a baseline without one). Values in the score's own units."""
    r = [goodness(v, direction) for v in right if _ok(v)]
    w = [goodness(v, direction) for v in wrong if _ok(v)]
    if not r or not w or len(baselines) == 0 or not all(_ok(v) for v in baselines):
        return None
    b = max(goodness(v, direction) for v in baselines)
    means = bool(np.mean(r) > np.mean(w) > b)
    strict = bool(min(r) > max(w) and min(w) > b)
    return means, strict


def _ok(v: float | None) -> bool:
    return v is not None and math.isfinite(v)


def _groups(result: SceneOrder, get: Callable[[ClipScore], float | None], min_px: float = 0.0
            ) -> dict[str, list[float | None]]:
    out: dict[str, list[float | None]] = {RIGHT: [], WRONG: [], STATIC: [], FLOW: []}
    for c in result.clips:
        if c.visible(min_px):
            out[c.kind].append(get(c))
    return out


def _mean(values: list[float]) -> float | None:
    return float(np.mean(values)) if values else None


def summarise_order(results: list[SceneOrder], metrics: list[Metric],
                    headline: Headline | None = None, min_px: float = 0.0) -> dict[str, dict]:
    """Rows ``headline`` (its name in ``name``), ``family:<family>`` and one per metric:
    ``scenes`` (cases where the ordering is defined), ``ordered_means``, ``ordered_strict``,
    their shares, and the mean value of each kind over those cases (a scene's mean over its
    variants first; None for a family). ``min_px``: only the (ii) clips whose motion departs
    from the truth's by at least that many pixels (`ClipScore.visible`); 0: every (ii) clip
    that differs from the truth at all."""
    headline = headline or Headline()
    rows: dict[str, dict] = {}

    def row(get: Callable[[ClipScore], float | None], direction: str) -> dict:
        cases, means, strict = 0, 0, 0
        kind_means: dict[str, list[float]] = {k: [] for k in KINDS}
        for res in results:
            g = _groups(res, get, min_px)
            o = order_of(g[RIGHT], g[WRONG], g[STATIC] + g[FLOW], direction)
            if o is None:
                continue
            cases += 1
            means += o[0]
            strict += o[1]
            for k in KINDS:
                vals = [v for v in g[k] if _ok(v)]
                if vals:
                    kind_means[k].append(float(np.mean(vals)))
        return {"direction": direction, "scenes": cases, "ordered_means": means,
                "ordered_strict": strict,
                "share_means": means / cases if cases else None,
                "share_strict": strict / cases if cases else None,
                **{f"mean_{k}": _mean(v) for k, v in kind_means.items()}}

    rows["headline"] = {"name": headline.name,
                        **row(lambda c: c.headline, HIGHER)}
    per_metric = {m.name: row(lambda c, n=m.name: c.scores.get(n), m.direction)
                  for m in metrics}
    for family in dict.fromkeys(m.family for m in metrics):
        members = [per_metric[m.name] for m in metrics if m.family == family]
        cases = sum(r["scenes"] for r in members)
        means = sum(r["ordered_means"] for r in members)
        strict = sum(r["ordered_strict"] for r in members)
        rows[f"family:{family}"] = {
            "metrics": [m.name for m in metrics if m.family == family], "scenes": cases,
            "ordered_means": means, "ordered_strict": strict,
            "share_means": means / cases if cases else None,
            "share_strict": strict / cases if cases else None,
            **{f"mean_{k}": None for k in KINDS}}
    rows.update(per_metric)
    return rows


def headline_placement(results: list[SceneOrder], min_px: float = 0.0) -> dict:
    """Where each kind and each variant sits on the headline scale: means over scenes, the
    static clip's exact-zero count, and the scenes where flow_extrapolate scores below every
    physics-right clip."""
    per_variant: dict[str, list[float]] = {}
    kinds: dict[str, list[float]] = {k: [] for k in KINDS}
    below, flow_cases, static_zero, static_cases = 0, 0, 0, 0
    for res in results:
        g = _groups(res, lambda c: c.headline, min_px)
        for k in KINDS:
            vals = [v for v in g[k] if _ok(v)]
            if vals:
                kinds[k].append(float(np.mean(vals)))
        for c in res.clips:
            if _ok(c.headline) and c.visible(min_px):
                per_variant.setdefault(f"{c.kind}:{c.name}", []).append(c.headline)
        right = [v for v in g[RIGHT] if _ok(v)]
        flows = [v for v in g[FLOW] if _ok(v)]
        if right and flows:
            flow_cases += 1
            below += all(f < min(right) for f in flows)
        statics = [v for v in g[STATIC] if _ok(v)]
        if statics:
            static_cases += 1
            static_zero += all(abs(v) < 1e-12 for v in statics)
    return {"kinds": {k: {"mean": _mean(v), "min": min(v) if v else None,
                          "max": max(v) if v else None, "scenes": len(v)}
                      for k, v in kinds.items()},
            "variants": {k: {"mean": _mean(v), "min": min(v), "scenes": len(v)}
                         for k, v in per_variant.items()},
            "flow_below_every_right": below, "flow_cases": flow_cases,
            "static_zero": static_zero, "static_cases": static_cases}


def rescored_headline(results: list[SceneOrder], metrics: list[Metric], headline: Headline,
                      ceiling: str = "twin") -> list[SceneOrder]:
    """``results`` with the headline recomputed under another definition (components, clip;
    ``ceiling="ideal"``: the ideal values instead of the twin's) from the stored values and
    anchors, the truth clip and the dose clips included (no clip is scored again; the static
    clip, or the scene's ``floor``, and the twin must hold every component: the study scores
    the twin with every metric)."""
    out = []
    for res in results:
        static = next((c for c in res.clips if c.kind == STATIC), None)
        held = static.scores if static is not None else res.floor
        floor = {m.name: held.get(m.name) for m in headline.metrics_of(metrics)}
        twin = res.twin if ceiling == "twin" else {}

        def again(c: ClipScore) -> ClipScore:
            return dataclasses.replace(c, headline=scene_headline(headline, metrics, c.scores,
                                                                  floor, twin)[0])

        out.append(dataclasses.replace(res, clips=[again(c) for c in res.clips],
                                       truth=again(res.truth) if res.truth else None,
                                       doses=[again(c) for c in res.doses]))
    return out


def headline_alternatives(results: list[SceneOrder], metrics: list[Metric],
                          headline: Headline | None = None, min_px: float = 0.0
                          ) -> dict[str, dict]:
    """The headline's ordering under other definitions: each component alone, each left out,
    other clip bounds, the ideal instead of the twin as the ceiling (`rescored_headline`)."""
    headline = headline or Headline()
    comps = headline.components
    variants: dict[str, tuple[Headline, str]] = {"as defined": (headline, "twin")}
    for c in comps:
        variants[f"only {c}"] = (dataclasses.replace(headline, components=(c,)), "twin")
    if len(comps) > 2:
        for c in comps:
            rest = tuple(x for x in comps if x != c)
            variants[f"without {c}"] = (dataclasses.replace(headline, components=rest), "twin")
    for clip in ((0.0, 1.0), (-1.0, 2.0), (-math.inf, math.inf)):
        variants[f"clip [{clip[0]:g}, {clip[1]:g}]"] = (dataclasses.replace(headline,
                                                                            clip=clip), "twin")
    variants["ceiling = ideal"] = (headline, "ideal")
    out = {}
    for label, (h, ceiling) in variants.items():
        res = rescored_headline(results, metrics, h, ceiling)
        out[label] = {**summarise_order(res, [], h, min_px)["headline"],
                      "placement": headline_placement(res, min_px)["kinds"]}
    return out


def strict_breakers(results: list[SceneOrder],
                    get: Callable[[ClipScore], float | None] = lambda c: c.headline,
                    direction: str = HIGHER, min_px: float = 0.0) -> dict:
    """Why the strict ordering fails, per scene where it does: ``right_low`` counts the (i)
    variant scoring lowest and ``wrong_high`` the (ii) variant scoring highest where some (ii)
    clip reaches an (i) clip; ``wrong_low`` and ``baseline_high`` the same where some (ii) clip
    does not beat both baselines (each scene counted once per failure)."""
    out: dict[str, dict[str, int]] = {"right_low": {}, "wrong_high": {}, "wrong_low": {},
                                      "baseline_high": {}}
    cases = {"right_vs_wrong": 0, "wrong_vs_baselines": 0, "scenes": 0}

    def bump(key: str, name: str) -> None:
        out[key][name] = out[key].get(name, 0) + 1

    for res in results:
        clips = [c for c in res.clips if c.visible(min_px) and _ok(get(c))]
        by = {k: [c for c in clips if c.kind == k] for k in KINDS}
        if not by[RIGHT] or not by[WRONG] or not by[STATIC] or not by[FLOW]:
            continue
        cases["scenes"] += 1

        def g(c: ClipScore) -> float:
            return goodness(get(c), direction)

        low_r, high_w = min(by[RIGHT], key=g), max(by[WRONG], key=g)
        low_w = min(by[WRONG], key=g)
        high_b = max(by[STATIC] + by[FLOW], key=g)
        if not g(low_r) > g(high_w):
            cases["right_vs_wrong"] += 1
            bump("right_low", low_r.name)
            bump("wrong_high", high_w.name)
        if not g(low_w) > g(high_b):
            cases["wrong_vs_baselines"] += 1
            bump("wrong_low", low_w.name)
            bump("baseline_high", high_b.name)
    return {**cases, **{k: dict(sorted(v.items(), key=lambda kv: -kv[1]))
                        for k, v in out.items()}}


def without_variants(results: list[SceneOrder], names: Iterable[str]) -> list[SceneOrder]:
    """``results`` without the clips of the named variants (e.g. to see what breaks an
    ordering); composes with every summary here."""
    drop = set(names)
    return [dataclasses.replace(r, clips=[c for c in r.clips if c.name not in drop])
            for r in results]
