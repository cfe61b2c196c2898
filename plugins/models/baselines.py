"""Offline pixel-space baselines: ``static`` and ``flow_extrapolate`` (no API, no weights).

They hand over a video instead of a program (``output_kind = "video"``), made from the key
frames alone, so they give the floor any model has to beat:

* ``static``: the first key frame held for the whole clip ("nothing moves");
* ``flow_extrapolate``: dense optical flow (OpenCV DIS, medium preset, on grayscale) from the
  first key frame (frame a) to the second (frame b), continued linearly in time: output frame k
  (0-based, at k / fps, i.e. frame k+1) is the first key frame warped by flow·(k+1−a)/(b−a).
  The warp is a backward mapping, out(x) = first(x − s·F(x)), with `cv2.remap` (bilinear,
  border replicate); F is the flow carried to the output frame (each pixel's flow splatted to
  where it lands, the larger motion winning, gaps keeping the flow of frame a), so a moving
  object is drawn where it arrives rather than where it started. With one key frame (the
  forecast-only mode) there is no motion to continue: it holds the frame, as ``static``, and
  says so in its reply.

Both are deterministic. The helpers here (key-frame indices, PNG decoding, writing the clip)
serve the other video models too.
"""

from __future__ import annotations

import re
import tempfile
import time
from pathlib import Path

import numpy as np

from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.media import decode_png, encode_video, resize_with_padding
from visphy_core.api.model import ImageInput, Model, ModelRequest, ModelResponse, OutputContract

_INDEX = re.compile(r"(\d+)\D*$")


def key_frame_index(image: ImageInput) -> int:
    """The 1-based frame number in a key frame's name (``frame_10`` → 10)."""
    m = _INDEX.search(image.name)
    if not m:
        raise ValueError(f"key frame name {image.name!r} carries no frame number")
    return int(m.group(1))


def write_clip(frames: np.ndarray | list[np.ndarray], contract: OutputContract,
               prefix: str = "visphy-video-") -> str:
    """Fit frames to the contract's size and encode them at its fps into a fresh temporary
    directory; returns the MP4's absolute path (the pipeline copies it into its cache)."""
    fitted = [resize_with_padding(np.asarray(f, dtype=np.uint8), contract.width,
                                  contract.height) for f in frames]
    path = Path(tempfile.mkdtemp(prefix=prefix)) / "video.mp4"
    encode_video(fitted, path, contract.fps)
    return str(path.resolve())


def static_frames(first: np.ndarray, contract: OutputContract) -> np.ndarray:
    frame = resize_with_padding(first, contract.width, contract.height)
    return np.repeat(frame[None], contract.n_frames, axis=0)


# --------------------------------------------------------------------------- optical flow
def dense_flow(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """DIS optical flow (medium preset) from ``first`` to ``second`` on grayscale: H×W×2,
    ``first(x) ≈ second(x + flow(x))``."""
    import cv2

    g0 = cv2.cvtColor(first, cv2.COLOR_RGB2GRAY)
    g1 = cv2.cvtColor(second, cv2.COLOR_RGB2GRAY)
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    return dis.calc(g0, g1, None)


def flow_at_target(flow: np.ndarray, s: float) -> np.ndarray:
    """The flow carried to the frame at fraction ``s`` of it: every pixel's flow splatted onto
    the four pixels around x + s·flow(x); where several land, the largest motion wins (moving
    things occlude the still background); pixels nothing lands on keep their own flow."""
    h, w = flow.shape[:2]
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    qx = np.floor(xs + s * flow[..., 0]).astype(np.int64).ravel()
    qy = np.floor(ys + s * flow[..., 1]).astype(np.int64).ravel()
    flat = flow.reshape(-1, 2)
    mag = np.hypot(flat[:, 0], flat[:, 1])
    lins, vals, mags = [], [], []
    for dx in (0, 1):
        for dy in (0, 1):
            tx, ty = qx + dx, qy + dy
            ok = (tx >= 0) & (tx < w) & (ty >= 0) & (ty < h)
            lins.append((ty * w + tx)[ok])
            vals.append(flat[ok])
            mags.append(mag[ok])
    lin, val, m = np.concatenate(lins), np.concatenate(vals), np.concatenate(mags)
    order = np.lexsort((m, lin))           # by target pixel, then by motion (stable)
    lin, val = lin[order], val[order]
    last = np.r_[lin[1:] != lin[:-1], True]
    out = flat.copy()
    out[lin[last]] = val[last]
    return out.reshape(h, w, 2)


def warp(frame: np.ndarray, flow: np.ndarray, s: float) -> np.ndarray:
    """``frame`` moved by s·flow: out(x) = frame(x − s·F(x)), F = `flow_at_target`."""
    import cv2

    if s == 0:
        return frame.copy()
    h, w = flow.shape[:2]
    target = flow_at_target(flow, s)
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    map_x = (xs - s * target[..., 0]).astype(np.float32)
    map_y = (ys - s * target[..., 1]).astype(np.float32)
    return cv2.remap(frame, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def extrapolate(first: np.ndarray, second: np.ndarray, a: int, b: int,
                contract: OutputContract) -> tuple[np.ndarray, np.ndarray]:
    """(frames, flow): frame k = ``first`` warped by flow·(k+1−a)/(b−a)."""
    if b == a:
        raise ValueError(f"the two key frames are the same frame ({a})")
    if second.shape != first.shape:
        second = resize_with_padding(second, first.shape[1], first.shape[0])
    flow = dense_flow(first, second)
    frames = [warp(first, flow, (k + 1 - a) / (b - a)) for k in range(contract.n_frames)]
    return _fit(frames, contract), flow


def _fit(frames: list[np.ndarray], contract: OutputContract) -> np.ndarray:
    return np.stack([resize_with_padding(f, contract.width, contract.height) for f in frames])


# --------------------------------------------------------------------------- models
class _Baseline(Model):
    version = "1"
    output_kind = "video"
    baseline = True

    def _respond(self, frames: np.ndarray, request: ModelRequest, text: str, start: float,
                 raw: dict) -> ModelResponse:
        path = write_clip(frames, request.output, prefix=f"visphy-{self.name}-")
        return ModelResponse(text=text, usage={}, cost_usd=0.0, raw=raw,
                             latency_s=time.perf_counter() - start, model_id=self.name,
                             prompt_version=request.prompt_version, video_path=path,
                             finish_reason="stop")

    @staticmethod
    def _bad(message: str, start: float) -> ModelResponse:
        return ModelResponse(text="", error=message, error_kind="bad_request",
                             latency_s=time.perf_counter() - start)


class StaticModel(_Baseline):
    """``static``: the first key frame held for the whole clip."""

    name = "static"

    def generate(self, request: ModelRequest) -> ModelResponse:
        start = time.perf_counter()
        if not request.images:
            return self._bad("static: the request carries no key frame", start)
        first = request.images[0]
        frames = static_frames(decode_png(first.png), request.output)
        c = request.output
        return self._respond(frames, request,
                             f"static: key frame {first.name} held for {c.n_frames} frames "
                             f"at {c.fps:g} fps", start, {"key_frames": [first.name]})


class FlowExtrapolateModel(_Baseline):
    """``flow_extrapolate``: DIS optical flow between the key frames, continued in time."""

    name = "flow_extrapolate"

    def generate(self, request: ModelRequest) -> ModelResponse:
        start = time.perf_counter()
        if not request.images:
            return self._bad("flow_extrapolate: the request carries no key frame", start)
        c = request.output
        first_img = request.images[0]
        first = decode_png(first_img.png)
        if len(request.images) < 2:
            frames = static_frames(first, c)
            return self._respond(
                frames, request,
                f"flow_extrapolate: only one key frame ({first_img.name}, forecast-only), no "
                f"motion to extrapolate: held it for {c.n_frames} frames (static)", start,
                {"key_frames": [first_img.name], "degraded_to": "static"})
        second_img = request.images[1]
        try:
            a, b = key_frame_index(first_img), key_frame_index(second_img)
            frames, flow = extrapolate(first, decode_png(second_img.png), a, b, c)
        except ValueError as exc:
            return self._bad(f"flow_extrapolate: {exc}", start)
        mean = flow.reshape(-1, 2).mean(axis=0)
        peak = float(np.hypot(flow[..., 0], flow[..., 1]).max())
        return self._respond(
            frames, request,
            f"flow_extrapolate: DIS flow {first_img.name}->{second_img.name} (frames {a}->{b}, "
            f"peak {peak:.1f} px) extrapolated linearly to {c.n_frames} frames at {c.fps:g} fps",
            start, {"key_frames": [first_img.name, second_img.name], "frames": [a, b],
                    "peak_flow_px": round(peak, 3),
                    "mean_flow_px": [round(float(v), 3) for v in mean]})


@hookimpl
def visphy_register_models(register):
    register("static", StaticModel)
    register("flow_extrapolate", FlowExtrapolateModel)
