"""What the frame metrics share: importing torch lazily, frames to tensors, threads, and the
per-frame cache.

torch is imported on first use, never at plugin registration, so listing plugins and running
the weight-free metrics stay fast and a machine without torch still runs them (the torch metrics
are then ``unavailable``, with the reason). Nothing here imports torch at module import.

`per_frame`: a pair metric's work that depends on one frame only (its blurred moments, phase
congruency, saliency, network features) is computed once per distinct frame and kept in one
process-wide LRU cache (`FRAME_CACHE_BYTES` in all), keyed by the frame's content (SHA-256 of
its bytes, with its shape and dtype), the side of the pair it is on (reference or generated:
the benchmark's generated clips are re-timed copies of the reference, and a hit across sides
would flatter the timings) and what computed it (the metric, the model). The scorer asks for
a scene's pairs one pairing at a time (unaligned, aligned, paper), and the same reference and
generated frames come back in each, so frames are shared across those calls too. A cached
result is exactly what a fresh computation gives: the cache only saves time.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import threading
from collections import OrderedDict
from contextlib import contextmanager
from functools import lru_cache
from typing import Any, Callable, Iterator, Sequence

import numpy as np

from visphy_core.api import weights


@lru_cache(maxsize=None)
def missing_packages(*modules: str) -> str | None:
    """The unavailable reason when one of ``modules`` cannot be imported here, else None."""
    absent = [m for m in modules if importlib.util.find_spec(m) is None]
    if not absent:
        return None
    return (f"not installed: {', '.join(absent)} — the default install has them "
            "(scripts/setup.sh installs them)")


#: intra-op threads for torch (default: the cores this process may use)
THREADS_ENV = "VISPHY_TORCH_THREADS"


def default_threads() -> int:
    """``$VISPHY_TORCH_THREADS`` when set (a positive integer), else the cores this process may
    use. On a machine whose cores other processes keep busy, 1 is faster: torch splits each
    operation evenly between its threads and waits for the slowest, so a thread that is not
    scheduled stalls the operation (measured with 2 threads on 2 shared cores: ST-LPIPS 1.5×,
    FSIM/VSI 2.5× slower than 1 thread, single runs up to 10× slower)."""
    env = os.environ.get(THREADS_ENV, "").strip()
    if env:
        try:
            return max(1, int(env))
        except ValueError:
            raise ValueError(f"${THREADS_ENV} must be a positive integer, not {env!r}") from None
    try:
        n = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        n = os.cpu_count() or 1
    return max(1, n)


@lru_cache(maxsize=1)
def torch():
    """torch, imported once, with intra-op threads set to `default_threads`."""
    import torch as _torch

    _torch.set_num_threads(default_threads())
    return _torch


@contextmanager
def threads(n: int) -> Iterator[None]:
    """torch's intra-op threads at most ``n`` inside the block (for work too small to share
    between threads: a second thread only adds waiting), restored after. The setting is the
    process's: metrics run one at a time."""
    t = torch()
    before = t.get_num_threads()
    if n >= before:
        yield
        return
    t.set_num_threads(n)
    try:
        yield
    finally:
        t.set_num_threads(before)


_LOCK = threading.RLock()
_LOADED: dict[tuple, Any] = {}


def load_once(key: tuple, build: Callable[[], Any]) -> Any:
    """The model for ``key`` (what it was built from: kind, weight files, device), built by
    ``build`` the first time and shared by every metric and scene of the process after."""
    with _LOCK:
        if key not in _LOADED:
            _LOADED[key] = build()
        return _LOADED[key]


def device():
    return torch().device(weights.device())


def to_tensor(frames: np.ndarray, value_range: tuple[float, float] = (0.0, 1.0)):
    """N×H×W×3 uint8 → N×3×H×W float32 on the metrics' device, scaled to ``value_range``."""
    t = torch()
    x = t.from_numpy(np.ascontiguousarray(frames[..., :3])).to(device())
    x = x.permute(0, 3, 1, 2).float() / 255.0
    lo, hi = value_range
    return x * (hi - lo) + lo if (lo, hi) != (0.0, 1.0) else x


def area_resize(frames: np.ndarray, size: int) -> np.ndarray:
    """N×H×W×3 uint8 → N×size×size×3 uint8 by area averaging (exact for integer factors)."""
    frames = np.asarray(frames)
    n, h, w = frames.shape[:3]
    if (h, w) == (size, size):
        return frames
    t = torch()
    x = t.from_numpy(np.ascontiguousarray(frames)).permute(0, 3, 1, 2).float()
    y = t.nn.functional.interpolate(x, size=(size, size), mode="area")
    return y.round().clamp(0, 255).to(t.uint8).permute(0, 2, 3, 1).numpy()


# --------------------------------------------------------------------------- per-frame cache
#: what the per-frame cache may hold, in MiB, when set (default 128)
FRAME_CACHE_ENV = "VISPHY_FRAME_CACHE_MB"


def _cache_bytes() -> int:
    env = os.environ.get(FRAME_CACHE_ENV, "").strip()
    try:
        return max(0, int(float(env) * 2**20)) if env else 128 * 2**20
    except ValueError:
        raise ValueError(f"${FRAME_CACHE_ENV} must be a number of MiB, not {env!r}") from None


#: What the per-frame cache may hold, in bytes (all metrics together; least recently used
#: entries go first): ``$VISPHY_FRAME_CACHE_MB``, default 128 MiB (a 2D scene's SSIM moments
#: take about 270 MiB, its ST-LPIPS features about 160 MiB; metrics run one after the other, so
#: the largest one's share is what counts). 128 MiB keeps a whole run under 3 GiB
#: (2.91–2.97 GiB over 21 scenes, against 3.17 at 384 MiB) for 3–10 % more scoring CPU. 0 turns it
#: off: each call still computes each distinct frame of its batch once.
FRAME_CACHE_BYTES = _cache_bytes()

_FRAMES: "OrderedDict[tuple, tuple[Any, int]]" = OrderedDict()
_FRAMES_LOCK = threading.Lock()
_frames_bytes = 0
#: hits and misses of the per-frame cache since the process started (tests, benchmarks)
frame_cache_stats = {"hits": 0, "misses": 0}


def nbytes(obj: Any) -> int:
    """Memory held by a per-frame result: numpy arrays and torch tensors (their own elements: a
    view into a batch's tensor counts its part), in tuples, lists and dicts (anything else
    counts 0)."""
    if isinstance(obj, np.ndarray):
        return int(obj.nbytes)
    if isinstance(obj, (tuple, list)):
        return sum(nbytes(o) for o in obj)
    if isinstance(obj, dict):
        return sum(nbytes(o) for o in obj.values())
    if hasattr(obj, "element_size") and hasattr(obj, "numel"):  # a torch tensor (or a view)
        return int(obj.numel() * obj.element_size())
    return 0


def frame_key(frame: np.ndarray) -> tuple:
    frame = np.ascontiguousarray(frame)
    return (hashlib.sha256(frame).digest(), frame.shape, frame.dtype.str)


def clear_frame_cache() -> None:
    global _frames_bytes
    with _FRAMES_LOCK:
        _FRAMES.clear()
        _frames_bytes = 0


def _put(key: tuple, value: Any) -> None:
    global _frames_bytes
    size = nbytes(value)
    with _FRAMES_LOCK:
        if key in _FRAMES or size > FRAME_CACHE_BYTES:
            return
        _FRAMES[key] = (value, size)
        _frames_bytes += size
        while _frames_bytes > FRAME_CACHE_BYTES and _FRAMES:
            _, (_, dropped) = _FRAMES.popitem(last=False)
            _frames_bytes -= dropped


def per_frame(frames: np.ndarray, namespace: tuple, compute: Callable[[np.ndarray], Sequence],
              chunk: int | None = None, store: bool = True) -> list:
    """``compute``'s result for each of ``frames`` (a K×H×W×C batch): one per distinct frame,
    from the cache or computed, where missing, on the distinct missing frames together (in
    chunks of ``chunk`` frames when given), and kept in the cache (``store``). ``compute(batch)``
    returns one result per frame of its batch (views into the batch's arrays are fine: the
    batch's memory goes when all its frames' entries have). Results are shared between the
    returned positions and the cache: never modify them in place. Every result of the batch
    is held until the call returns: callers pass their pairs a few at a time."""
    keys = [namespace + frame_key(f) for f in frames]
    found: dict[tuple, Any] = {}
    with _FRAMES_LOCK:
        for k in keys:
            if k in _FRAMES and k not in found:
                _FRAMES.move_to_end(k)
                found[k] = _FRAMES[k][0]
    missing: dict[tuple, int] = {}
    for i, k in enumerate(keys):
        if k not in found and k not in missing:
            missing[k] = i
    frame_cache_stats["hits"] += len(keys) - len(missing)
    frame_cache_stats["misses"] += len(missing)
    if missing:
        idx = list(missing.values())
        step = chunk or len(idx)
        results: list = []
        for s in range(0, len(idx), step):
            out = list(compute(np.asarray(frames)[idx[s:s + step]]))
            if len(out) != len(idx[s:s + step]):
                raise RuntimeError(f"per_frame: {len(out)} results for "
                                   f"{len(idx[s:s + step])} frames")
            results += out
        for k, r in zip(missing, results):
            found[k] = r
            if store and FRAME_CACHE_BYTES > 0:
                _put(k, r)
    return [found[k] for k in keys]
