"""The validity ordering's (i) clips: the physics of the ground truth X, drawn differently
(`APPEARANCES`; each one line in ``what``):

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

and, for the validity goals:

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
"""

from __future__ import annotations

import colorsys
import copy
import dataclasses
from typing import Any, Callable, Iterable

import numpy as np

from visphy_plugins.studies.validity.clips import NotApplicable, Truth

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


# ------------------------------------------------------------------------ (i) appearance
ClipFn = Callable[[Truth], np.ndarray]


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
    # more restyles, for the validity goals
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
