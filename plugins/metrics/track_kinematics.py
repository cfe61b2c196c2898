"""The object-track metrics' kinematics (`tracks.py`): velocities from the centroid tracks, and
the event times (contact, rest, exit) the event errors compare."""

from __future__ import annotations

import math

import numpy as np

from visphy_core.api.metrics import MetricInput

AREA_JUMP = 1.6                 # area ratio within a contact window that voids it
MOVED_FACTOR = 3.0              # a body comes to rest only if it once moved 3× faster
CONTACT_FIT_BEFORE, CONTACT_FIT_AFTER = 4, 6  # frames around a contact its sub-frame fit uses
OWN_ACC_POINTS = 4              # points a piece needs for an acceleration of its own
KINK_GRID, KINK_LEVELS = 16, 4  # the break search: points per level, levels (≈1e-4 frame)
EARLIER_RESIDUAL = 0.25  # an earlier interval must fit this much better than a later one
EXIT_WHOLE_FRACTION = 0.9       # of its largest area: a body not cut by the frame border


def _clip_consts(inp: MetricInput) -> tuple[float, float, float]:
    """(fps, frame diagonal D in px, clip duration T in s) of the reference clip."""
    fps = float(getattr(inp.scene.clip, "fps", 0.0) or 0.0)
    fps = fps if fps > 0 else 1.0
    h, w = inp.reference.shape[1:3]
    return fps, float(math.hypot(h, w)), max(len(inp.reference) - 1, 1) / fps


def _velocities(c: np.ndarray, p: np.ndarray, frames: np.ndarray, fps: float):
    """Interval velocities (K−1×B×2, px/s, NaN where undefined) between the clip's frames
    ``frames`` (K indices) and whether each is defined (the body present at both ends, a
    positive time step)."""
    dt = np.diff(frames) / fps
    ok = p[1:] & p[:-1] & (dt[:, None] > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        v = (c[1:] - c[:-1]) / np.where(dt > 0, dt, np.nan)[:, None, None]
    return np.where(ok[..., None], v, np.nan), ok


def _first(fire: np.ndarray) -> list[int | None]:
    """Per column of a K×B bool array, the row of its first True (None: never)."""
    if fire.shape[0] == 0:
        return [None] * fire.shape[1]
    first = fire.argmax(axis=0)
    return [int(k) if fire[k, b] else None for b, k in enumerate(first)]


def _pairs_time(tau: np.ndarray, ends, i: int, t: float) -> float:
    """A time ``t`` of a clip's own clock between its frames i and i + 1 (``ends``: their
    times on that clock) on the pairs' clock: linear between τ_i and τ_{i+1}, clamped."""
    span = ends[1] - ends[0]
    f = min(1.0, max(0.0, (t - ends[0]) / span)) if span > 0 else 0.0
    return float(tau[i] + f * (tau[i + 1] - tau[i]))


def _piecewise_cost(t: np.ndarray, y: np.ndarray, n_pre: int, breaks: np.ndarray,
                    h: float) -> np.ndarray:
    """For each break time τ in ``breaks``: the residual sum of squares (px²) of the best
    continuous least-squares fit of the positions ``y`` (n×2) at times ``t`` by one polynomial
    per axis before τ (the first ``n_pre`` points) and another after it, meeting at τ. Each
    piece has constant acceleration: its own when both pieces have `OWN_ACC_POINTS` points or
    more (a piece fitted exactly by its own parabola could swallow a point of the other side
    unnoticed); otherwise one shared by both (free flight before and after a bounce); a piece
    of one point is still."""
    u = (t[None, :] - breaks[:, None]) / h                      # G×n, in frame gaps
    pre = np.arange(len(t)) < n_pre
    n_post = len(t) - n_pre
    cols = [np.ones_like(u)]  # the shared position at τ: the two pieces meet
    if n_pre >= 2:
        cols.append(np.where(pre, u, 0.0))
    if n_post >= 2:
        cols.append(np.where(pre, 0.0, u))
    if n_pre >= OWN_ACC_POINTS and n_post >= OWN_ACC_POINTS:
        cols += [np.where(pre, u * u, 0.0), np.where(pre, 0.0, u * u)]
    else:
        moving = (pre & (n_pre >= 2)) | (~pre & (n_post >= 2))
        cols.append(np.where(moving, u * u, 0.0))
    x = np.stack(cols, axis=-1)                                  # G×n×m
    xt = np.swapaxes(x, 1, 2)
    gram = xt @ x
    gram += 1e-12 * np.eye(len(cols)) * np.trace(gram, axis1=1, axis2=2)[:, None, None]
    r = y - x @ np.linalg.solve(gram, xt @ y)
    return (r * r).sum(axis=(1, 2))


def kink_time(t: np.ndarray, y: np.ndarray, n_pre: int) -> tuple[float, float]:
    """The break (τ, residual px²) of the best continuous two-piece constant-acceleration fit
    of a track whose change of motion lies between its points ``n_pre − 1`` and ``n_pre``
    (``t``: times, ``y``: n×2 positions): a coarse-to-fine search (`KINK_GRID` points,
    `KINK_LEVELS` times) over that interval, exact to ~1e-4 of it on noise-free parabolas."""
    t, y = np.asarray(t, float), np.asarray(y, float)
    a, b = float(t[n_pre - 1]), float(t[n_pre])
    h = float(np.mean(np.diff(t)))
    lo, hi = a, b
    for _ in range(KINK_LEVELS):
        grid = np.linspace(lo, hi, KINK_GRID + 1)
        cost = _piecewise_cost(t, y, n_pre, grid, h)
        j = int(np.argmin(cost))
        step = (hi - lo) / KINK_GRID
        lo, hi = max(a, grid[j] - step), min(b, grid[j] + step)
    return float(grid[j]), float(cost[j])


def _contact_time(c, p, area, frames, fps: float, tau, k: int) -> float:
    """Sub-frame time of a change of motion first seen on frames k..k+3 (see the module
    docstring): it lies in one of the intervals (k, k+1), (k+1, k+2), (k+2, k+3); each is
    tried with the frames around (the steady ones, `CONTACT_FIT_BEFORE` before k and up to
    k + `CONTACT_FIT_AFTER`), latest first; an earlier interval wins when its continuous
    two-piece fit leaves less than `EARLIER_RESIDUAL` of the best residual so far."""
    k_n = len(p)
    frames = np.asarray(frames)
    ref = area[k:k + 4]
    lo_a, hi_a = ref.min(), ref.max()

    def usable(j: int, nxt: int) -> bool:  # frame j joins the fit next to frame nxt
        return (bool(p[j]) and hi_a <= AREA_JUMP * area[j] and area[j] <= AREA_JUMP * lo_a
                and (frames[j] - frames[nxt]) * (j - nxt) > 0)

    lo, hi = k, k + 3
    while lo > max(0, k - CONTACT_FIT_BEFORE) and usable(lo - 1, lo):
        lo -= 1
    while hi < min(k_n - 1, k + CONTACT_FIT_AFTER) and usable(hi + 1, hi):
        hi += 1
    best = None
    t = (frames[lo:hi + 1] - frames[lo]) / fps  # the clock's origin does not move the answer
    for i in (k + 2, k + 1, k):
        at, cost = kink_time(t, c[lo:hi + 1], i - lo + 1)
        if best is None or cost < EARLIER_RESIDUAL * best[2]:
            best = (i, at, cost)
    i, at = best[:2]
    return _pairs_time(tau, t[i - lo:i - lo + 2], i, at)


def contact_times(c, p, area, frames, fps, tau, contact_px) -> list[float | None]:
    """Per body: the time of its first abrupt change of motion (see the module docstring)."""
    k_n, n_b = p.shape
    if k_n < 4:
        return [None] * n_b
    v, vok = _velocities(c, p, frames, fps)
    dt = np.diff(frames) / fps
    with np.errstate(invalid="ignore", divide="ignore"):
        acc = (v[1:] - v[:-1]) / ((dt[1:] + dt[:-1]) / 2)[:, None, None]
        jump = np.linalg.norm(acc[1:] - acc[:-1], axis=-1)            # K−3 × B
    h = (dt[:-2] + dt[1:-1] + dt[2:]) / 3
    ok = vok[:-2] & vok[1:-1] & vok[2:]
    win = np.lib.stride_tricks.sliding_window_view(area, 4, axis=0)   # K−3 × B × 4
    lo, hi = win.min(axis=-1), win.max(axis=-1)
    steady = (lo > 0) & (hi <= AREA_JUMP * lo)
    fire = ok & steady & (np.nan_to_num(jump) * (h * h)[:, None] > contact_px)
    return [None if k is None else _contact_time(c[:, b], p[:, b], area[:, b], frames, fps, tau, k)
            for b, k in enumerate(_first(fire))]


def rest_times(c, p, frames, fps, tau, rest_speed: float) -> list[float | None]:
    """Per body that moved and is seen in the last frame: the time its speed falls below
    ``rest_speed`` for good (linear between the middles of the last moving interval and of
    the first interval of the still run that lasts to the end of the clip)."""
    k_n, n_b = p.shape
    out: list[float | None] = [None] * n_b
    if k_n < 2:
        return out
    v, vok = _velocities(c, p, frames, fps)
    speed = np.linalg.norm(np.nan_to_num(v), axis=-1)
    mid = (tau[1:] + tau[:-1]) / 2
    for b in range(n_b):
        idx = np.flatnonzero(vok[:, b])
        if not p[-1, b] or len(idx) == 0:
            continue
        moving = idx[speed[idx, b] >= rest_speed]
        if len(moving) == 0 or speed[moving, b].max() < MOVED_FACTOR * rest_speed:
            continue
        after = idx[idx > moving[-1]]
        if len(after):  # else still moving at the end
            m, a = moving[-1], after[0]
            fast, slow = speed[m, b], speed[a, b]
            f = (fast - rest_speed) / (fast - slow)
            out[b] = float(mid[m] + f * (mid[a] - mid[m]))
    return out


def _exit_time(c, p, area, own, last: int, size) -> float | None:
    """When a body last seen (present) in frame ``last`` has wholly left the frame, on its
    clip's own clock: its centre's path (constant acceleration through its last ≤ 3 whole
    frames, area ≥ `EXIT_WHOLE_FRACTION` of its largest; else its last ≤ 3 frames) reaching an
    equivalent radius beyond an edge. None when the path does not."""
    h, w = size
    run = [last]
    while run[-1] > 0 and p[run[-1] - 1] and own[run[-1] - 1] < own[run[-1]]:
        run.append(run[-1] - 1)
    run = run[::-1]
    biggest = float(area[run].max())
    whole = [j for j in run if area[j] >= EXIT_WHOLE_FRACTION * biggest][-3:]
    pts = whole if len(whole) >= 2 else run[-3:]
    if len(pts) < 2:
        return None
    t0 = own[pts[-1]]
    radius = math.sqrt(biggest / math.pi)
    ts = own[pts] - t0
    best = None
    for axis, (low, high) in ((0, (-radius, w + radius)), (1, (-radius, h + radius))):
        coef = np.polyfit(ts, c[pts, axis], min(2, len(pts) - 1))
        for bound in (low, high):
            shifted = coef.copy()
            shifted[-1] -= bound
            for root in np.roots(shifted):
                if abs(root.imag) < 1e-9 and root.real >= -1e-9:
                    best = root.real if best is None else min(best, root.real)
    return None if best is None else float(best + t0)


def exit_times(c, p, area, max_area, tau, size, frames=None, fps: float = 1.0
               ) -> list[float | None]:
    """Per body: the time it wholly left the frame (see the module docstring) — in the
    interval after the last frame it is seen in (present), when it then stays missing and was
    last seen at the border. ``frames``/``fps``: the clip's own clock (default: ``tau``)."""
    k_n, n_b = p.shape
    out: list[float | None] = [None] * n_b
    h, w = size
    own = np.asarray(tau, float) if frames is None else np.asarray(frames, float) / fps
    for b in range(n_b):
        seen = np.flatnonzero(p[:, b])
        if len(seen) == 0 or seen[-1] == k_n - 1:
            continue
        last = seen[-1]
        x, y = c[last, b]
        radius = math.sqrt(max(max_area[b], area[last, b]) / math.pi)
        step = float(np.linalg.norm(c[last, b] - c[last - 1, b])) \
            if last > 0 and p[last - 1, b] else 0.0
        if min(x, y, w - x, h - y) <= radius + step + 2.0:
            t = _exit_time(c[:, b], p[:, b], area[:, b], own, last, size)
            out[b] = float(tau[last + 1]) if t is None else \
                _pairs_time(tau, own[last:last + 2], last, t)
    return out


def _event_error(ref: list, gen: list, duration: float) -> float:
    errs = [abs(a - b) if a is not None and b is not None else duration
            for a, b in zip(ref, gen) if a is not None or b is not None]
    return float(np.mean(errs)) if errs else 0.0

