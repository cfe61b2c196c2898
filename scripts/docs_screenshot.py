"""Build the docs site and screenshot pages of it, served on loopback, in headless Chromium.

    .venv/bin/python scripts/docs_screenshot.py                 # -> docs/img/docs_home.png
    .venv/bin/python scripts/docs_screenshot.py --page reference/metrics/ -o /tmp/metrics.png

The site is built strictly (``mkdocs build --strict``) into a temporary folder and served by
Python's ``http.server`` on 127.0.0.1 (Material's search needs HTTP, not ``file://``).
"""

from __future__ import annotations

import argparse
import functools
import http.server
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def build_site(out: Path) -> None:
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-q", "-d",
                           str(out)], cwd=REPO, capture_output=True, text=True)
    if proc.returncode != 0:
        sys.exit(f"mkdocs build --strict failed:\n{proc.stderr[-3000:]}")


def screenshot(site: Path, page: str, out: Path, width: int, height: int) -> None:
    from playwright.sync_api import sync_playwright

    from visphy_core.sandbox.browser import find_chromium

    handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(site))
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=httpd.serve_forever, daemon=True).start()
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=find_chromium())
            tab = browser.new_page(viewport={"width": width, "height": height})
            tab.goto(f"http://127.0.0.1:{httpd.server_address[1]}/{page}")
            tab.wait_for_load_state("networkidle")
            out.parent.mkdir(parents=True, exist_ok=True)
            tab.screenshot(path=str(out))
            browser.close()
    finally:
        httpd.shutdown()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--page", default="", help="the page's path in the site ('' = home)")
    parser.add_argument("-o", "--out", type=Path, default=REPO / "docs/img/docs_home.png")
    parser.add_argument("--size", default="1280x900", help="viewport WxH")
    args = parser.parse_args(argv)
    width, height = (int(v) for v in args.size.split("x"))
    with tempfile.TemporaryDirectory() as tmp:
        build_site(Path(tmp) / "site")
        screenshot(Path(tmp) / "site", args.page, args.out, width, height)
    print(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
