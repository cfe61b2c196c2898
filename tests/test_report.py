"""HTML reports (visphy_core.report): real runs, opened in headless Chromium from file:// with
every non-file request aborted.

Two runs are made once for the module: the oracle on two mini scenes (near-perfect; the
session's mini build is lossless, so its ground-truth clips are the H.264 High 4:4:4 files
Chromium shows with wrong colours), and a replay of hostile replies judged by a fake Gemini
server: one reply renders but carries script injections in its analysis, program and the
judge's justification; the other fails at runtime and is scored on the fallback clip.
"""

from __future__ import annotations

import io
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from urllib.parse import unquote

import numpy as np
import pandas as pd
import pytest
from PIL import Image

from conftest import REPO, run_cli
from visphy_core.infra.video import decode_video
from visphy_core.report import write_run_report, write_study_report
from visphy_core.report.media import describe_clip

pytestmark = pytest.mark.browser

INJECTION = '</script><script>window.__pwned=1</script><img src=x onerror="window.__pwned=2">'
BROKEN = ("Broken on purpose.\n\n```html\n<html><body><canvas id='c'></canvas><script>"
          "undefinedFunction();</script></body></html>\n```\n")
SCENES = ("vpb3-s0-2d-t001-v00", "vpb3-s0-2d-t002-v00")


@pytest.fixture(scope="module")
def home(tmp_path_factory, mini_root) -> Path:
    home = tmp_path_factory.mktemp("report") / "home"
    shutil.copytree(mini_root, home / "data" / mini_root.name)
    return home


def _only_run(home: Path, model: str) -> Path:
    (run_dir,) = [p for p in (home / "runs").iterdir() if f"_{model}_" in p.name]
    return run_dir


@pytest.fixture(scope="module")
def oracle_run(home) -> Path:
    # the headline's components too (the plots show the headline and the tracked bodies)
    run_cli("model=oracle", "dataset.limit=2", "tracking=none", "run.progress=false",
            "metrics.names=[psnr,ssim,spatiotemporal_iou_tol,weighted_spatial_iou_tol,"
            "track_pos_err]",
            "metrics.spec_track=false", "metrics.variance_norm=false", home=home)
    return _only_run(home, "oracle")


@pytest.fixture(scope="module")
def hostile_run(home, tmp_path_factory) -> Path:
    from visphy_plugins.testing.fake_gemini import FakeGeminiServer
    from visphy_plugins.testing.fake_server import ok
    from visphy_plugins.testing.replies import ANALYSIS, HTML_PROGRAM, SPEC_2D

    replies = tmp_path_factory.mktemp("replies")
    program = HTML_PROGRAM.replace("<body", f"<!-- {INJECTION} --><body", 1)
    (replies / f"{SCENES[0]}.txt").write_text(f"{ANALYSIS} {INJECTION}\n\n```json\n"
                                              f"{json.dumps(SPEC_2D)}\n```\n\n```html\n"
                                              f"{program}\n```\n")
    (replies / f"{SCENES[1]}.txt").write_text(BROKEN)
    verdict = json.dumps({"score": 3, "justification": f"partly right {INJECTION}"})
    env = {k: v for k, v in os.environ.items() if not k.endswith("_API_KEY")}
    env["GEMINI_API_KEY"] = "test-report-key"
    with FakeGeminiServer(default=lambda req: ok(verdict)) as gemini:
        run_cli("model=replay", f"model.source={replies}", "dataset.limit=2", "tracking=none",
                "run.progress=false", "metrics.names=[psnr,ssim]", "metrics.variance_norm=false",
                "judge=gemini", f"judge.gemini.base_url={gemini.url}", home=home, env=env)
    return _only_run(home, "replay")


@pytest.fixture(scope="module")
def browser():
    from playwright.sync_api import sync_playwright

    from visphy_core.sandbox.browser import find_chromium

    with sync_playwright() as p:
        chromium = p.chromium.launch(executable_path=find_chromium(),
                                     args=["--autoplay-policy=no-user-gesture-required"])
        yield chromium
        chromium.close()


class Opened:
    """A report page, with every request the page made and every console message."""

    def __init__(self, browser, index: Path):
        self.requests: list[str] = []
        self.aborted: list[str] = []
        self.console: list[str] = []
        self.page = browser.new_page(viewport={"width": 1280, "height": 1000})
        self.page.on("request", lambda r: self.requests.append(r.url))
        self.page.on("console", lambda m: self.console.append(m.text))

        def route(r):
            if r.request.url.startswith("file://"):
                r.continue_()
            else:
                self.aborted.append(r.request.url)
                r.abort()

        self.page.route("**/*", route)
        self.page.goto(index.resolve().as_uri())
        self.wait("document.querySelectorAll('.sync:not([data-ready])').length === 0")

    def eval(self, script: str, arg=None):
        return self.page.evaluate(script, arg)

    def wait(self, condition: str, timeout_s: float = 20.0) -> None:
        """Poll a JS condition (Playwright's wait_for_function evaluates its predicate with
        eval, which the report's Content Security Policy refuses, as it should)."""
        deadline = time.monotonic() + timeout_s
        while not self.page.evaluate(condition):
            assert time.monotonic() < deadline, f"timed out waiting for: {condition}"
            self.page.wait_for_timeout(50)

    def close(self) -> None:
        assert self.aborted == [], f"the report tried the network: {self.aborted}"
        assert all(u.startswith("file://") for u in self.requests), self.requests
        assert not [m for m in self.console if "Content Security Policy" in m], self.console
        self.page.close()


def _rows(run_dir: Path) -> pd.DataFrame:
    return pd.read_parquet(run_dir / "results.parquet")


def test_run_report_leaderboard_first_counts_match_results_one_section_per_scene(
        oracle_run, hostile_run, browser, tmp_path):
    for run_dir in (oracle_run, hostile_run):
        index = write_run_report(run_dir)
        assert index == run_dir / "report" / "index.html"
        rows, summary = _rows(run_dir), json.loads((run_dir / "summary.json").read_text())
        page = Opened(browser, index)
        first = page.eval("document.querySelector('header.top').nextElementSibling.id")
        assert first == "leaderboard"
        # the folded tables' title names only the groups the run has (no normalisation here)
        folded = page.eval("document.querySelector('#leaderboard details summary').textContent")
        assert "aligned" in folded and "variance-normalised" not in folded
        board = page.eval("""Array.from(document.querySelectorAll(
            '#leaderboard table.leaderboard tbody tr'))
            .map(tr => Array.from(tr.cells).map(td => td.textContent))""")
        by_metric = {r[0]: r for r in board}
        psnr = summary["metrics"]["psnr"]
        assert by_metric["psnr↑"][1] == f"{psnr['mean_model_success']:.4g} " \
                                        f"(n={psnr['n_model_success']})"
        assert by_metric["psnr↑"][2] == f"{psnr['mean_with_fallbacks']:.4g} " \
                                        f"(n={psnr['n_with_fallbacks']})"
        n, ok = len(rows), int(rows["model_success"].sum())
        assert page.eval("document.querySelector('#count-model-success .v').textContent") \
            .startswith(f"{ok}/{n} ")
        assert page.eval("document.querySelector('#count-fallbacks .v').textContent") == \
            str(int(rows["fallback"].sum()))
        failures = page.eval("""Array.from(document.querySelectorAll('#failures tbody tr'))
            .map(tr => [tr.cells[0].textContent, Number(tr.cells[2].textContent)])""")
        expected = rows.loc[~rows["model_success"], "failure_class"].value_counts()
        assert dict(failures) == {k: int(v) for k, v in expected.items()}
        sections = page.eval("Array.from(document.querySelectorAll('section.scene'))"
                             ".map(s => s.querySelector('h2 a').textContent)")
        assert sections == list(rows["scene_id"])
        page.page.screenshot(path=str(tmp_path / f"{run_dir.name}.png"))
        page.close()
        with Image.open(tmp_path / f"{run_dir.name}.png") as shot:
            assert np.asarray(shot.convert("L")).std() > 10   # a page, not a blank
    # the oracle's report as a person sees it (kept for a look: pytest's tmp_path)
    assert (tmp_path / f"{oracle_run.name}.png").stat().st_size > 20_000


def _plots(page: Opened) -> dict:
    """What the report's plots show, read from their SVG elements' data attributes."""
    return page.eval("""() => {
        const d = (el, k) => el.getAttribute('data-' + k);
        const scenes = {};
        for (const s of document.querySelectorAll('section.scene')) {
            const curve = s.querySelector('figure.psnr-curve');
            scenes[s.id.slice(6)] = {
                frames: curve ? Number(d(curve, 'frames')) : null,
                series: curve ? Array.from(curve.querySelectorAll('g.series')).map(
                    g => [d(g, 'series'), d(g, 'values').split(',').map(Number),
                          g.querySelectorAll('circle').length]) : [],
                tracks: Array.from(s.querySelectorAll('figure.track-overlay g.track')).map(
                    g => [d(g, 'body'), d(g, 'clip'), Number(d(g, 'found')),
                          Array.from(g.querySelectorAll('polyline.path')).map(
                              p => p.getAttribute('points').split(' ').map(
                                  xy => xy.split(',').map(Number)))]),
                overlayImage: !!s.querySelector('figure.track-overlay svg image'),
                missing: Array.from(s.querySelectorAll('.plot-missing'))
                    .map(p => p.textContent)};
        }
        return {
            headline: Array.from(document.querySelectorAll('g.headline-row')).map(
                g => [d(g, 'view'), Number(d(g, 'mean')), d(g, 'lo'), d(g, 'hi'),
                      Number(d(g, 'n'))]),
            scale: (document.querySelector('figure.family-bars') || {}).dataset?.scale,
            bars: Array.from(document.querySelectorAll('figure.family-bars g.bar')).map(
                g => [d(g, 'metric'), d(g, 'family'), d(g, 'value'), Number(d(g, 'n'))]),
            runMissing: Array.from(document.querySelectorAll('#run-plots .plot-missing'))
                .map(p => p.textContent),
            scenes};
    }""")


def test_run_report_plots_headline_family_bars_curve_and_track_overlay(
        oracle_run, hostile_run, browser, home):
    summary = json.loads((oracle_run / "summary.json").read_text())
    page = Opened(browser, write_run_report(oracle_run))
    shown = _plots(page)
    page.close()   # no request left the report folder, no CSP violation
    head = summary["headline"]
    assert shown["headline"] == [
        ["all scored scenes", head["mean"], repr(head["ci"][0]), repr(head["ci"][1]), head["n"]],
        ["model successes", head["mean_model_success"], repr(head["ci_model_success"][0]),
         repr(head["ci_model_success"][1]), head["n_model_success"]]]
    # one bar per plain-pairing metric but the headline, grouped by its declared family, n as
    # in the summary; without normalised scores a bar is the mean's place in the metric's
    # range, the best end longest (an error without an upper bound has no bar)
    assert shown["scale"] == "range"
    bars = {m: (fam, val, count) for m, fam, val, count in shown["bars"]}
    assert set(bars) == {"psnr", "ssim", "spatiotemporal_iou_tol", "weighted_spatial_iou_tol",
                         "track_pos_err"}
    psnr = summary["metrics"]["psnr"]
    assert bars["psnr"] == ("pixel", repr(psnr["mean_model_success"] / 100.0),
                            psnr["n_model_success"])
    assert bars["track_pos_err"] == ("physics", "", summary["metrics"]["track_pos_err"]
                                     ["n_model_success"])
    data_root = next((home / "data").glob("visphybench-*"))
    for row in _rows(oracle_run).itertuples():
        scene = shown["scenes"][row.scene_id]
        clip = decode_video(data_root / "videos" / f"{row.scene_id}.mp4")[0]
        frames, height = len(clip), clip.shape[1]
        # the curve: one point per frame of the clips, for the generated and the still clip
        assert scene["frames"] == frames and scene["missing"] == []
        assert [(name, len(values), marks) for name, values, marks in scene["series"]] == [
            ("still clip (first frame held)", frames, frames), ("generated", frames, frames)]
        generated = np.array(scene["series"][1][1])
        assert np.nanmean(generated[np.isfinite(generated)]) > 35   # the oracle: near-exact
        # the overlay: each body the track metrics tracked, in both clips, over key frame 1
        details = json.loads((oracle_run / "scenes" / row.scene_id / "metric_details.json")
                             .read_text())
        tracked = details["tracks"]["tracked"]
        assert [(b, c) for b, c, _, _ in scene["tracks"]] == [
            (b, c) for b in tracked for c in ("ground truth", "generated")]
        assert scene["overlayImage"]
        for _, _, found, paths in scene["tracks"]:
            assert 0 < found <= frames and sum(len(p) for p in paths) == found
        # the red ball's drawn path is its simulated trajectory (px, y up, frame by frame)
        poses = np.load(data_root / "trajectories" / f"{row.scene_id}.npz")
        ids = [str(i) for i in poses["body_ids"]]
        if "red_ball" in tracked and "red_ball" in ids:
            truth = np.array(sum(next(p for b, c, _, p in scene["tracks"]
                                      if b == "red_ball" and c == "ground truth"), []))
            if len(truth) == frames:
                x, y = poses["frame_poses"][:, ids.index("red_ball"), :2].T
                assert np.abs(truth - np.stack([x, height - y], 1)).max() < 2.0
    # a run without a headline or normalised scores, and with a failed scene on its fallback
    page = Opened(browser, write_run_report(hostile_run))
    shown = _plots(page)
    page.close()
    assert shown["headline"] == [] and len(shown["runMissing"]) == 1
    assert shown["runMissing"][0].startswith("no headline plot: the run has no headline score")
    assert shown["scale"] == "range"
    bars = {m: (fam, val, count) for m, fam, val, count in shown["bars"]}
    assert set(bars) == {"psnr", "ssim", "judge_gemini"}
    assert bars["judge_gemini"] == ("judges", "0.3", 1)     # 3/10 on the scene that rendered
    failed = shown["scenes"][SCENES[1]]
    (still, _, _), (name, fallback, _) = [s for s in failed["series"]]
    assert name == "generated (fallback clip)"
    # the fallback clip is the first key frame held: its curve is the still clip's
    assert np.allclose(fallback[1:], failed["series"][0][1][1:], atol=1.5)


def test_one_control_plays_scrubs_and_loops_every_clip_of_a_scene(hostile_run, browser):
    page = Opened(browser, hostile_run / "report" / "index.html")
    group = "document.querySelector('section.scene .sync')"
    clips = page.eval(f"{group}.querySelectorAll('video').length")
    assert clips == 3                                   # ground truth, generated, spec track
    page.wait(f"Array.from({group}.querySelectorAll('video')).every(v => v.readyState >= 2)")
    page.page.locator("section.scene .sync [data-act=play]").first.click()
    page.page.wait_for_timeout(900)
    times = page.eval(f"Array.from({group}.querySelectorAll('video')).map(v => v.currentTime)")
    assert min(times) > 0.3 and max(times) - min(times) < 0.25, times
    page.page.locator("section.scene .sync [data-act=play]").first.click()   # pause
    page.eval(f"""() => {{ const r = {group}.querySelector('input[type=range]');
        r.value = '8'; r.dispatchEvent(new Event('input')); }}""")
    page.wait(f"Array.from({group}.querySelectorAll('video')).every(v => !v.seeking)")
    times = page.eval(f"Array.from({group}.querySelectorAll('video')).map(v => v.currentTime)")
    assert times == pytest.approx([8.5 / 5] * 3, abs=0.02)   # frame 9 of 17 at 5 fps
    assert page.eval(f"{group}.querySelector('.frame-label').textContent").startswith("frame 9/17")
    assert page.eval(f"Array.from({group}.querySelectorAll('video')).every(v => v.loop)")
    page.close()


def test_lossless_ground_truth_is_transcoded_and_shown_with_its_true_colours(
        oracle_run, browser, mini_root):
    gt = mini_root / "videos" / f"{SCENES[0]}.mp4"
    assert describe_clip(gt)[0] is False                 # High 4:4:4 (gbrp): not as it is
    copy = oracle_run / "report" / "media" / SCENES[0] / "ground_truth.mp4"
    playable, what = describe_clip(copy)
    assert playable and "yuv420p" in what
    page = Opened(browser, oracle_run / "report" / "index.html")
    video = page.page.locator("section.scene .sync video").first
    assert "transcoded for the browser" in page.eval(
        "document.querySelector('section.scene figure.clip').textContent")
    page.wait("document.querySelector('section.scene video').readyState >= 2")
    page.eval("""() => new Promise(done => {
        const v = document.querySelector('section.scene video');
        v.addEventListener('seeked', done, {once: true}); v.currentTime = 0.1; })""")
    shot = np.asarray(Image.open(io.BytesIO(video.screenshot())).convert("RGB"))
    box = page.eval("(() => { const r = document.querySelector('section.scene video')"
                    ".getBoundingClientRect(); return [r.width, r.height]; })()")
    frames, _ = decode_video(gt)
    truth = np.asarray(Image.fromarray(frames[0]).resize((shot.shape[1], shot.shape[0]),
                                                          Image.BILINEAR)).astype(float)
    assert shot.shape[1] == round(box[0])
    assert np.abs(shot.astype(float) - truth).mean() < 6   # wrong planes: ≈ 40 off
    page.close()


def test_replies_programs_and_verdicts_render_as_text_never_as_markup(hostile_run, browser):
    html = (hostile_run / "report" / "index.html").read_text()
    assert INJECTION not in html
    page = Opened(browser, hostile_run / "report" / "index.html")
    assert page.eval("window.__pwned") is None
    assert page.eval("document.querySelectorAll('script').length") == 1
    assert page.eval("document.querySelectorAll('[onerror]').length") == 0
    assert page.eval("document.querySelectorAll('img[src=x]').length") == 0
    analysis = page.eval("document.querySelector('section.scene p.analysis').textContent")
    assert analysis.endswith(INJECTION)
    verdict = page.eval("document.querySelector('section.scene .verdict p.text').textContent")
    assert verdict == f"partly right {INJECTION}"
    program = page.eval("document.querySelector('section.scene pre.program').textContent")
    assert f"<!-- {INJECTION} -->" in program and "setupRecording(cv, 3400);" in program
    page.close()


def test_a_failed_scene_shows_its_class_detail_fallback_and_the_filters_find_it(
        hostile_run, browser):
    page = Opened(browser, hostile_run / "report" / "index.html")
    failed = f"document.getElementById('scene-{SCENES[1]}')"
    assert page.eval(f"{failed}.dataset.outcome") == "runtime_error"
    text = page.eval(f"{failed}.textContent")
    assert "fallback clip" in text and "undefinedFunction is not defined" in text
    assert page.eval(f"{failed}.querySelectorAll('figcaption')[1].textContent") == \
        "generated (fallback clip)"
    first = f"document.getElementById('scene-{SCENES[0]}')"
    assert page.eval(f"{first}.querySelectorAll('table.spec-diff td.chg').length") >= 4
    assert "gemini 3/10" in page.eval(f"{first}.querySelector('.verdict').textContent")
    page.page.select_option("#filter-outcome", "runtime_error")
    visible = page.eval("Array.from(document.querySelectorAll('section.scene'))"
                        ".filter(s => !s.hidden).map(s => s.id)")
    assert visible == [f"scene-{SCENES[1]}"]
    assert page.eval("document.getElementById('filter-count').textContent") == "1 of 2 scenes"
    page.close()


def test_an_interrupted_run_without_its_dataset_still_renders(oracle_run, browser, tmp_path):
    run_dir = tmp_path / "runs" / oracle_run.name
    shutil.copytree(oracle_run, run_dir, ignore=shutil.ignore_patterns("report"))
    (run_dir / "summary.json").unlink()
    (run_dir / "results.parquet").unlink()
    first, _ = (oracle_run / "results.jsonl").read_text().splitlines()[:2]
    (run_dir / "results.jsonl").write_text(first + "\n" + first[:40])   # killed mid-line
    manifest = json.loads((run_dir / "manifest.json").read_text())
    (run_dir / "manifest.json").write_text(json.dumps(manifest | {"status": "running"}))
    config = (run_dir / "config.yaml").read_text()
    gone = tmp_path / "deleted-data"
    (run_dir / "config.yaml").write_text(config.replace(str(oracle_run.parents[1] / "data"),
                                                        str(gone)))
    page = Opened(browser, write_run_report(run_dir))
    assert page.eval("document.getElementById('run-status').textContent") == "running"
    assert "recomputed from results.jsonl" in page.eval("document.querySelector('header')"
                                                        ".textContent")
    psnr = json.loads(first)["score_psnr"]
    board = page.eval("Array.from(document.querySelectorAll('#leaderboard tbody tr'))"
                      ".map(tr => tr.textContent)")
    assert any(row.startswith(f"psnr↑{psnr:.4g} (n=1)") for row in board)
    sections = page.eval("Array.from(document.querySelectorAll('section.scene'))"
                         ".map(s => [s.id, s.dataset.outcome, s.textContent])")
    assert [s[:2] for s in sections] == [[f"scene-{SCENES[0]}", "success"],
                                         [f"scene-{SCENES[1]}", "not_run"]]
    assert all("ground truth not found: no videos/" in s[2] for s in sections)
    # no clip to compare with: the plots say why, and nothing is drawn
    missing = _plots(page)["scenes"]
    assert [m["missing"] for m in missing.values()] == [
        [f"no plots: {why}"] for why in page.eval(
            "Array.from(document.querySelectorAll('section.scene > p.note.warn'))"
            ".map(p => p.textContent)")]
    assert all(m["frames"] is None and m["tracks"] == [] for m in missing.values())
    page.close()


def test_rewriting_a_report_copies_nothing_again(oracle_run, monkeypatch):
    from visphy_core.report import frame_data
    from visphy_core.report import media as report_media

    index = write_run_report(oracle_run)
    media = sorted((oracle_run / "report" / "media").rglob("*.*"))
    assert media  # clips and key frames were placed the first time
    stamps = {p: p.stat().st_mtime_ns for p in media}
    before = index.read_text()
    placed = []  # the second write neither copies nor transcodes a clip or an image
    monkeypatch.setattr(report_media.shutil, "copyfile", lambda *a, **k: placed.append(a))
    monkeypatch.setattr(report_media, "encode_for_browser", lambda *a, **k: placed.append(a))
    # nor decodes the clips again for the plots (media/.plots.json)
    monkeypatch.setattr(frame_data, "compute", lambda *a, **k: placed.append(a))
    assert write_run_report(oracle_run) == index
    assert placed == []
    assert index.read_text() == before
    assert {p: p.stat().st_mtime_ns for p in media} == stamps


def test_study_report_leaderboard_tables_figures_and_run_links(
        oracle_run, hostile_run, browser, tmp_path):
    figure = tmp_path / "box.png"
    Image.new("RGB", (40, 30), (10, 120, 200)).save(figure)
    extra = pd.DataFrame({"model": ["oracle", "replay"], "psnr": [41.8, 14.6]})
    out = tmp_path / "study"
    index = write_study_report([oracle_run, hostile_run], out, "Study <b>one</b>",
                               tables={"by difficulty": extra}, figures={"boxplots": [figure]},
                               markdown="# Notes\n\nsee <script>window.__pwned=3</script>\n\n"
                                        "![boxes](box.png) ![gone](elsewhere/gone.png)")
    page = Opened(browser, index)
    assert page.eval("document.querySelector('header.top').nextElementSibling.id") == \
        "leaderboard"
    assert page.eval("document.querySelector('h1').textContent") == "Study <b>one</b>"
    rows = page.eval("""Array.from(document.querySelectorAll('#leaderboard-table tbody tr'))
        .map(tr => [tr.cells[0].textContent, tr.cells[5].textContent])""")
    assert rows == [[oracle_run.name, "2/2 (100.0%)"], [hostile_run.name, "1/2 (50.0%)"]]
    links = page.eval("Array.from(document.querySelectorAll('#runs a')).map(a => a.href)")
    assert [Path(unquote(h[len("file://"):])) for h in links] \
        == [oracle_run / "report" / "index.html", hostile_run / "report" / "index.html"]
    assert page.eval("document.querySelector('#figures img').naturalWidth") == 40
    assert page.eval("window.__pwned") is None
    assert "<script>" in page.eval("document.getElementById('notes').textContent")
    # the write-up's figure points at its copy; an image nowhere to be found becomes text
    assert page.eval("Array.from(document.querySelectorAll('#notes img'))"
                     ".map(i => [i.getAttribute('src'), i.naturalWidth])") == \
        [["figures/boxplots/box.png", 40]]
    assert "[figure elsewhere/gone.png]" in page.eval("document.getElementById('notes')"
                                                      ".textContent")
    page.close()
    given = pd.DataFrame({"run": ["a"], "psnr": [12.3456789]})
    index = write_study_report([oracle_run], out, "given", tables={"leaderboard": given})
    assert "12.35" in index.read_text()


def test_report_command_writes_run_and_study_reports_and_refuses_a_non_run(
        oracle_run, hostile_run, tmp_path):
    def report(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "visphy_core", "report", *args], cwd=REPO,
                              capture_output=True, text=True, timeout=120)

    proc = report(str(oracle_run), str(hostile_run), "-o", str(tmp_path / "s"), "--title", "T")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == f"report: {tmp_path / 's' / 'index.html'}"
    proc = report(str(tmp_path))
    assert proc.returncode == 2
    assert proc.stderr.strip() == (f"error: {tmp_path} is not a visphy run directory (none of "
                                   "manifest.json, results.jsonl, summary.json, nor config.yaml "
                                   "beside scenes/); pass a folder under <VISPHY_HOME>/runs/")
