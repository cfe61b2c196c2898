"""Write the report pictures of the docs from fresh offline runs on the ``mini`` split:

* ``docs/img/report_screenshot.png``: a run report's first screen (the oracle's), the first
  scene's clips scrubbed to the middle frame, so the synchronised clips show motion;
* ``docs/img/report_plots.png``: a run report's plots (the ``flow_extrapolate`` baseline's: a
  model that gets things wrong draws more telling curves): the headline with its interval and
  the family bars, then one scene's clips, per-frame PSNR curve and track overlay;
* ``docs/img/radar.png``: the study radar of the three runs (oracle, flow_extrapolate, static).

    .venv/bin/python scripts/report_screenshot.py [--home DIR] [--only screen plots radar]

The runs use ``--home`` as ``VISPHY_HOME`` (its dataset and cache are reused when present) and
no MLflow tracking; ``--run-dir MODEL=DIR`` uses an existing run instead of a fresh one.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
IMG = REPO / "docs" / "img"
MODELS = ("oracle", "flow_extrapolate", "static")
#: The scene of the plots picture: the red ball falls onto a ramp (the baseline keeps it still).
PLOTS_SCENE = "vpb3-s0-2d-t001-v00"


def fresh_run(home: Path, model: str) -> Path:
    env = dict(os.environ, VISPHY_HOME=str(home))
    proc = subprocess.run([sys.executable, "-m", "visphy_core", f"model={model}",
                           "engine=threejs", "dataset=mini", "tracking=none",
                           "run.progress=false"],
                          cwd=REPO, env=env, capture_output=True, text=True)
    if proc.returncode != 0:
        sys.exit(f"the {model} run failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
    match = re.search(r"^run directory: (.+)$", proc.stdout, re.M)
    if match is None:
        sys.exit(f"no run directory in the run's output:\n{proc.stdout[-3000:]}")
    return Path(match.group(1).strip())


def wait_until(page, condition: str, timeout_s: float = 30.0) -> None:
    """Poll a JS condition (the report's Content Security Policy refuses the eval that
    Playwright's wait_for_function polls with)."""
    deadline = time.monotonic() + timeout_s
    while not page.evaluate(condition):
        if time.monotonic() > deadline:
            sys.exit(f"timed out waiting for {condition}")
        page.wait_for_timeout(50)


def _open(browser, index: Path, width: int, height: int, section: str = "section.scene"):
    page = browser.new_page(viewport={"width": width, "height": height})
    page.route("**/*", lambda r: r.continue_() if r.request.url.startswith("file://")
               else r.abort())
    page.goto(index.resolve().as_uri())
    videos = f"Array.from(document.querySelector({section!r}).querySelectorAll('video'))"
    wait_until(page, f"{videos}.every(v => v.readyState >= 2)")
    page.evaluate("""(sel) => { const r = document.querySelector(sel + ' .sync '
        + 'input[type=range]'); r.value = String(Math.floor(r.max / 2));
        r.dispatchEvent(new Event('input')); }""", section)
    wait_until(page, f"{videos}.every(v => !v.seeking)")
    page.wait_for_timeout(300)
    return page


def first_screen(browser, index: Path, out: Path) -> None:
    page = _open(browser, index, 1280, 2300)
    page.screenshot(path=str(out))
    page.close()


def plots_picture(browser, index: Path, out: Path, scene: str) -> None:
    """The header's title, the run's plots, then one scene's title, clips and plots, stacked."""
    from PIL import Image

    section = f"section#scene-{scene}"
    page = _open(browser, index, 1280, 1400, section)
    parts = ["header.top h1", "#run-plots", f"{section} > h2", f"{section} .sync",
             f"{section} .plots"]
    with tempfile.TemporaryDirectory() as tmp:
        shots = []
        for i, selector in enumerate(parts):
            path = Path(tmp) / f"{i}.png"
            page.locator(selector).first.screenshot(path=str(path))
            shots.append(Image.open(path).convert("RGB"))
        page.close()
        gap = 14
        width = max(s.width for s in shots) + 2 * gap
        sheet = Image.new("RGB", (width, sum(s.height + gap for s in shots) + gap), "white")
        y = gap
        for shot in shots:
            sheet.paste(shot, (gap, y))
            y += shot.height + gap
        sheet.save(out, optimize=True)


def radar_picture(run_dirs: list[Path], out: Path) -> None:
    import shutil

    from visphy_core.analysis import figures
    from visphy_core.analysis.column_views import pick_columns
    from visphy_core.analysis.load import label_runs, load_runs

    runs = load_runs(run_dirs)
    table = figures.radar_table(runs, label_runs(runs), pick_columns(runs, None))
    with tempfile.TemporaryDirectory() as tmp:
        paths = figures.radar(table, Path(tmp))
        if not paths:
            sys.exit("no radar: fewer than 3 metrics or 2 runs in common")
        shutil.copyfile(paths[0], out)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--home", type=Path, default=Path(os.environ.get("VISPHY_HOME",
                                                                         "visphy-out")))
    parser.add_argument("--only", nargs="+", choices=("screen", "plots", "radar"),
                        default=["screen", "plots", "radar"])
    parser.add_argument("--run-dir", action="append", default=[], metavar="MODEL=DIR",
                        help="use this run of MODEL (oracle, flow_extrapolate, static)")
    parser.add_argument("--out-dir", type=Path, default=IMG)
    args = parser.parse_args()
    from playwright.sync_api import sync_playwright

    from visphy_core.report import write_run_report
    from visphy_core.sandbox.browser import find_chromium

    given = dict(item.split("=", 1) for item in args.run_dir)
    needed = {"screen": ["oracle"], "plots": ["flow_extrapolate"], "radar": list(MODELS)}
    runs = {}
    for model in dict.fromkeys(m for what in args.only for m in needed[what]):
        runs[model] = Path(given[model]) if model in given else fresh_run(args.home.resolve(),
                                                                          model)
    args.out_dir.mkdir(parents=True, exist_ok=True)
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=find_chromium())
        if "screen" in args.only:
            first_screen(browser, write_run_report(runs["oracle"]),
                         args.out_dir / "report_screenshot.png")
        if "plots" in args.only:
            plots_picture(browser, write_run_report(runs["flow_extrapolate"]),
                          args.out_dir / "report_plots.png", PLOTS_SCENE)
        browser.close()
    if "radar" in args.only:
        radar_picture([runs[m] for m in MODELS], args.out_dir / "radar.png")
    for what in args.only:
        name = {"screen": "report_screenshot", "plots": "report_plots", "radar": "radar"}[what]
        print(args.out_dir / f"{name}.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
