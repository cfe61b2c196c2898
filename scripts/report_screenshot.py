"""Write ``docs/report_screenshot.png`` for the README: a fresh oracle run on the ``mini`` split,
its HTML report, and the report's first screen as headless Chromium shows it (the first scene's
clips scrubbed to the middle frame, so the synchronised clips show motion).

    .venv/bin/python scripts/report_screenshot.py [--home DIR] [--out PNG]

The run uses ``--home`` as ``VISPHY_HOME`` (its dataset and cache are reused when present) and
no MLflow tracking; ``--run-dir`` screenshots an existing run's report instead.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def fresh_oracle_run(home: Path) -> Path:
    env = dict(os.environ, VISPHY_HOME=str(home))
    proc = subprocess.run([sys.executable, "-m", "visphy_core", "model=oracle", "engine=threejs",
                           "dataset=mini", "tracking=none", "run.progress=false"],
                          cwd=REPO, env=env, capture_output=True, text=True)
    if proc.returncode != 0:
        sys.exit(f"the oracle run failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
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


def screenshot(index: Path, out: Path, width: int = 1280, height: int = 2300) -> None:
    from playwright.sync_api import sync_playwright

    from visphy_core.sandbox.browser import find_chromium

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=find_chromium())
        page = browser.new_page(viewport={"width": width, "height": height})
        page.route("**/*", lambda r: r.continue_() if r.request.url.startswith("file://")
                   else r.abort())
        page.goto(index.resolve().as_uri())
        first = "Array.from(document.querySelector('section.scene').querySelectorAll('video'))"
        wait_until(page, f"{first}.every(v => v.readyState >= 2)")
        page.evaluate("""() => { const r = document.querySelector('section.scene .sync '
            + 'input[type=range]'); r.value = String(Math.floor(r.max / 2));
            r.dispatchEvent(new Event('input')); }""")
        wait_until(page, f"{first}.every(v => !v.seeking)")
        page.wait_for_timeout(300)
        out.parent.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(out))
        browser.close()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--home", type=Path, default=Path(os.environ.get("VISPHY_HOME",
                                                                         "visphy-out")))
    parser.add_argument("--out", type=Path, default=REPO / "docs" / "report_screenshot.png")
    parser.add_argument("--run-dir", type=Path, default=None,
                        help="report this run instead of making a fresh one")
    args = parser.parse_args()
    from visphy_core.report import write_run_report

    run_dir = args.run_dir or fresh_oracle_run(args.home.resolve())
    index = write_run_report(run_dir)
    screenshot(index, args.out)
    print(f"{args.out} (from {index})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
