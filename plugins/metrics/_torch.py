"""What the learned and piq metrics share: importing torch lazily, frames to tensors, threads.

torch is imported on first use, never at plugin registration, so listing plugins and running
the weight-free metrics stay fast and a machine without torch still runs them (the torch metrics
are then ``unavailable``, with the reason).
"""

from __future__ import annotations

import importlib.util
import os
import threading
from functools import lru_cache
from typing import Any, Callable

import numpy as np

from visphy_core import weights


@lru_cache(maxsize=None)
def missing_packages(*modules: str) -> str | None:
    """The unavailable reason when one of ``modules`` cannot be imported here, else None."""
    absent = [m for m in modules if importlib.util.find_spec(m) is None]
    if not absent:
        return None
    return (f"not installed: {', '.join(absent)} — the default install has them "
            "(scripts/setup.sh installs them)")


@lru_cache(maxsize=1)
def torch():
    """torch, imported once, with intra-op threads set to the cores this process may use."""
    import torch as _torch

    try:
        n = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        n = os.cpu_count() or 1
    _torch.set_num_threads(max(1, n))
    return _torch


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
