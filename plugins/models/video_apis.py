"""Video-generation APIs as pixel-space models: ``veo`` (Google, Gemini API) and ``sora`` (OpenAI).

Both get the first key frame and a fixed, versioned text prompt (`PROMPT`, `PROMPT_VERSION`):
a static-camera physics video continuing the image. The benchmark's own prompt (which asks for a
program) is not sent. The key frame is letterboxed with white into the provider's frame (16:9 or
9:16) so nothing is cropped by the provider; the same box is cut back out of the returned video,
which is then resampled to the clip contract by its own timestamps (time 0 of the provider's
video is the first key frame's time) and written as the reply's MP4.

Every HTTP step (create, each poll, the download) is one unit retried by
`visphy_core.calls.retry.call_with_retries` under the endpoint's adaptive limiter; the SDKs' own
retries are off. A generation that finishes with an error is ``error_kind="server"``; a
content-policy rejection is ``"bad_request"``. Cost: seconds of video × ``price_usd_per_second``.

Wire formats (checked against the installed SDKs, google-genai 3.6.1 and openai 3.57):

* Veo, Gemini API: ``POST /v1beta/models/{model}:predictLongRunning`` with
  ``{"instances": [{"prompt", "image": {"bytesBase64Encoded", "mimeType"}}], "parameters":
  {...}}`` → ``{"name": "models/{model}/operations/{id}"}``; polled with
  ``client.aio.operations.get`` (``GET /v1beta/{name}``) until ``done``; the video is
  ``response.generateVideoResponse.generatedSamples[0].video.uri``, fetched with
  ``client.aio.files.download`` (``GET /v1beta/files/{id}:download?alt=media``). The key goes in
  the ``x-goog-api-key`` header. google-genai 3.6.1's ``models.generate_videos`` refuses the
  Gemini Developer API ("only supported in Gemini Enterprise Agent Platform mode"), so the create
  request is sent through the SDK client's own transport (same key header, base URL, timeout and
  error types); polling and download use the public SDK methods.
* Sora: ``client.videos.create(model, prompt, input_reference=(name, png, "image/png"), seconds,
  size)`` (multipart ``POST /v1/videos``), ``client.videos.retrieve(id)`` (``GET
  /v1/videos/{id}``) until ``completed``/``failed``, ``client.videos.download_content(id)``
  (``GET /v1/videos/{id}/content``). Key: ``Authorization: Bearer``. (The SDK marks these
  methods deprecated: OpenAI announced the Sora API's shutdown for 2026-09-24.)
"""
# size: two providers' video jobs share one submit, poll and download path

from __future__ import annotations

import asyncio
import base64
import json
import tempfile
import time
import warnings
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any, Awaitable, Callable, Optional, TypeVar

import numpy as np

from visphy_core.api.calls import (
    CallError,
    CallErrorKind,
    RetryPolicy,
    call_with_retries,
    kind_for_status,
    limiter_for,
    require_key,
    retry_after_seconds,
)
from visphy_core.api.config_schema import ModelConfig
from visphy_core.api.errors import ConfigError
from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.media import (
    ClipInfo,
    VideoBudget,
    decode_video_timed,
    png_bytes,
    resample_by_time,
    resize_with_padding,
)
from visphy_core.api.model import Model, ModelRequest, ModelResponse, OutputContract
from visphy_plugins.models.baselines import decode_png, key_frame_index, write_clip
from visphy_plugins.providers.config import ConcurrencyConfig, RetriesConfig

T = TypeVar("T")

PROMPT_VERSION = "video-continue-v1"
PROMPT = (
    "Continue this image as a video. The image is the first frame of a physics experiment "
    "filmed by a fixed camera. Keep the camera completely still: no pan, tilt, zoom, shake or "
    "cut. Keep the framing, lighting, colours and flat style exactly as in the image, including "
    "any plain white margins, and add no new objects, text, hands or people. Objects move only "
    "under gravity and their contacts: they fall, slide, roll, collide and bounce realistically "
    "and come to rest. No music or sound."
)

#: Words in a provider's failure message that mean the request was refused on policy grounds.
POLICY_WORDS = ("safety", "policy", "guideline", "moderation", "responsible ai", "blocked",
                "prohibited", "rai ")


# ============================================================================ config
class Orientation(StrEnum):
    auto = "auto"             # landscape unless the key frame is taller than wide
    landscape = "landscape"
    portrait = "portrait"


@dataclass
class VideoApiConfig(ModelConfig):
    """What both video APIs configure."""

    model_id: str = ""
    api_key_env: Optional[str] = None
    base_url: Optional[str] = None              # null: the SDK's default
    seconds: Optional[int] = field(default=None, metadata={"min": 1, "max": 60})  # null: auto
    allowed_seconds: list[int] = field(default_factory=list, metadata={"min": 1})
    orientation: Orientation = Orientation.auto
    price_usd_per_second: Optional[float] = field(default=None, metadata={"min": 0})
    poll_interval_s: float = field(default=10.0, metadata={"min": 0, "max": 600})
    max_wait_s: float = field(default=1800.0, metadata={"min": 1, "max": 86400})
    timeout_s: float = field(default=300.0, metadata={"min": 1, "max": 7200})  # per HTTP step
    retries: RetriesConfig = field(default_factory=RetriesConfig)
    concurrency: ConcurrencyConfig = field(default_factory=lambda: ConcurrencyConfig(2, 4))


@dataclass
class VeoConfig(VideoApiConfig):
    model_id: str = "veo-3.1-generate-preview"
    api_key_env: Optional[str] = "GEMINI_API_KEY"
    api_version: str = "v1beta"
    resolution: str = "720p"                    # 720p | 1080p
    allowed_seconds: list[int] = field(default_factory=lambda: [4, 6, 8], metadata={"min": 1})
    negative_prompt: Optional[str] = "camera motion, zoom, cuts, text, people"
    person_generation: Optional[str] = None     # e.g. allow_adult (null: the API's default)
    seed: Optional[int] = field(default=None, metadata={"min": 0, "max": 2**32 - 1})


@dataclass
class SoraConfig(VideoApiConfig):
    model_id: str = "sora-2"
    api_key_env: Optional[str] = "OPENAI_API_KEY"
    size: str = "1280x720"                      # landscape size; portrait frames swap it
    allowed_seconds: list[int] = field(default_factory=lambda: [4, 8, 12], metadata={"min": 1})


VEO_RESOLUTIONS = {"720p": (1280, 720), "1080p": (1920, 1080)}
SORA_SIZES = ("1280x720", "720x1280", "1792x1024", "1024x1792")


# ============================================================================ helpers
@dataclass(frozen=True)
class Framing:
    """Where the key frame sits inside the provider's frame (white letterbox around it)."""

    width: int          # the provider's frame
    height: int
    x0: int             # the key frame's box inside it
    y0: int
    w: int
    h: int


def letterbox(frame: np.ndarray, width: int, height: int) -> tuple[np.ndarray, Framing]:
    """``frame`` fitted into width×height with white margins, and where it went."""
    fh, fw = frame.shape[:2]
    scale = min(width / fw, height / fh)
    w, h = max(1, round(fw * scale)), max(1, round(fh * scale))
    framing = Framing(width, height, (width - w) // 2, (height - h) // 2, w, h)
    return resize_with_padding(frame, width, height), framing


def frame_size(landscape: tuple[int, int], orientation: Orientation, frame: np.ndarray
               ) -> tuple[int, int]:
    w, h = max(landscape), min(landscape)
    portrait = (orientation == Orientation.portrait
                or (orientation == Orientation.auto and frame.shape[0] > frame.shape[1]))
    return (h, w) if portrait else (w, h)


def choose_seconds(cfg: Any, contract: OutputContract, first_index: int) -> int:
    """The configured length, else the shortest allowed one that covers the clip from the first
    key frame to its end (the longest allowed when none does: the last frame is then held)."""
    if cfg.get("seconds"):
        return int(cfg.seconds)
    allowed = sorted(int(s) for s in cfg.allowed_seconds)
    needed = (contract.n_frames - first_index) / contract.fps
    return next((s for s in allowed if s >= needed - 1e-9), allowed[-1])


def finish_clip(video: bytes, framing: Framing, contract: OutputContract, first_index: int,
                prefix: str) -> tuple[str, ClipInfo]:
    """The provider's MP4 as the contract's clip (see `finish_frames`), decoded with its own
    timestamps."""
    tmp = Path(tempfile.mkdtemp(prefix=prefix)) / "provider.mp4"
    tmp.write_bytes(video)
    try:
        # the provider's bytes are untrusted: header checked, decoded within a budget
        frames, times, info = decode_video_timed(tmp, VideoBudget())
    except (ValueError, FileNotFoundError) as exc:
        raise CallError(CallErrorKind.malformed, f"the returned video does not decode: {exc}")
    return finish_frames(frames, times, framing, contract, first_index, prefix), info


def finish_frames(frames: np.ndarray, times_s: np.ndarray, framing: Framing,
                  contract: OutputContract, first_index: int, prefix: str) -> str:
    """Generated frames as the contract's clip: the key frame's box cut out (scaled to the
    frames' size), frames paired by their times (time 0 = the first key frame, frame
    ``first_index``), written to a fresh temporary directory; returns the MP4's path."""
    import cv2

    height, width = frames.shape[1:3]
    sx, sy = width / framing.width, height / framing.height
    x0, x1 = round(framing.x0 * sx), max(round((framing.x0 + framing.w) * sx), 1)
    y0, y1 = round(framing.y0 * sy), max(round((framing.y0 + framing.h) * sy), 1)
    x0, y0 = min(x0, x1 - 1), min(y0, y1 - 1)
    crops = [cv2.resize(np.ascontiguousarray(f[y0:y1, x0:x1]), (contract.width, contract.height),
                        interpolation=cv2.INTER_AREA) for f in frames]
    offset = (first_index - 1) / contract.fps
    target = ClipInfo(contract.fps, contract.n_frames, contract.width, contract.height)
    out = resample_by_time(np.stack(crops), np.asarray(times_s, dtype=np.float64) + offset,
                           target)
    return write_clip(out, contract, prefix=prefix)


def policy_refusal(message: str) -> bool:
    low = f" {message.lower()} "
    return any(word in low for word in POLICY_WORDS)


class _Failed(Exception):
    """The generation itself failed (the provider's job ended in an error)."""

    def __init__(self, kind: str, message: str):
        super().__init__(message)
        self.kind = kind


# ============================================================================ base model
class VideoApiModel(Model):
    """Shared flow: key, letterbox, create → poll → download (each step retried), finish."""

    version = "1"
    output_kind = "video"
    provider = ""

    def __init__(self, cfg: Any):
        super().__init__(cfg)
        self.name = str(cfg.name) if cfg is not None and cfg.get("name") else self.name
        self.policy = RetryPolicy.from_cfg(cfg)
        self.needs_key = str(cfg.api_key_env) if cfg.get("api_key_env") else None
        self._client: Any = None
        self.sleep: Callable[[float], Awaitable[Any]] = asyncio.sleep

    # --------------------------------------------------------------- contract
    def api_key(self) -> str:
        return require_key(self.needs_key, f"model={self.name}") if self.needs_key else "none"

    def check_ready(self) -> None:
        self.check_settings()
        self.api_key()

    def check_settings(self) -> None:
        """Raise `ConfigError` for a setting the API does not accept."""

    def identity_settings(self) -> dict[str, Any]:
        keys = ("model_id", "seconds", "allowed_seconds", "orientation")
        return {k: self.cfg.get(k) for k in keys}

    def identity(self) -> str:
        from omegaconf import OmegaConf

        settings = {k: (OmegaConf.to_container(v) if OmegaConf.is_config(v) else v)
                    for k, v in self.identity_settings().items()}
        return json.dumps([self.provider, self.version, PROMPT_VERSION, settings],
                          sort_keys=True, default=str)

    def describe(self) -> dict:
        return {**super().describe(), "provider": self.provider,
                "model_id": str(self.cfg.model_id), "prompt_version": PROMPT_VERSION}

    @property
    def endpoint(self) -> str:
        return f"{self.provider}:{self.cfg.get('base_url') or 'default'}"

    # --------------------------------------------------------------- steps
    async def _step(self, attempt: Callable[[], Awaitable[T]], counter: list[int]) -> T:
        conc = self.cfg.get("concurrency") or {}
        limiter = limiter_for(self.endpoint, int(conc.get("initial", 2)),
                              int(conc.get("maximum", 4)))

        async def guarded() -> T:
            try:
                return await attempt()
            except CallError:
                raise
            except Exception as exc:  # noqa: BLE001 - the SDK's exception, classified
                raise self.classify(exc) from exc

        try:
            result, n = await call_with_retries(guarded, self.policy, limiter, sleep=self.sleep)
        except CallError as exc:
            counter[0] += getattr(exc, "attempts", 1)
            raise
        counter[0] += n
        return result

    def classify(self, exc: Exception) -> CallError:
        raise NotImplementedError

    async def create(self, image_png: bytes, framing: Framing, seconds: int,
                     counter: list[int]) -> Any:
        raise NotImplementedError

    async def poll(self, job: Any, counter: list[int]) -> tuple[bool, Any]:
        """(done, job); raises `_Failed` when the job ended in an error."""
        raise NotImplementedError

    async def download(self, job: Any, counter: list[int]) -> bytes:
        raise NotImplementedError

    def job_name(self, job: Any) -> str:
        return str(getattr(job, "name", None) or getattr(job, "id", ""))

    # --------------------------------------------------------------- flow
    async def agenerate(self, request: ModelRequest) -> ModelResponse:
        start = time.perf_counter()
        counter = [0]

        def failed(kind: str, message: str) -> ModelResponse:
            return ModelResponse(text="", error=f"{self.name}: {message}", error_kind=kind,
                                 latency_s=time.perf_counter() - start,
                                 transport_attempts=max(counter[0], 1),
                                 prompt_version=PROMPT_VERSION)

        if not request.images:
            return failed("bad_request", "the request carries no key frame")
        first = request.images[0]
        try:
            first_index = key_frame_index(first)
        except ValueError:
            first_index = 1
        frame = decode_png(first.png)
        width, height = self.frame_size(frame)
        padded, framing = letterbox(frame, width, height)
        upload = first.png if (frame.shape[1], frame.shape[0]) == (width, height) \
            else png_bytes(padded)
        seconds = choose_seconds(self.cfg, request.output, first_index)
        try:
            job = await self.create(upload, framing, seconds, counter)
            deadline = time.monotonic() + float(self.cfg.max_wait_s)
            polls = 0
            done, job = self.initial_state(job)
            while not done:
                if time.monotonic() > deadline:
                    raise CallError(CallErrorKind.timeout,
                                    f"job {self.job_name(job)} not done after "
                                    f"{float(self.cfg.max_wait_s):g} s ({polls} polls)")
                await self.sleep(float(self.cfg.poll_interval_s))
                done, job = await self.poll(job, counter)
                polls += 1
            video = await self.download(job, counter)
            path, info = finish_clip(video, framing, request.output, first_index,
                                     prefix=f"visphy-{self.name}-")
        except _Failed as exc:
            return failed(exc.kind, str(exc))
        except CallError as exc:
            return failed(exc.kind.value, exc.describe())
        price = self.cfg.get("price_usd_per_second")
        c = request.output
        text = (f"{self.name}: {self.cfg.model_id} made {seconds} s of {info.width}x"
                f"{info.height} video ({info.n_frames} frames @ {info.fps:g} fps) from "
                f"{first.name} and prompt {PROMPT_VERSION} in {polls} polls; resampled by "
                f"timestamp to {c.n_frames} frames {c.width}x{c.height} @ {c.fps:g} fps")
        return ModelResponse(
            text=text, usage={"video_seconds": seconds},
            cost_usd=None if price is None else float(price) * seconds,
            latency_s=time.perf_counter() - start, transport_attempts=counter[0],
            prompt_version=PROMPT_VERSION, model_id=str(self.cfg.model_id), finish_reason="stop",
            video_path=path,
            raw={"job": self.job_name(job), "polls": polls, "seconds": seconds,
                 "provider_clip": {"fps": info.fps, "n_frames": info.n_frames,
                                   "width": info.width, "height": info.height},
                 "framing": framing.__dict__, "key_frame": first.name})

    def initial_state(self, job: Any) -> tuple[bool, Any]:
        return False, job

    def frame_size(self, frame: np.ndarray) -> tuple[int, int]:
        raise NotImplementedError


# ============================================================================ Veo
class VeoModel(VideoApiModel):
    """``veo``: Google Veo through the Gemini API (google-genai SDK)."""

    name = "veo"
    provider = "veo"

    def check_settings(self) -> None:
        if str(self.cfg.resolution) not in VEO_RESOLUTIONS:
            raise ConfigError(f"model.resolution={self.cfg.resolution!r} is not valid for veo; "
                              f"valid: {', '.join(VEO_RESOLUTIONS)}")
        if not self.cfg.allowed_seconds:
            raise ConfigError("model.allowed_seconds is empty: list the durations Veo accepts")

    def identity_settings(self) -> dict[str, Any]:
        keys = ("resolution", "negative_prompt", "person_generation", "seed", "api_version")
        return {**super().identity_settings(), **{k: self.cfg.get(k) for k in keys}}

    def frame_size(self, frame: np.ndarray) -> tuple[int, int]:
        return frame_size(VEO_RESOLUTIONS[str(self.cfg.resolution)],
                          Orientation(str(self.cfg.orientation)), frame)

    def client(self) -> Any:
        if self._client is None:
            from google import genai
            from google.genai import types

            opts = types.HttpOptions(base_url=self.cfg.get("base_url") or None,
                                     api_version=str(self.cfg.api_version),
                                     timeout=int(float(self.cfg.timeout_s) * 1000))
            self._client = genai.Client(api_key=self.api_key(), http_options=opts)
        return self._client

    def classify(self, exc: Exception) -> CallError:
        from google.genai import errors

        if isinstance(exc, errors.APIError):
            headers = getattr(getattr(exc, "response", None), "headers", None)
            try:
                headers = dict(headers) if headers is not None else None
            except (TypeError, ValueError):
                headers = None
            code = int(exc.code or 0)
            return CallError(kind_for_status(code) if code else CallErrorKind.server,
                             f"{exc.status or ''} {exc.message or exc}".strip(), code or None,
                             retry_after_seconds(headers))
        return _transport_error(exc)

    async def create(self, image_png: bytes, framing: Framing, seconds: int,
                     counter: list[int]) -> Any:
        from google.genai import types

        cfg = self.cfg
        params: dict[str, Any] = {
            "aspectRatio": "16:9" if framing.width >= framing.height else "9:16",
            "resolution": str(cfg.resolution), "durationSeconds": seconds}
        if cfg.get("negative_prompt"):
            params["negativePrompt"] = str(cfg.negative_prompt)
        if cfg.get("person_generation"):
            params["personGeneration"] = str(cfg.person_generation)
        if cfg.get("seed") is not None:
            params["seed"] = int(cfg.seed)
        body = {"instances": [{"prompt": PROMPT, "image": {
            "bytesBase64Encoded": base64.b64encode(image_png).decode("ascii"),
            "mimeType": "image/png"}}], "parameters": params}
        api = self.client().aio._api_client   # see the module docstring: generate_videos
        path = f"models/{cfg.model_id}:predictLongRunning"   # refuses the Gemini API

        async def attempt() -> Any:
            response = await api.async_request("post", path, body, None)
            try:
                data = json.loads(response.body or "")
            except ValueError as exc:
                raise CallError(CallErrorKind.malformed, f"create: not JSON: {exc}") from None
            if not isinstance(data, dict) or not data.get("name"):
                raise CallError(CallErrorKind.malformed, f"create: no operation name in {data}")
            return types.GenerateVideosOperation.from_api_response(data, is_vertex_ai=False)

        return await self._step(attempt, counter)

    def initial_state(self, job: Any) -> tuple[bool, Any]:
        return self._state(job), job

    def _state(self, op: Any) -> bool:
        if not op.done:
            return False
        if op.error:
            err = op.error if isinstance(op.error, dict) else {"message": str(op.error)}
            message = f"operation {op.name} failed: {err.get('code', '')} {err.get('message', '')}"
            raise _Failed("bad_request" if policy_refusal(message) else "server", message.strip())
        videos = (op.response.generated_videos if op.response is not None else None) or []
        if not videos:
            filtered = getattr(op.response, "rai_media_filtered_count", None) or 0
            reasons = getattr(op.response, "rai_media_filtered_reasons", None) or []
            if filtered or reasons:
                raise _Failed("bad_request", f"operation {op.name}: video blocked by the "
                              f"content filter ({'; '.join(reasons) or filtered})")
            raise _Failed("server", f"operation {op.name} finished without a video")
        return True

    async def poll(self, job: Any, counter: list[int]) -> tuple[bool, Any]:
        client = self.client()
        op = await self._step(lambda: client.aio.operations.get(job), counter)
        return self._state(op), op

    async def download(self, job: Any, counter: list[int]) -> bytes:
        video = job.response.generated_videos[0].video
        if video is None:
            raise _Failed("server", f"operation {job.name}: a sample without a video")
        if video.video_bytes:
            return bytes(video.video_bytes)
        if not video.uri or "files/" not in video.uri:
            raise CallError(CallErrorKind.malformed, f"operation {job.name}: no downloadable "
                            f"video (uri {video.uri!r})")
        client = self.client()

        async def attempt() -> bytes:
            data = await client.aio.files.download(file=video)
            if not data:
                raise CallError(CallErrorKind.empty, f"empty download of {video.uri}")
            return bytes(data)

        return await self._step(attempt, counter)

    async def aclose(self) -> None:
        if self._client is not None:
            try:
                await self._client.aio.aclose()
            finally:
                self._client = None


# ============================================================================ Sora
class SoraModel(VideoApiModel):
    """``sora``: OpenAI Sora through the OpenAI SDK's Videos API."""

    name = "sora"
    provider = "sora"

    def check_settings(self) -> None:
        if str(self.cfg.size) not in SORA_SIZES:
            raise ConfigError(f"model.size={self.cfg.size!r} is not valid for sora; valid: "
                              f"{', '.join(SORA_SIZES)}")
        if not self.cfg.allowed_seconds:
            raise ConfigError("model.allowed_seconds is empty: list the durations Sora accepts")

    def identity_settings(self) -> dict[str, Any]:
        return {**super().identity_settings(), "size": self.cfg.get("size")}

    def frame_size(self, frame: np.ndarray) -> tuple[int, int]:
        w, h = (int(v) for v in str(self.cfg.size).split("x"))
        return frame_size((w, h), Orientation(str(self.cfg.orientation)), frame)

    def client(self) -> Any:
        if self._client is None:
            import openai

            self._client = openai.AsyncOpenAI(api_key=self.api_key(),
                                              base_url=self.cfg.get("base_url") or None,
                                              max_retries=0,
                                              timeout=float(self.cfg.timeout_s))
        return self._client

    def classify(self, exc: Exception) -> CallError:
        import openai

        if isinstance(exc, openai.APIStatusError):
            headers = dict(exc.response.headers) if exc.response is not None else None
            return CallError(kind_for_status(exc.status_code), str(exc.message or exc),
                             exc.status_code, retry_after_seconds(headers))
        if isinstance(exc, openai.APITimeoutError):
            return CallError(CallErrorKind.timeout, str(exc))
        if isinstance(exc, openai.APIConnectionError):
            return CallError(CallErrorKind.connection, str(exc))
        return _transport_error(exc)

    @staticmethod
    def _quiet(call: Callable[[], Awaitable[T]]) -> Callable[[], Awaitable[T]]:
        """The SDK marks the Videos API deprecated (a warning per call): keep the log clean."""
        async def run() -> T:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", DeprecationWarning)
                pending = call()
            return await pending
        return run

    async def create(self, image_png: bytes, framing: Framing, seconds: int,
                     counter: list[int]) -> Any:
        client = self.client()
        size = f"{framing.width}x{framing.height}"
        return await self._step(self._quiet(lambda: client.videos.create(
            model=str(self.cfg.model_id), prompt=PROMPT,
            input_reference=("frame.png", image_png, "image/png"),
            seconds=str(seconds), size=size)), counter)

    def initial_state(self, job: Any) -> tuple[bool, Any]:
        return self._state(job), job

    @staticmethod
    def _state(video: Any) -> bool:
        if video.status == "completed":
            return True
        if video.status == "failed":
            err = video.error
            code = getattr(err, "code", "") or ""
            message = f"video {video.id} failed: {code} {getattr(err, 'message', '') or ''}"
            raise _Failed("bad_request" if policy_refusal(f"{code} {message}") else "server",
                          message.strip())
        return False

    async def poll(self, job: Any, counter: list[int]) -> tuple[bool, Any]:
        client = self.client()
        video = await self._step(self._quiet(lambda: client.videos.retrieve(job.id)), counter)
        return self._state(video), video

    async def download(self, job: Any, counter: list[int]) -> bytes:
        client = self.client()

        async def attempt() -> bytes:
            content = await self._quiet(lambda: client.videos.download_content(job.id))()
            data = content.content
            if not data:
                raise CallError(CallErrorKind.empty, f"empty download of video {job.id}")
            return bytes(data)

        return await self._step(attempt, counter)

    async def aclose(self) -> None:
        if self._client is not None:
            try:
                await self._client.close()
            finally:
                self._client = None


def _transport_error(exc: Exception) -> CallError:
    """An exception from the HTTP layer under an SDK (timeouts, refused connections), else a
    reply the SDK could not parse."""
    name = type(exc).__name__.lower()
    if "timeout" in name:
        return CallError(CallErrorKind.timeout, f"{type(exc).__name__}: {exc}")
    if "connect" in name or "network" in name or "protocol" in name or isinstance(exc, OSError):
        return CallError(CallErrorKind.connection, f"{type(exc).__name__}: {exc}")
    return CallError(CallErrorKind.malformed, f"{type(exc).__name__}: {exc}")


@hookimpl
def visphy_register_configs(config_store):
    config_store.store(group="model", name="schema_veo", node=VeoConfig)
    config_store.store(group="model", name="schema_sora", node=SoraConfig)


@hookimpl
def visphy_register_models(register):
    register("veo", VeoModel)
    register("sora", SoraModel)
