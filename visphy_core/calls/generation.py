"""Model and judge calls: one asyncio loop per process, the response cache and the ledger.

API adapters are async (their SDKs' async clients). `GenerationService` runs one event loop on a
background thread for every call of the process, so calls for many scenes can be in flight while
the main thread renders and scores (the run loop submits the first call of upcoming scenes ahead
of time: `ModelCaller.submit`). Each provider endpoint bounds its own concurrency
(`visphy_core.calls.retry.AdaptiveLimiter`).

`ModelCaller` is the one path from the pipeline to a model: it answers from the content-addressed
cache when the same request was answered before (zero calls on a re-run), checks the run's cost
cap before a new call, records every call in the run's ledger, stores each successful reply in
the cache right after it arrives (a run killed later never pays for it again), and shares one
call between identical requests (a prefetched first call and the pipeline's own request for it).
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import json
import threading
from dataclasses import asdict
from pathlib import Path
from typing import Any, Awaitable, Coroutine, TypeVar

from visphy_core.api.model import Model, ModelRequest, ModelResponse
from visphy_core.calls.usage import CallRecord, UsageLedger
from visphy_core.infra.cache import Cache, CorruptEntry, read_json
from visphy_core.infra.secrets import redact, redact_obj

T = TypeVar("T")
#: A cached reply's video, in its cache entry (beside ``response.json``).
ENTRY_VIDEO = "video.mp4"


class GenerationService:
    """An event loop on a daemon thread; coroutines are submitted from any thread."""

    def __init__(self) -> None:
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()

    @property
    def loop(self) -> asyncio.AbstractEventLoop:
        with self._lock:
            if self._loop is None or self._loop.is_closed():
                loop = asyncio.new_event_loop()
                ready = threading.Event()

                def serve() -> None:
                    asyncio.set_event_loop(loop)
                    loop.call_soon(ready.set)
                    loop.run_forever()

                self._thread = threading.Thread(target=serve, name="visphy-calls", daemon=True)
                self._thread.start()
                ready.wait()
                self._loop = loop
            return self._loop

    def submit(self, coro: Coroutine[Any, Any, T]) -> concurrent.futures.Future[T]:
        return asyncio.run_coroutine_threadsafe(coro, self.loop)

    def run(self, coro: Coroutine[Any, Any, T]) -> T:
        return self.submit(coro).result()

    def close(self) -> None:
        with self._lock:
            loop, thread = self._loop, self._thread
            self._loop = self._thread = None
        if loop is None:
            return

        async def drain() -> None:
            tasks = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
            for t in tasks:
                t.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)

        try:
            asyncio.run_coroutine_threadsafe(drain(), loop).result(timeout=10)
        except Exception:  # noqa: BLE001 - closing must not fail the run
            pass
        loop.call_soon_threadsafe(loop.stop)
        if thread is not None:
            thread.join(timeout=10)
        loop.close()


_SERVICE: GenerationService | None = None


def get_service() -> GenerationService:
    global _SERVICE
    if _SERVICE is None:
        _SERVICE = GenerationService()
    return _SERVICE


def run_async(awaitable: Awaitable[T]) -> T:
    """Run a coroutine on the process's call loop and wait for it (for blocking callers)."""

    async def wrap() -> T:
        return await awaitable

    return get_service().run(wrap())


def _response_from_entry(entry: Path) -> ModelResponse:
    data = read_json(entry / "response.json")
    response = ModelResponse(**data)
    if not isinstance(response.text, str):
        raise CorruptEntry("response text is not a string")
    if response.video_path is not None:
        video = entry / response.video_path
        if not video.is_file():
            raise CorruptEntry(f"missing {video}")
        response.video_path = str(video)
    return response


def provider_of(model: Any) -> tuple[str | None, str | None]:
    cfg = getattr(model, "cfg", None)
    get = getattr(cfg, "get", None)
    if get is None:
        return None, None
    return get("provider", None), get("model_id", None)


class ModelCaller:
    """The pipeline's path to one model: cache, cost cap, ledger, shared in-flight calls."""

    def __init__(self, model: Model, cache: Cache, ledger: UsageLedger,
                 service: GenerationService | None = None):
        self.model = model
        self.cache = cache
        self.ledger = ledger
        self.service = service or get_service()
        self._identity = model.identity()
        self._futures: dict[str, concurrent.futures.Future] = {}
        self._lock = threading.Lock()

    def key(self, request: ModelRequest) -> str:
        return request.cache_key(self._identity)

    def submit(self, request: ModelRequest) -> concurrent.futures.Future:
        """Start (or join) the call for ``request``; the future gives (response, cached) or
        raises `CostCapReached`."""
        key = self.key(request)
        with self._lock:
            fut = self._futures.get(key)
            if fut is None:
                fut = self.service.submit(self._call(request, key))
                self._futures[key] = fut
            return fut

    def call(self, request: ModelRequest) -> tuple[ModelResponse, bool]:
        """The reply to ``request`` (blocking); the shared future is released afterwards."""
        key = self.key(request)
        fut = self.submit(request)
        try:
            return fut.result()
        finally:
            with self._lock:
                if self._futures.get(key) is fut:
                    del self._futures[key]

    def pending(self) -> int:
        with self._lock:
            return sum(not f.done() for f in self._futures.values())

    def wait_pending(self, timeout_s: float | None = None) -> None:
        """Wait for the calls in flight (prefetched ones the run no longer needs included):
        each reply is cached when it arrives, so a resumed run does not pay for it again."""
        with self._lock:
            futures = list(self._futures.values())
        concurrent.futures.wait(futures, timeout=timeout_s)

    def _record(self, request: ModelRequest, response: ModelResponse, cached: bool,
                ticket: int | None = None) -> None:
        provider, model_id = provider_of(self.model)
        self.ledger.record(CallRecord(
            stage=request.stage, scene_id=request.scene_id, caller=self.model.name,
            provider=provider, model_id=response.model_id or model_id, cached=cached,
            ok=response.error is None, cost_usd=response.cost_usd, latency_s=response.latency_s,
            transport_attempts=0 if cached else response.transport_attempts,
            error_kind=response.error_kind, usage=dict(response.usage)), ticket)

    async def _call(self, request: ModelRequest, key: str) -> tuple[ModelResponse, bool]:
        cached = self.cache.load("response", key, _response_from_entry)
        if cached is not None:
            self._record(request, cached, cached=True)
            return cached, True
        ticket = self.ledger.reserve()  # raises CostCapReached: no call is made
        try:
            response = await self.model.agenerate(request)
        except BaseException:
            self.ledger.release(ticket)
            raise
        response.prompt_version = response.prompt_version or request.prompt_version
        response.error = redact(response.error)
        # a reply that echoes a secret (a hostile provider) is redacted before anything sees
        # it, so the live run and one resumed from the cache see the same text
        response.text = redact(response.text) or ""
        self._record(request, response, cached=False, ticket=ticket)
        if response.error is None:  # provider errors are not cached: a later run may succeed
            self._store(key, response)
        return response, False

    def _store(self, key: str, response: ModelResponse) -> None:
        data = asdict(response)
        data["raw"] = redact_obj(data.get("raw") or {})
        files: dict[str, Any] = {}
        if response.video_path:
            files[ENTRY_VIDEO] = Path(response.video_path)
            data["video_path"] = ENTRY_VIDEO
        files["response.json"] = json.dumps(data, default=str)
        entry = self.cache.put("response", key, files)
        if response.video_path:
            response.video_path = str(entry / ENTRY_VIDEO)
