"""Provider storms never break a run or lose its rows: whole runs on the mini split (4 scenes)
through each provider's real SDK against its loopback fake server, whose replies are scripted per
scene (429s with ``Retry-After``, 500/503s, replies slower than ``model.timeout_s``).

* A burst shorter than the retry budget is absorbed, for each provider: the rows equal those of
  a clean run.
* A storm longer than it ends in ``model_error`` rows that name the error kind; the run still
  writes every row, says on its last stderr line what failed and what to do, and rerunning the
  same command once the storm is over gives the clean run's rows, calling the provider again for
  the failed scenes only.
* Retries are counted on the server: each visphy attempt is one HTTP request (the SDKs' own
  retries are off), there are never more than ``model.retries.max_attempts``, a ``Retry-After``
  is waited for, and one beyond ``max_retry_after_s`` fails the call at once.

Every run shares one home and its cache (the clean run renders and scores the four programs,
later runs find them there); each scenario sets its own ``model.seed``, part of the reply cache's
identity, so no scenario is answered from another's cached replies.
"""

from __future__ import annotations

import base64
import io
import json
import shutil
import threading
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from PIL import Image

from conftest import with_fast_metrics
from visphy_plugins.testing.fake_anthropic import FakeAnthropicServer
from visphy_plugins.testing.fake_gemini import FakeGeminiServer
from visphy_plugins.testing.fake_openai import FakeOpenAIServer
from visphy_plugins.testing.fake_server import Behaviour, Recorded, delay, ok, status
from visphy_plugins.testing.replies import HTML_PROGRAM, reply

pytestmark = pytest.mark.browser

#: model config -> (fake server class, base-url suffix, key variable)
PROVIDERS = {"gpt41": (FakeOpenAIServer, "/v1", "OPENAI_API_KEY"),
             "claude": (FakeAnthropicServer, "", "ANTHROPIC_API_KEY"),
             "gemini25pro": (FakeGeminiServer, "", "GEMINI_API_KEY")}
#: per attempt (2 s: a loaded machine never times out a good reply); the fake's slow replies
#: take `SLOW_S`, so each of them is a client timeout
TIMEOUT_S = 2
SLOW_S = TIMEOUT_S + 1.5
COMPARED = ("scene_id", "model_success", "system_success", "fallback", "attempts",
            "failure_class", "first_failure_class", "frame_digests")
PROBLEM_LINE = "failed on provider errors"


def program_reply(index: int) -> str:
    """A reply whose program is the scene's own (the ball starts lower for each scene), so a
    reply answered to the wrong scene, or a late reply used after its timeout, changes a row."""
    start = "let y = 8, v = 0;"
    assert start in HTML_PROGRAM
    return reply("html").replace(start, f"let y = {8 + 6 * index}, v = 0;")


def first_png(body: object) -> bytes | None:
    """The first base64 PNG anywhere in a request body, whatever the wire format (an OpenAI data
    URL, an Anthropic image source, a Gemini inlineData part)."""
    if isinstance(body, dict):
        body = list(body.values())
    if isinstance(body, list):
        for item in body:
            found = first_png(item)
            if found is not None:
                return found
        return None
    if isinstance(body, str):
        data = body.split("base64,", 1)[-1]
        if data.startswith("iVBOR"):
            data = data.replace("-", "+").replace("_", "/")
            return base64.b64decode(data + "=" * (-len(data) % 4))
    return None


class Weather:
    """The fake provider's ``default``: what it does to each scene's requests, the scene told by
    the first key frame the request carries. ``bursts[scene]`` are the first replies the scene
    gets (then good ones); ``storms[scene]`` is what it gets for every request until `clear`.
    Every request is logged under its scene, with its arrival time."""

    def __init__(self, scenes: list):
        self.frames = [(s.scene_id, s.key_frame(1)) for s in scenes]
        self.index = {s.scene_id: i for i, s in enumerate(scenes)}
        self.bursts: dict[str, list[Behaviour]] = {}
        self.storms: dict[str, Behaviour] = {}
        self.log: dict[str, list[float]] = defaultdict(list)
        self._known: dict[bytes, str] = {}
        self._lock = threading.Lock()

    def scene_of(self, req: Recorded) -> str:
        png = first_png(req.json)
        assert png is not None, f"a request without a key frame: {req.path}"
        if png not in self._known:
            pixels = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))
            (sid,) = [sid for sid, frame in self.frames if np.array_equal(pixels, frame)]
            self._known[png] = sid
        return self._known[png]

    def __call__(self, req: Recorded) -> Behaviour:
        sid = self.scene_of(req)
        with self._lock:
            self.log[sid].append(req.time)
            if sid in self.storms:
                return self.storms[sid]
            burst = self.bursts.get(sid)
            if burst:
                return burst.pop(0)
        return ok(program_reply(self.index[sid]))

    def counts(self) -> dict[str, int]:
        with self._lock:
            return {sid: len(self.log.get(sid, [])) for sid, _ in self.frames}

    def clear(self) -> None:
        with self._lock:
            self.bursts.clear()
            self.storms.clear()

    def late(self) -> Behaviour:
        """A reply that comes after the client gave up: another scene's program, so the row
        would show it if it were ever used."""
        return delay(SLOW_S, ok(program_reply(len(self.frames))))


# --------------------------------------------------------------------------- running

@pytest.fixture(scope="module")
def scenes(mini_scenes) -> list:
    assert len(mini_scenes) == 4
    return list(mini_scenes)


@pytest.fixture(scope="module")
def home(tmp_path_factory, mini_root) -> Path:
    home = tmp_path_factory.mktemp("storms")
    shutil.copytree(mini_root, home / "data" / mini_root.name)
    return home


@pytest.fixture(scope="module", autouse=True)
def keys():
    with pytest.MonkeyPatch.context() as mp:
        for _, _, key in PROVIDERS.values():
            mp.setenv(key, f"fake-{key.lower()}")
        yield


def run(home: Path, server, model: str, seed: int, max_attempts: int, *extra: str) -> dict:
    """One run of ``model`` against ``server``; the same arguments are the same command."""
    from visphy_core.config.check import compose
    from visphy_core.execute.run import run_experiment

    _, suffix, _ = PROVIDERS[model]
    cfg = compose(list(with_fast_metrics((
        f"paths.root={home}", "tracking=none", "run.progress=false", "dataset=mini",
        "engine=threejs", f"model={model}", f"model.base_url={server.url}{suffix}",
        f"model.seed={seed}", f"model.timeout_s={TIMEOUT_S}",
        f"model.retries.max_attempts={max_attempts}", "model.retries.base_delay_s=0.01",
        "model.retries.max_delay_s=0.05",
        # room for every scene's call however often a 429 halves the limit (at most once a
        # second, from 16): a retry waits for its backoff or Retry-After, never for a slot
        "model.concurrency.initial=16", "model.concurrency.maximum=16", *extra))))
    return run_experiment(cfg)


def rows_of(summary: dict) -> dict[str, dict]:
    """The run's rows by scene (one per scene, or the test fails), all columns."""
    run_dir = Path(summary["run_dir"])
    rows = [json.loads(line) for line in (run_dir / "results.jsonl").read_text().splitlines()]
    ids = [r["scene_id"] for r in rows]
    assert len(ids) == len(set(ids)), f"duplicate rows: {ids}"
    assert sorted(pd.read_parquet(run_dir / "results.parquet")["scene_id"]) == sorted(ids)
    assert summary["status"] == "finished" and summary["n_scenes"] == len(rows)
    return {r["scene_id"]: r for r in rows}


def comparable(rows: dict[str, dict]) -> dict[str, dict]:
    return {sid: {k: v for k, v in r.items() if k in COMPARED or k.startswith("score_")}
            for sid, r in rows.items()}


def response_of(summary: dict, sid: str) -> dict:
    return json.loads((Path(summary["run_dir"]) / "scenes" / sid / "response.json").read_text())


@pytest.fixture(scope="module")
def clean(home, scenes) -> dict[str, dict]:
    """The rows of a run without faults (OpenAI; every provider gets the same replies)."""
    weather = Weather(scenes)
    with FakeOpenAIServer(default=weather) as server:
        summary = run(home, server, "gpt41", 0, 4)
    rows = rows_of(summary)
    assert len(rows) == 4 and all(r["model_success"] for r in rows.values())
    assert weather.counts() == dict.fromkeys(rows, 1)
    scores = {r["score_psnr"] for r in rows.values()}
    assert len(scores) == 4  # each scene's own program: a mix-up would show
    return comparable(rows)


# --------------------------------------------------------------------------- bursts

@pytest.mark.parametrize("model", list(PROVIDERS))
def test_bursts_shorter_than_the_retry_budget_leave_no_trace(home, scenes, clean, model,
                                                            capfd):
    """429s (one with a 0.4 s ``Retry-After``), 500/503s and client timeouts, interleaved with
    good replies, each scene failing at most ``max_attempts - 1`` times: every scene gets its
    reply, the rows are the clean run's, and each failure cost exactly one more request."""
    cls, _, _ = PROVIDERS[model]
    weather = Weather(scenes)
    s0, s1, s2, s3 = (s.scene_id for s in scenes)
    weather.bursts = {
        s0: [status(429, {"Retry-After": "0"}), status(429, {"Retry-After": "0.4"})],
        s1: [status(500), status(503)],
        s2: [weather.late()],
        s3: [status(503), weather.late(), status(429, {"Retry-After": "0"})],  # the 4th works
    }
    capfd.readouterr()
    with cls(default=weather) as server:
        summary = run(home, server, model, 10 + list(PROVIDERS).index(model), 4)
        assert server.count() == 12
    rows = rows_of(summary)
    assert comparable(rows) == clean
    expected = {s0: 3, s1: 3, s2: 2, s3: 4}
    assert weather.counts() == expected
    for sid, n in expected.items():
        response = response_of(summary, sid)
        assert response["error"] is None and not response["cached"]
        assert response["transport_attempts"] == n  # one HTTP request per visphy attempt
    _, second, third = weather.log[s0]
    assert third - second >= 0.4  # the Retry-After was waited for
    assert summary["usage"]["generate"]["calls"] == 4
    assert summary["usage"]["generate"]["errors"] == 0
    assert summary["failures"]["model"] == {}
    assert PROBLEM_LINE not in capfd.readouterr().err


# --------------------------------------------------------------------------- storms

def test_a_storm_longer_than_the_retry_budget_then_a_rerun(home, scenes, clean, capfd):
    """Three scenes' requests fail every time (429, 503, a timeout): those rows are model_error
    naming the kind, after exactly ``max_attempts`` requests each; the last stderr line says so
    and how to recover. The storm over, the same command gives the clean rows, calling the
    provider once more for each failed scene and never for the one that had its reply.

    One provider: what is provider-specific in a lasting failure (each SDK's exception turned
    into a kind) is covered per provider by tests/test_provider_*.py; the rest is the run's."""
    weather = Weather(scenes)
    s0, s1, s2, s3 = (s.scene_id for s in scenes)
    weather.storms = {s0: status(429, {"Retry-After": "0"}), s1: status(503),
                      s2: weather.late()}
    capfd.readouterr()
    with FakeOpenAIServer(default=weather) as server:
        summary = run(home, server, "gpt41", 20, 3)
        err = capfd.readouterr().err
        rows = rows_of(summary)
        assert len(rows) == 4
        assert weather.counts() == {s0: 3, s1: 3, s2: 3, s3: 1}
        kinds = {s0: ("rate_limit", "rate_limit HTTP 429"), s1: ("server", "server HTTP 503"),
                 s2: ("timeout", "timeout")}
        for sid, (kind, detail) in kinds.items():
            row = rows[sid]
            assert row["failure_class"] == "model_error" and not row["model_success"]
            assert row["fallback"] and row["attempts"] == 1 and row["model_calls"] == 1
            assert row["failure_detail"].startswith(detail), row["failure_detail"]
            response = response_of(summary, sid)
            assert response["error_kind"] == kind and response["transport_attempts"] == 3
        assert comparable(rows)[s3] == clean[s3]
        assert summary["failures"]["model"] == {"model_error": 3}
        assert summary["usage"]["generate"]["errors"] == 3
        assert err.strip().splitlines()[-1] == (
            "3 scenes failed on provider errors (rate_limit ×1, server ×1, timeout ×1): rerun "
            "the same command to retry them; replies already received are cached")

        weather.clear()  # the storm is over
        again = run(home, server, "gpt41", 20, 3)
        err = capfd.readouterr().err
    assert Path(again["run_dir"]) != Path(summary["run_dir"])  # a finished run is not resumed
    assert comparable(rows_of(again)) == clean
    assert weather.counts() == {s0: 4, s1: 4, s2: 4, s3: 1}  # s3's reply came from the cache
    usage = again["usage"]["generate"]
    assert usage["calls"] == 3 and usage["cache_hits"] == 1 and usage["errors"] == 0
    assert PROBLEM_LINE not in err


def test_a_retry_after_beyond_the_cap_fails_the_call_at_once(home, scenes, clean, capfd):
    """A provider asking for an hour's pause is not waited for (``max_retry_after_s``): one
    request, a rate_limit row saying why, and the run goes on."""
    weather = Weather(scenes[:1])
    sid = scenes[0].scene_id
    weather.storms = {sid: status(429, {"Retry-After": "3600"})}
    capfd.readouterr()
    start = time.monotonic()
    with FakeOpenAIServer(default=weather) as server:
        summary = run(home, server, "gpt41", 30, 6, "dataset.limit=1",
                      "model.retries.max_retry_after_s=5")
    assert time.monotonic() - start < 60
    assert weather.counts() == {sid: 1}
    (row,) = rows_of(summary).values()
    assert row["failure_class"] == "model_error"
    assert row["failure_detail"].startswith("rate_limit HTTP 429")
    assert "Retry-After 3600 s exceeds 5 s" in row["failure_detail"]
    assert capfd.readouterr().err.strip().splitlines()[-1].startswith(
        "1 scene failed on provider errors (rate_limit ×1): rerun the same command")


def test_the_provider_line_promises_a_fix_only_for_transient_kinds():
    """The line's advice follows the kinds: a rerun retries the transient ones, not a refused
    request or an error that names no kind; a re-score or a merge sends the reader to the
    command of the run the rows come from."""
    from visphy_core.execute.console import provider_failures_line
    from visphy_core.results.row import SceneResult

    def row(sid: str, cls: str | None, detail: str | None = None) -> SceneResult:
        return SceneResult(scene_id=sid, dim="2d", difficulty=None, failure_class=cls,
                           failure_detail=detail)

    rows = [row("a", None), row("b", "runtime_error", "ReferenceError: x"),
            row("c", "model_error", "server HTTP 502: bad gateway"),
            row("d", "model_error", "timeout: no reply within 2 s")]
    assert provider_failures_line({}, rows[:2]) is None
    assert provider_failures_line({}, rows) == (
        "2 scenes failed on provider errors (server ×1, timeout ×1): rerun the same command to "
        "retry them; replies already received are cached")
    rows += [row("e", "model_error", "bad_request HTTP 400: Unsupported parameter"),
             row("f", "model_error", "no recorded reply for f (looked for f.txt)")]
    assert provider_failures_line({}, rows) == (
        "4 scenes failed on provider errors (bad_request ×1, other ×1, server ×1, timeout ×1): "
        "rerun the same command to retry the 2 transient one(s); replies already received are "
        "cached; bad_request, other: not a transient kind, see each row's failure_detail")
    assert "rerun the command of the run these rows come from to retry" in \
        provider_failures_line({"rescored_from": "runs/x"}, rows[:4])
