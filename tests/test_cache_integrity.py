"""Cache integrity: every entry carries its payload digests, verified on every read; a corrupt,
legacy or unparseable entry is reported once (path named), dropped and recomputed, never served.
Timeouts, resource limits and infrastructure errors are never replayed; ``run.cache=false``
recomputes, returns and stores the fresh result."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from visphy_core.api.engine import Engine, FailureClass, Program, RenderContract, RenderResult
from visphy_core.execute.pipeline import render_cached
from visphy_core.infra.cache import Cache, content_key

# --------------------------------------------------------------------------- unit level

def test_entries_carry_digests_and_a_flipped_byte_is_a_miss(tmp_path, caplog):
    cache = Cache(tmp_path)
    key = content_key("x")
    entry = cache.put("render", key, {"meta.json": "{}", "video.mp4": b"\x00" * 100})
    marker = json.loads((entry / ".complete").read_text())
    assert set(marker["files"]) == {"meta.json", "video.mp4"}
    assert cache.get("render", key) == entry
    data = bytearray((entry / "video.mp4").read_bytes())
    data[50] ^= 0xFF
    (entry / "video.mp4").write_bytes(bytes(data))
    with caplog.at_level("WARNING", logger="visphy.cache"):
        assert cache.get("render", key) is None
    assert not entry.exists()  # dropped
    assert str(entry) in caplog.text and "digest mismatch" in caplog.text
    assert cache.stats()["render"] == {"hits": 1, "misses": 1, "dropped": 1}


@pytest.mark.parametrize("damage", ["missing_file", "legacy_marker", "garbage_marker",
                                    "extra_file"])
def test_damaged_or_legacy_entries_are_dropped(tmp_path, damage):
    cache = Cache(tmp_path)
    key = content_key(damage)
    entry = cache.put("score", key, {"value.json": json.dumps({"value": 1.0})})
    if damage == "missing_file":
        (entry / "value.json").unlink()
    elif damage == "legacy_marker":   # entries written before digests existed
        (entry / ".complete").write_text("")
    elif damage == "garbage_marker":
        (entry / ".complete").write_bytes(os.urandom(64))
    else:
        (entry / "planted.json").write_text("{}")
    assert cache.get("score", key) is None
    assert len(cache.warnings) == 1 and str(entry) in cache.warnings[0]
    assert not entry.exists()


def test_an_unparseable_payload_with_valid_digests_is_dropped_by_load(tmp_path):
    """Digests catch changes after writing; `Cache.load` also catches a payload that was
    stored broken (random bytes): dropped, a miss, no exception."""
    from visphy_core.infra.cache import read_json

    cache = Cache(tmp_path)
    key = content_key("r")
    entry = cache.put("response", key, {"response.json": os.urandom(200)})
    assert cache.load("response", key, lambda e: read_json(e / "response.json")) is None
    assert not entry.exists()
    assert "response.json" in cache.warnings[0] and str(entry) in cache.warnings[0]
    assert cache.stats()["response"] == {"hits": 0, "misses": 1, "dropped": 1}


def test_put_replaces_an_existing_entry(tmp_path):
    cache = Cache(tmp_path, enabled=False)
    key = content_key("k")
    cache.put("score", key, {"value.json": '{"value": 1}'})
    entry = cache.put("score", key, {"value.json": '{"value": 2}'})
    assert (entry / "value.json").read_text() == '{"value": 2}'
    assert Cache(tmp_path).get("score", key) == entry  # and it verifies
    assert not [p for p in entry.parent.iterdir() if p.name.startswith(".")]


class FakeEngine(Engine):
    """Times out under a 5 s limit, renders a moving square otherwise; counts renders."""

    name, language, version = "fake", "html", "1"

    def __init__(self, failure=None):
        super().__init__()
        self.renders = 0
        self.failure = failure

    def extract(self, text):
        return Program("html", text)

    def validate(self, program):
        pass

    def render(self, program, contract):
        self.renders += 1
        if self.failure is not None:
            return RenderResult(frames=None, failure=self.failure, error="boom")
        if contract.timeout_s < 5:
            return RenderResult(frames=None, failure=FailureClass.TIMEOUT, error="timed out")
        frames = np.zeros((contract.n_frames, contract.height, contract.width, 3), np.uint8)
        for k in range(contract.n_frames):
            frames[k, 8:16, 2 * k:2 * k + 8] = 255
        return RenderResult(frames=frames, wall_s=0.1, isolation="test")

    def program_from_spec(self, scene):
        raise NotImplementedError


def _contract(timeout_s):
    return RenderContract(fps=5, n_frames=6, width=32, height=32, timeout_s=timeout_s)


def test_a_timeout_at_1s_is_not_replayed_at_a_larger_limit(tmp_path):
    cache, engine, program = Cache(tmp_path), FakeEngine(), Program("html", "<p>x</p>")
    first = render_cached(engine, program, _contract(1), cache)
    assert first.failure is FailureClass.TIMEOUT and not first.cached
    second = render_cached(engine, program, _contract(60), cache)
    assert engine.renders == 2 and second.failure is None and len(second.frames) == 6
    third = render_cached(engine, program, _contract(60), cache)
    assert engine.renders == 2 and third.cached and third.frame_digests == second.frame_digests


@pytest.mark.parametrize("failure, replayed", [
    (FailureClass.TIMEOUT, False), (FailureClass.INFRA_ERROR, False),
    (FailureClass.RESOURCE_LIMIT, False), (FailureClass.RUNTIME_ERROR, True),
    (FailureClass.SYNTAX_ERROR, True)])
def test_only_deterministic_failures_are_replayed(tmp_path, failure, replayed):
    cache, engine, program = Cache(tmp_path), FakeEngine(failure), Program("html", "x")
    render_cached(engine, program, _contract(60), cache)
    again = render_cached(engine, program, _contract(60), cache)
    assert again.failure is failure
    assert again.cached is replayed and engine.renders == (1 if replayed else 2)


def test_an_engine_exception_is_an_uncached_infra_error(tmp_path):
    class Exploding(FakeEngine):
        def render(self, program, contract):
            self.renders += 1
            raise RuntimeError("browser went away")

    cache, engine = Cache(tmp_path), Exploding()
    out = render_cached(engine, Program("html", "x"), _contract(60), cache)
    assert out.failure is FailureClass.INFRA_ERROR
    assert "RuntimeError: browser went away" in out.error
    render_cached(engine, Program("html", "x"), _contract(60), cache)
    assert engine.renders == 2


def test_a_truncated_cached_video_is_recomputed(tmp_path):
    """A video cut short (with its digest rewritten to match) still fails to parse: dropped."""
    cache, engine, program = Cache(tmp_path), FakeEngine(), Program("html", "y")
    fresh = render_cached(engine, program, _contract(60), cache)
    entry = fresh.video_path.parent
    video = entry / "video.mp4"
    video.write_bytes(video.read_bytes()[: video.stat().st_size // 3])
    files = {p.name: p.read_bytes() for p in entry.iterdir() if p.name != ".complete"}
    cache.put("render", content_key("render", engine.cache_identity(), program.digest,
                                    _contract(60).key()), files)  # valid digests, bad payload
    again = render_cached(engine, program, _contract(60), cache)
    assert engine.renders == 2 and not again.cached
    assert again.frame_digests == fresh.frame_digests
    assert any("video.mp4" in w for w in cache.warnings)


# --------------------------------------------------------------------------- whole runs


@pytest.fixture
def home(tmp_path, mini_root):
    home = tmp_path / "home"
    shutil.copytree(mini_root, home / "data" / mini_root.name)
    return home


def _run(home: Path, *overrides: str) -> tuple[dict, dict]:
    from visphy_core.config.check import compose
    from visphy_core.execute.run import run_experiment

    cfg = compose([f"paths.root={home}", "dataset.limit=1", "tracking=none",
                   "run.progress=false", "model=oracle", "engine=threejs",
                   "metrics.names=[psnr,ssim]", "metrics.spec_track=false",
                   "metrics.variance_norm=false", *overrides])
    summary = run_experiment(cfg)
    row = json.loads((Path(summary["run_dir"]) / "results.jsonl").read_text().splitlines()[0])
    return summary, row


def _entries(home: Path, kind: str, name: str) -> list[Path]:
    return sorted((home / "cache" / kind).glob(f"*/*/{name}"))


@pytest.fixture
def clean(home):
    return _run(home)


@pytest.mark.browser
def test_flipped_video_bytes_are_recomputed_with_correct_scores(home, clean):
    s1, row1 = clean
    assert row1["model_success"] and row1["score_psnr"] > 30
    (video,) = _entries(home, "render", "video.mp4")
    data = bytearray(video.read_bytes())
    rng = np.random.default_rng(0)
    for i in rng.choice(np.arange(len(data) // 4, len(data)), 64, replace=False):
        data[i] ^= 0xFF
    video.write_bytes(bytes(data))
    s2, row2 = _run(home)
    assert s2["cache"]["render"] == {"hits": 0, "misses": 1, "dropped": 1}
    assert row2["score_psnr"] == pytest.approx(row1["score_psnr"], abs=1e-9)
    assert row2["frame_digests"] == row1["frame_digests"] and not row2["render_cached"]
    assert any(str(video.parent) in w for w in s2["cache_warnings"])


@pytest.mark.browser
def test_an_edited_cached_score_is_recomputed(home, clean):
    s1, row1 = clean
    entries = _entries(home, "score", "value.json")
    assert len(entries) == 6  # psnr and ssim, each unaligned, aligned and paper
    for value in entries:
        value.write_text(json.dumps({"value": 99.0}))
    s2, row2 = _run(home)
    for col in ("psnr", "ssim", "psnr.aligned", "paper.ssim"):
        assert row2[f"score_{col}"] == pytest.approx(row1[f"score_{col}"], abs=1e-9)
    assert s2["cache"]["score"]["dropped"] == 6 and s2["cache"]["render"]["hits"] == 1


@pytest.mark.browser
def test_random_bytes_in_a_json_entry_are_recomputed_and_named(home, clean, capsys):
    s1, row1 = clean
    (response,) = _entries(home, "response", "response.json")
    response.write_bytes(os.urandom(300))
    (meta,) = _entries(home, "render", "meta.json")
    meta.write_bytes(os.urandom(300))
    s2, row2 = _run(home)  # no UnicodeDecodeError
    assert row2["model_success"] and row2["score_psnr"] == pytest.approx(row1["score_psnr"])
    assert row2["model_calls"] == 1 and not row2["response_cached"]
    warnings = "\n".join(s2["cache_warnings"])
    assert str(response.parent) in warnings and str(meta.parent) in warnings
    assert len(s2["cache_warnings"]) == 2  # each reported once


@pytest.mark.browser
def test_cache_false_returns_fresh_results_and_replaces_the_entry(home, clean):
    from visphy_core.infra.cache import Cache

    s1, row1 = clean
    cache = Cache(home / "cache")
    planted = []
    for value in _entries(home, "score", "value.json"):
        key = value.parent.name  # a stale entry with valid digests (as an old run left it)
        cache.put("score", key, {"value.json": json.dumps({"value": -1.0})})
        planted.append(value)
    stale, _ = _run(home)
    assert stale["metrics"]["psnr"]["mean_model_success"] == -1.0  # served when enabled ...
    s2, row2 = _run(home, "run.cache=false")
    assert row2["score_psnr"] == pytest.approx(row1["score_psnr"])  # ... never with cache=false
    assert not row2["render_cached"] and not row2["response_cached"]
    for value in planted:  # and the fresh value replaced the stale entry
        assert json.loads(value.read_text())["value"] != -1.0
    s3, row3 = _run(home)
    assert row3["score_psnr"] == pytest.approx(row1["score_psnr"]) and row3["render_cached"]
