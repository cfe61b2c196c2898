"""The run's prefetch never sends a second first call for a scene a worker has already taken,
however slowly it looks at that scene's inputs (under load, a worker's own call could finish
before the prefetch's submission; the ledger then counted two calls for one scene)."""

from __future__ import annotations

import threading
from types import SimpleNamespace

import visphy_core.execute.prefetch as run_mod


def _services(submitted: list[str]):
    prompt = SimpleNamespace(frames=(1, 10), forecast_only=False)
    caller = SimpleNamespace(submit=lambda request: submitted.append(request))
    return SimpleNamespace(settings=SimpleNamespace(prompt=prompt), caller=caller)


def test_a_scene_taken_while_its_inputs_are_checked_is_not_prefetched(monkeypatch):
    scenes = [SimpleNamespace(scene_id=f"s{i}") for i in range(4)]
    looking, release = threading.Event(), threading.Event()

    def slow_sendable(scene, frames):
        if scene.scene_id == "s1":
            looking.set()
            assert release.wait(10)
        return True

    monkeypatch.setattr(run_mod, "_sendable", slow_sendable)
    monkeypatch.setattr(run_mod, "first_call",
                        lambda scene, services: SimpleNamespace(request=scene.scene_id))
    submitted: list[str] = []
    prefetch = run_mod._Prefetch(scenes, _services(submitted), window=2)
    first = threading.Thread(target=prefetch.advance, args=(0,))
    first.start()
    assert looking.wait(10)
    prefetch.advance(1)          # a second worker takes s1 and makes its own call
    release.set()
    first.join(10)
    assert "s1" not in submitted
    assert sorted(submitted) == ["s2", "s3"]


def test_scenes_ahead_are_prefetched_once_each(monkeypatch):
    monkeypatch.setattr(run_mod, "_sendable", lambda scene, frames: scene.scene_id != "s2")
    monkeypatch.setattr(run_mod, "first_call",
                        lambda scene, services: SimpleNamespace(request=scene.scene_id))
    scenes = [SimpleNamespace(scene_id=f"s{i}") for i in range(6)]
    submitted: list[str] = []
    prefetch = run_mod._Prefetch(scenes, _services(submitted), window=3)
    for position in range(6):
        prefetch.advance(position)
    # each scene once, ahead of its turn; s2's inputs are unsound, s0 is the first one taken
    assert submitted == ["s1", "s3", "s4", "s5"]


def test_nothing_is_submitted_once_the_run_stops_the_prefetch(monkeypatch):
    monkeypatch.setattr(run_mod, "_sendable", lambda scene, frames: True)
    monkeypatch.setattr(run_mod, "first_call",
                        lambda scene, services: SimpleNamespace(request=scene.scene_id))
    scenes = [SimpleNamespace(scene_id=f"s{i}") for i in range(6)]
    submitted: list[str] = []
    prefetch = run_mod._Prefetch(scenes, _services(submitted), window=2)
    prefetch.advance(0)
    prefetch.stop()               # the run was interrupted: workers may still take scenes
    prefetch.advance(1)
    prefetch.advance(2)
    assert submitted == ["s1", "s2"]
