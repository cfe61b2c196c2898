"""The object-track metrics' palette (`tracks.py`): the ground truth's body colours, and each
pixel classified against them (exact in 2D, by chromaticity in shaded 3D)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

FLAT_MAX_DIST = 90.0            # RGB units, 2D
SHADED_MAX_ANGLE_DEG = 10.0     # degrees between RGB vectors, 3D
SHADED_MIN_BRIGHTNESS = 24      # max channel, 3D: darker pixels have no reliable chromaticity
SHADED_SCALE = (0.15, 1.7)      # brightness factor of a pixel relative to its palette colour
FLAT_MIN_SEPARATION = 30.0      # RGB units: two colours closer than this are "shared" (2D)
SHADED_MIN_SEPARATION_DEG = 2.0  # degrees: same, 3D (chromaticity)
_STATIC_PHYRE = ((0, 0, 0), (75, 74, 164))  # black and purple: static in PHYRE's palette
_NEUTRAL = (1.0, 1.0, 1.0)


@dataclass(frozen=True)
class Palette:
    """What to look for in a scene's clips: the tracked bodies (label k + 1 for ``ids[k]``) and
    every other colour that must not be mistaken for them."""

    mode: str                                   # "flat" (2D) or "shaded" (3D)
    ids: tuple[str, ...]                        # tracked body ids
    tracked: tuple[tuple[int, int, int], ...]   # their colours
    others: tuple[tuple[int, int, int], ...]    # background, floor, other bodies
    skipped: tuple[tuple[str, str], ...] = ()   # (dynamic body id, why it is not tracked)
    background: tuple[tuple[int, int, int], ...] = ()  # background (and 3D floor) colours

    @property
    def distractors(self) -> tuple[tuple[int, int, int], ...]:
        """The other bodies' colours (static, shared, too dark): not the background's."""
        return tuple(c for c in self.others if c not in self.background)

    @property
    def bits(self) -> int:
        return 5 if self.mode == "flat" else 6


def _rgb(value) -> tuple[int, int, int] | None:
    try:
        r, g, b = (int(round(float(v))) for v in list(value)[:3])
    except (TypeError, ValueError):
        return None
    return (min(max(r, 0), 255), min(max(g, 0), 255), min(max(b, 0), 255))


def _angle_deg(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    if na == 0 or nb == 0:
        return 0.0 if na == nb else 90.0
    return math.degrees(math.acos(min(1.0, max(-1.0, float(a @ b) / (na * nb)))))


def _same_colour(mode: str, a, b) -> bool:
    if mode == "flat":
        return float(np.linalg.norm(np.subtract(a, b, dtype=float))) < FLAT_MIN_SEPARATION
    if max(a) < SHADED_MIN_BRIGHTNESS or max(b) < SHADED_MIN_BRIGHTNESS:
        return max(a) < SHADED_MIN_BRIGHTNESS and max(b) < SHADED_MIN_BRIGHTNESS
    return _angle_deg(a, b) < SHADED_MIN_SEPARATION_DEG


def scene_palette(scene) -> Palette | None:
    """The palette of a scene from its spec (else its detection); None without either."""
    try:
        spec = scene.spec
    except Exception:  # noqa: BLE001 - an unreadable spec: fall back to the detection
        spec = None
    bodies: list[tuple[str, tuple[int, int, int], bool]] = []
    backgrounds: list[tuple[int, int, int]] = []
    dim = getattr(scene, "dim", "2d")
    if isinstance(spec, dict) and isinstance(spec.get("bodies"), list):
        dim = spec.get("dim", dim)
        for b in spec["bodies"]:
            rgb = _rgb(b.get("color_rgb")) if isinstance(b, dict) else None
            if rgb is not None:
                bodies.append((str(b.get("id")), rgb, bool(b.get("dynamic"))))
        bg = _rgb((spec.get("render") or {}).get("background_rgb"))
        backgrounds.append(bg or (255, 255, 255))
        floor = _rgb(((spec.get("world") or {}).get("floor") or {}).get("color_rgb"))
        if floor is not None:
            backgrounds.append(floor)
    else:
        try:
            det = scene.detection
        except Exception:  # noqa: BLE001
            det = None
        if not isinstance(det, dict) or not isinstance(det.get("objects"), list):
            return None
        for o in det["objects"]:
            rgb = _rgb(o.get("color_rgb")) if isinstance(o, dict) else None
            if rgb is not None:
                bodies.append((str(o.get("id")), rgb, rgb not in _STATIC_PHYRE))
        backgrounds.append((255, 255, 255))
    mode = "shaded" if dim == "3d" else "flat"
    ids, tracked, others, skipped = [], [], list(backgrounds), []
    for i, (bid, rgb, dynamic) in enumerate(bodies):
        if not dynamic:
            others.append(rgb)
            continue
        clash = [o for j, (o, c, _) in enumerate(bodies) if j != i and _same_colour(mode, rgb, c)]
        if mode == "shaded" and max(rgb) < SHADED_MIN_BRIGHTNESS:
            skipped.append((bid, "too dark to segment by chromaticity"))
            others.append(rgb)
        elif clash:
            skipped.append((bid, f"shares its colour with {', '.join(clash)}"))
            others.append(rgb)
        elif any(_same_colour(mode, rgb, c) for c in backgrounds) or (
                mode == "shaded" and _angle_deg(rgb, _NEUTRAL) < SHADED_MIN_SEPARATION_DEG):
            skipped.append((bid, "its colour is the background's"))
        else:
            ids.append(bid)
            tracked.append(rgb)
    return Palette(mode=mode, ids=tuple(ids), tracked=tuple(tracked),
                   others=tuple(dict.fromkeys(others)), skipped=tuple(skipped),
                   background=tuple(dict.fromkeys(backgrounds)))


def classify(palette: Palette, rgb: np.ndarray) -> np.ndarray:
    """Label of each colour of an M×3 array (0: none, k + 1: tracked body k)."""
    cube = np.asarray(rgb, dtype=np.float32).reshape(-1, 3)
    cols = np.array(palette.tracked + palette.others, dtype=np.float32).reshape(-1, 3)
    n_tracked = len(palette.tracked)
    if len(cube) == 0:
        return np.zeros(0, np.uint8)
    if palette.mode == "flat":
        d2 = ((cube[:, None, :] - cols[None, :, :]) ** 2).sum(-1)
        best = d2.argmin(1)
        ok = d2[np.arange(len(cube)), best] <= FLAT_MAX_DIST ** 2
    else:
        chroma = np.concatenate([cols, np.array([_NEUTRAL], np.float32)])
        bright = chroma.max(1) >= SHADED_MIN_BRIGHTNESS
        bright[-1] = True
        unit = chroma / np.maximum(np.linalg.norm(chroma, axis=1, keepdims=True), 1e-6)
        norm = np.maximum(np.linalg.norm(cube, axis=1, keepdims=True), 1e-6)
        cos = (cube / norm) @ unit.T
        cos[:, ~bright] = -2.0  # black/dark colours have no chromaticity
        best = cos.argmax(1)
        cbest = cos[np.arange(len(cube)), best]
        scale = (cube * chroma[best]).sum(1) / np.maximum((chroma[best] ** 2).sum(1), 1e-6)
        ok = ((cbest >= math.cos(math.radians(SHADED_MAX_ANGLE_DEG)))
              & (cube.max(1) >= SHADED_MIN_BRIGHTNESS)
              & (scale >= SHADED_SCALE[0]) & (scale <= SHADED_SCALE[1]))
    return np.where(ok & (best < n_tracked), best + 1, 0).astype(np.uint8)


@lru_cache(maxsize=64)
def _lut(palette: Palette) -> tuple[np.ndarray, np.ndarray]:
    """The look-up table over the quantised RGB cube (label per cell) and which cells are
    filled in: cells are classified the first time a clip shows them (`_fill`)."""
    size = 1 << (3 * palette.bits)
    return np.zeros(size, np.uint8), np.zeros(size, bool)


def _fill(palette: Palette, keys: np.ndarray) -> np.ndarray:
    """The table with every cell in ``keys`` classified (at the cell's centre)."""
    lut, done = _lut(palette)
    bits = palette.bits
    miss = ~done[keys]
    if miss.any():
        todo = np.unique(keys[miss]).astype(np.int64)
        mask = (1 << bits) - 1
        q = np.stack([(todo >> (2 * bits)) & mask, (todo >> bits) & mask, todo & mask], axis=1)
        centre = q * float(1 << (8 - bits)) + ((1 << (8 - bits)) - 1) / 2.0
        lut[todo] = classify(palette, centre)
        done[todo] = True
    return lut

