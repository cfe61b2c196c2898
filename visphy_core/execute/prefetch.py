"""The run's model calls around its scenes (`visphy_core.execute.run`): the first call of the
scenes ahead started while earlier ones render (`_Prefetch`), the calls in flight waited for at
the end (their replies are cached), and the clients closed."""

from __future__ import annotations

import logging
import signal
import sys
import threading

from visphy_core.api.scene import Scene
from visphy_core.calls.generation import ModelCaller, get_service
from visphy_core.execute.pipeline import SceneServices, first_call

log = logging.getLogger("visphy.run")


class _Prefetch:
    """Starts the first model call of the next ``window`` scenes while earlier ones render.

    A scene is prefetched only after its inputs check out (`_sendable`: a ``data_error`` scene
    is never sent to the model); the pipeline later asks for the same request and joins the call
    in flight. Called by the scheduler's workers as they take scenes (thread-safe).
    """

    def __init__(self, scenes: list[Scene], services: SceneServices, window: int):
        self.scenes = scenes
        self.services = services
        self.window = window
        self.next = 0
        self._taken = -1  # the scheduler takes scenes in order: all up to here are taken
        self._stopped = False
        self._lock = threading.Lock()

    def stop(self) -> None:
        """No call is submitted after this (the run is ending: a call sent now would be neither
        waited for nor cached, and the next run would pay for it again)."""
        with self._lock:
            self._stopped = True

    def advance(self, position: int) -> None:
        """Called as scene ``position`` is taken: prefetch the scenes after it. A scene already
        taken by a worker is never prefetched (its pipeline makes its own call): the check and
        the submission hold the lock its dispatch takes, so a slow look at one scene's inputs
        cannot send a second call after that scene's own call has finished."""
        settings = self.services.settings
        frames = settings.prompt.frames[:1] if settings.prompt.forecast_only \
            else settings.prompt.frames
        with self._lock:
            self._taken = max(self._taken, position)
        while True:
            with self._lock:  # the scenes after ``position``: its own call is its own
                if self._stopped:
                    return
                self.next = max(self.next, position + 1)
                if self.next >= min(len(self.scenes), position + 1 + self.window):
                    return
                index = self.next
                scene = self.scenes[index]
                self.next += 1
            try:
                if not _sendable(scene, tuple(frames) or (1,)):
                    continue
                request = first_call(scene, self.services).request
                with self._lock:
                    if index > self._taken and not self._stopped:
                        self.services.caller.submit(request)
            except Exception:  # noqa: BLE001 - the pipeline classifies this scene itself
                continue


def _sendable(scene: Scene, key_frames: tuple[int, ...]) -> bool:
    """Whether a scene's inputs look sound enough to send it to the model ahead of its turn:
    what `Scene.check_inputs` checks, with the ground-truth clip probed (frame count and size
    from its header) instead of decoded, so each clip is decoded once, by its scene."""
    import av

    if scene.load_error:
        return False
    try:
        scene.detection, scene.spec, scene.trajectory  # noqa: B018 - read (and kept) now
        with av.open(str(scene.video_path)) as container:
            stream = container.streams.video[0]
            n, width, height = int(stream.frames), stream.width, stream.height
    except Exception:  # noqa: BLE001 - check_inputs names the fault when the scene runs
        return False
    c = scene.clip
    return (n == c.n_frames and n >= max(key_frames) and (width, height) == (c.width, c.height))


def _wait_for_calls(caller: ModelCaller) -> None:
    """Let the model calls in flight finish: each reply is cached on arrival, so a resumed run
    never pays for it again. A (further) SIGINT/SIGTERM abandons them."""
    pending = caller.pending()
    if not pending:
        return
    print(f"waiting for {pending} model call(s) in flight (their replies are cached for the "
          "next run; interrupt again to abandon them)", file=sys.stderr)
    abandon = threading.Event()
    previous = {}
    if threading.current_thread() is threading.main_thread():
        previous = {sig: signal.signal(sig, lambda s, f: abandon.set())
                    for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        while caller.pending() and not abandon.is_set():
            caller.wait_pending(0.2)
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


def _close_calls(services: SceneServices) -> None:
    """Close the clients of the model, the reference writer and the judges."""
    for thing in (services.model, services.references.model if services.references else None):
        if thing is not None:
            try:
                get_service().run(thing.aclose())
            except Exception as exc:  # noqa: BLE001
                log.warning("closing %s failed: %s", thing.name, exc)
    if services.judges is not None:
        services.judges.close()
