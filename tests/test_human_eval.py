"""``rate``: the model-blind rating page, driven in headless Chromium over a real oracle run.

One module-scoped oracle run (two mini scenes) feeds a rating server started in-process on a
free port; a real Chromium (Playwright, Debian's binary) plays both clips, rates one item with the
mouse, and after a restart of the server, as the same rater, resumes at the other item and rates
it with the keyboard. Everything the browser receives is checked for the model's and the
engine's names."""

from __future__ import annotations

import datetime as dt
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import urllib.error
import urllib.request
from pathlib import Path
from urllib.parse import urlsplit

import pytest

from tests.conftest import REPO, run_cli
from visphy_core.api.errors import UserError
from visphy_core.human.items import collect_items, find_run_dirs, rater_order
from visphy_core.human.media import PlayableCopies, byte_range
from visphy_core.human.server import RatingServer, RatingSession, loopback_address
from visphy_core.human.store import RATINGS_FILE, check_rater

KEYS = ["scene_id", "rater", "rating", "item", "ts", "comment"]


@pytest.fixture(scope="module")
def oracle_run(mini_root, tmp_path_factory) -> tuple[Path, Path]:
    home = tmp_path_factory.mktemp("rate") / "home"
    shutil.copytree(mini_root, home / "data" / mini_root.name)
    run_cli("model=oracle", "dataset.limit=2", "tracking=none", home=home)
    (run_dir,) = (home / "runs").iterdir()
    return home, run_dir


class Serving:
    """A rating server on a free loopback port, serving from a thread until closed."""

    def __init__(self, runs: Path, rater: str, tmp: Path):
        self.session = RatingSession(collect_items(find_run_dirs([runs])), rater)
        self.server = RatingServer(self.session, PlayableCopies(tmp), port=0)
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)
        self.thread.start()

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()


def _post(url: str, body: object, origin: str | None, content_type="application/json"):
    data = body if isinstance(body, bytes) else json.dumps(body).encode()
    headers = {"Content-Type": content_type} | ({"Origin": origin} if origin else {})
    request = urllib.request.Request(url + "api/rate", data=data, headers=headers)
    try:
        with urllib.request.urlopen(request, timeout=10) as response:
            return response.status, json.loads(response.read())
    except urllib.error.HTTPError as err:
        return err.code, json.loads(err.read())


def _lines(run_dir: Path) -> list[dict]:
    path = run_dir / RATINGS_FILE
    return [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []


@pytest.mark.browser
def test_rating_in_chromium_blind_resumable(oracle_run, tmp_path):
    from playwright.sync_api import sync_playwright

    from visphy_core.sandbox.browser import find_chromium

    home, run_dir = oracle_run
    hidden = ["oracle", "threejs", run_dir.name]
    received: list[tuple[int, str, bytes]] = []  # status, URL and headers, body

    def keep(response) -> None:
        try:
            body = response.body()
        except Exception:  # noqa: BLE001 - a cancelled media range has no body to read
            body = b""
        received.append((response.status, response.url + " " + json.dumps(response.headers),
                         body))

    first = Serving(home / "runs", "alice", tmp_path / "copies1")
    order = [i.item for i in first.session.order]
    args = ["--autoplay-policy=no-user-gesture-required", "--mute-audio"]
    if os.geteuid() == 0:
        args.append("--no-sandbox")
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=find_chromium(), args=args)
        try:
            page = browser.new_page(viewport={"width": 1200, "height": 900})
            page.on("response", keep)
            page.goto(first.server.url)
            page.wait_for_function("['reference','generated'].every(id => "
                                   "document.getElementById(id).readyState >= 2)", timeout=20_000)
            assert page.inner_text("#progress") == "1 / 2"
            page.click('[data-rating="4"]')
            page.fill("#comment", "the ball bounces too high")
            page.screenshot(path=str(tmp_path / "rating_page.png"))
            dom = page.content()
            page.click("#next")
            page.wait_for_function("document.getElementById('progress').textContent"
                                   " === '2 / 2'")
            (line,) = _lines(run_dir)
            assert list(line) == KEYS
            assert line["rater"] == "alice" and line["rating"] == 4
            assert line["item"] == order[0] and line["comment"] == "the ball bounces too high"
            assert line["scene_id"] == first.session.by_id[order[0]].scene_id
            assert dt.datetime.fromisoformat(line["ts"]).tzinfo is not None

            # Refused: another origin, no origin, a rating outside 1..5, a string rating,
            # an unknown item, a second rating of the same item, a body that is not JSON.
            url, own = first.server.url, first.server.url.rstrip("/")
            for body, origin in [({"item": order[1], "rating": 3}, "http://evil.example"),
                                 ({"item": order[1], "rating": 3}, None),
                                 ({"item": order[1], "rating": 6}, own),
                                 ({"item": order[1], "rating": 0}, own),
                                 ({"item": order[1], "rating": "3"}, own),
                                 ({"item": order[1], "rating": True}, own),
                                 ({"item": "0123456789abcdef", "rating": 3}, own),
                                 ({"item": order[0], "rating": 3}, own),
                                 (b"rating=3", own)]:
                status, reply = _post(url, body, origin)
                assert status == 400 and reply["ok"] is False, (body, origin, reply)
            assert len(_lines(run_dir)) == 1
        finally:
            first.close()

        # The same rater again, on a new server: the rated item is skipped.
        second = Serving(home / "runs", "alice", tmp_path / "copies2")
        try:
            assert [i.item for i in second.session.order] == order
            page.goto(second.server.url)
            page.wait_for_function("document.getElementById('generated').readyState >= 2",
                                   timeout=20_000)
            assert page.inner_text("#progress") == "2 / 2"
            assert page.evaluate("document.getElementById('generated').src").endswith(
                f"/video/{order[1]}/generated.mp4")
            page.keyboard.press("5")
            page.keyboard.press("Enter")
            page.wait_for_selector("#finished:not(.hidden)")
            assert "All items are rated" in page.inner_text("#finished")
            dom += page.content()
        finally:
            second.close()
            browser.close()

    lines = _lines(run_dir)
    assert [(r["item"], r["rating"], r["comment"]) for r in lines] == [
        (order[0], 4, "the ball bounces too high"), (order[1], 5, None)]
    videos = [(status, u) for status, u, _ in received if "/video/" in u]
    assert {f"/video/{i}/{kind}.mp4" for i in order for kind in ("reference", "generated")} \
        <= {urlsplit(u.split()[0]).path for _, u in videos}
    assert any(status == 206 and '"content-range"' in u for status, u in videos)
    for text in [dom] + [u for _, u, _ in received] + [b.decode("latin-1")
                                                        for _, _, b in received]:
        for name in hidden:
            assert name not in text


@pytest.mark.browser  # the oracle run renders its clips
def test_cli_prints_the_url_and_stops_cleanly(oracle_run):
    home, run_dir = oracle_run
    env = dict(os.environ, VISPHY_HOME=str(home))
    # started as a background job of a script would be: with SIGINT ignored, which a child
    # inherits; Ctrl-C must still stop it
    proc = subprocess.Popen([sys.executable, "-m", "visphy_core", "rate", str(home / "runs"),
                             "--rater", "bob", "--port", "0"], cwd=REPO, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    try:
        assert proc.stdout.readline().startswith("rating 2 clip(s) from 1 run(s) as bob")
        url = proc.stdout.readline().split()[1]
        assert url.startswith("http://127.0.0.1:")
        with urllib.request.urlopen(url + "api/state", timeout=10) as response:
            state = json.loads(response.read())
        assert state["rater"] == "bob" and state["total"] == 2 and len(state["queue"]) == 2
        assert not any(n in json.dumps(state) for n in ("oracle", "threejs", run_dir.name))
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            _, err = proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()  # no survivor when Ctrl-C did not stop it
            proc.communicate()
            raise
    assert proc.returncode == 0 and "stopped: 0 rating(s) saved" in err


@pytest.mark.browser  # the oracle run renders its clips
def test_order_is_seeded_by_the_rater(oracle_run):
    home, _ = oracle_run
    items = collect_items(find_run_dirs([home]))
    assert len(items) == 2
    orders = {r: [i.item for i in rater_order(items, r)] for r in "abcdefgh"}
    assert orders["a"] == [i.item for i in rater_order(list(reversed(items)), "a")]
    assert len({tuple(o) for o in orders.values()}) == 2  # both orders occur over 8 raters


def test_bad_inputs_are_refused():
    for host in ("0.0.0.0", "192.168.1.10", "example.org"):
        with pytest.raises(UserError, match="loopback only"):
            loopback_address(host)
    assert loopback_address("localhost") == "127.0.0.1"
    for rater in ("", "a b", "x" * 65, "../etc"):
        with pytest.raises(UserError, match="--rater"):
            check_rater(rater)
    assert byte_range(None, 100) is None
    assert byte_range("bytes=0-", 100) == (0, 99)
    assert byte_range("bytes=10-19", 100) == (10, 19)
    assert byte_range("bytes=-10", 100) == (90, 99)
    assert byte_range("bytes=90-500", 100) == (90, 99)
    for bad in ("bytes=100-", "bytes=5-2", "items=0-1", "bytes=-"):
        with pytest.raises(ValueError):
            byte_range(bad, 100)
    with pytest.raises(UserError, match="no run directory"):
        find_run_dirs([REPO / "conf"])
