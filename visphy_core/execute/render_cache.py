"""The render cache: a program's render under a contract, stored content-addressed by
everything that determines its frames (`render_key`), replayed when the same program is rendered
again, and never replayed for failures that depend on the time limit or the machine."""

from __future__ import annotations

import json
import os
import threading
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from visphy_core.api.engine import (
    Engine,
    FailureClass,
    Program,
    RenderContract,
    RenderFlag,
    RenderResult,
)
from visphy_core.infra.cache import Cache, CorruptEntry, content_key, read_json
from visphy_core.infra.errors import host_fault, one_line
from visphy_core.infra.secrets import redact, redact_obj
from visphy_core.infra.video import decode_video, encode_video, frame_digest

#: Render failures never replayed from the cache: they depend on the time limit or the machine.
UNCACHED_FAILURES = (FailureClass.TIMEOUT, FailureClass.INFRA_ERROR, FailureClass.RESOURCE_LIMIT)


@dataclass
class RenderOutcome:
    frames: np.ndarray | None
    failure: FailureClass | None
    error: str | None
    logs: list[str]
    frame_digests: list[str]
    video_path: Path | None
    cached: bool
    wall_s: float
    isolation: str | None = None
    flags: list[str] = field(default_factory=list)  # RenderFlag values (RenderResult.flags)
    partial_path: Path | None = None  # partial_clip: the frames before a runtime error (mp4)


#: Row flags that come from a render (`RenderFlag`): the row shows those of its last render.
RENDER_FLAGS = tuple(f.value for f in RenderFlag)
#: A render cache entry's files: its record, its clip and the partial clip of a failed render.
ENTRY_META, ENTRY_VIDEO, ENTRY_PARTIAL = "meta.json", "video.mp4", "partial.mp4"


def _safe_render(engine: Engine, program: Program, contract: RenderContract) -> RenderResult:
    """``engine.render``; an exception (an engine bug, a browser that will not start) is our
    side's failure: an ``infra_error`` result carrying the exception type and message."""
    try:
        return engine.render(program, contract)
    except Exception as exc:  # noqa: BLE001 - engines must not abort the run
        if host_fault(exc) is not None:  # the machine's fault: it stops the run (resumable)
            raise
        return RenderResult(frames=None, failure=FailureClass.INFRA_ERROR,
                            error=one_line(f"{type(exc).__name__}: {exc}")[:2000])


def render_key(engine: Engine, program: Program, contract: RenderContract) -> str:
    """The render cache's key: everything that determines a render's frames."""
    return content_key("render", engine.cache_identity(), program.digest, contract.key())


def render_cached(engine: Engine, program: Program, contract: RenderContract,
                  cache: Cache, memo: dict[str, RenderOutcome] | None = None) -> RenderOutcome:
    """Render through the content-addressed cache.

    ``memo``: one scene's clips by render key, so a program the scene renders twice (the
    privileged model's program is the reference program of its S) is rendered or decoded once;
    a clip from it counts as cached.

    Deterministic program failures (syntax or runtime errors, blank output...) are cached: the
    same program fails the same way. Timeouts, resource limits and infrastructure errors are not:
    they depend on the time limit and the machine, so they are rendered again next time. Error
    text and logs are redacted before they are cached. The render's flags and its partial clip
    (``partial.mp4``: the frames before a runtime error) are cached with it and replayed.
    """
    key = render_key(engine, program, contract)

    def parse(entry: Path) -> RenderOutcome:
        meta = read_json(entry / ENTRY_META)
        failure = FailureClass(meta["failure"]) if meta["failure"] else None
        if failure in UNCACHED_FAILURES:
            raise CorruptEntry(f"{failure.value} entries are never replayed")
        video = entry / ENTRY_VIDEO
        frames = None
        if failure is None:
            if not video.is_file():
                raise CorruptEntry(f"missing {video}")
            frames = decode_video(video)[0]
            if len(frames) != len(meta["frame_digests"]) or len(frames) != contract.n_frames:
                raise CorruptEntry(f"{video} has {len(frames)} frames, expected "
                                   f"{contract.n_frames}")
        partial = entry / ENTRY_PARTIAL
        if meta.get("partial_frames") and not partial.is_file():
            raise CorruptEntry(f"missing {partial}")
        return RenderOutcome(frames=frames, failure=failure, error=meta["error"],
                             logs=list(meta["logs"]), frame_digests=list(meta["frame_digests"]),
                             video_path=video if frames is not None else None, cached=True,
                             wall_s=float(meta["wall_s"]), isolation=meta.get("isolation"),
                             flags=[str(f) for f in meta.get("flags") or []],
                             partial_path=partial if meta.get("partial_frames") else None)

    if memo is not None and key in memo:
        return replace(memo[key], cached=True)

    def remember(outcome: RenderOutcome) -> RenderOutcome:
        if memo is not None and outcome.failure is None:
            memo[key] = outcome
        return outcome

    outcome = cache.load("render", key, parse)
    if outcome is not None:
        return remember(outcome)
    result = _safe_render(engine, program, contract)
    ok = result.failure is None and result.frames is not None
    failure = result.failure or (None if ok else FailureClass.INFRA_ERROR)
    partial = result.partial_frames if failure is not None else None
    if partial is not None and (len(partial) == 0 or partial.shape[1:] != (
            contract.height, contract.width, 3)):
        partial = None
    meta = {"failure": failure.value if failure else None,
            "error": redact(result.error), "logs": redact_obj(list(result.logs[-200:])),
            "wall_s": result.wall_s, "isolation": result.isolation,
            "frame_digests": [frame_digest(f) for f in result.frames] if ok else [],
            "flags": [str(f) for f in result.flags],
            "partial_frames": len(partial) if partial is not None else 0}
    if failure in UNCACHED_FAILURES:
        return RenderOutcome(frames=None, failure=failure, error=meta["error"], logs=meta["logs"],
                             frame_digests=[], video_path=None, cached=False,
                             wall_s=result.wall_s, isolation=result.isolation,
                             flags=meta["flags"])
    files: dict = {ENTRY_META: json.dumps(meta, indent=1)}
    here = f"{os.getpid()}-{threading.get_ident()}"  # scenes render on several threads
    tmp_video = cache.root / "tmp" / f"{key}.{here}.mp4"
    tmp_partial = cache.root / "tmp" / f"{key}.{here}.partial.mp4"
    if ok:
        encode_video(result.frames, tmp_video, contract.fps)
        files[ENTRY_VIDEO] = tmp_video
    if partial is not None:
        encode_video(partial, tmp_partial, contract.fps)
        files[ENTRY_PARTIAL] = tmp_partial
    try:
        entry = cache.put("render", key, files)
    finally:
        tmp_video.unlink(missing_ok=True)
        tmp_partial.unlink(missing_ok=True)
    # Read back what was stored: a fresh render and a cached one give the same decoded frames.
    outcome = parse(entry)
    outcome.cached = False
    return remember(outcome)
