"""The leaderboard site in Chromium from file://: a header click sorts, every link resolves to a
file of the site, no console error, and no request leaves the site's folder."""

from __future__ import annotations

from pathlib import Path
from urllib.parse import unquote, urlparse

import pytest

from test_leaderboard import N, write_run
from visphy_core.leaderboard import SiteOptions, build_site

pytestmark = pytest.mark.browser


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("runs")
    base = [0.2 + 0.03 * (i % 7) for i in range(N)]
    for name, shift in (("low", 0.0), ("high", 0.5), ("mid", 0.25)):
        write_run(root, name, name, [v + shift for v in base])
    out = tmp_path_factory.mktemp("site") / "site"
    build_site([root], out, SiteOptions(progress=False))
    return out


def _local(url: str) -> Path | None:
    parsed = urlparse(url)
    return Path(unquote(parsed.path)) if parsed.scheme == "file" else None


def test_the_site_sorts_links_locally_and_requests_nothing_outside(site):
    from playwright.sync_api import sync_playwright

    from visphy_core.sandbox.browser import find_chromium

    outside: list[str] = []
    errors: list[str] = []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=find_chromium())
        page = browser.new_page()

        def route(r):
            path = _local(r.request.url)
            if path is None or site.resolve() not in (path.resolve(), *path.resolve().parents):
                outside.append(r.request.url)
                r.abort()
            else:
                r.continue_()

        page.route("**/*", route)
        page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto((site / "index.html").as_uri())
        order = "() => [...document.querySelectorAll('#leaderboard tbody tr')]" \
                ".map(r => r.cells[2].textContent)"
        before = page.evaluate(order)
        assert before == ["high", "mid", "low"]
        page.click("#leaderboard th:nth-child(3)")          # model: descending text
        first = page.evaluate(order)
        page.click("#leaderboard th:nth-child(3)")          # again: ascending
        second = page.evaluate(order)
        assert first == ["mid", "low", "high"] and second == ["high", "low", "mid"]

        pages = [site / "index.html", site / "breakdowns.html", site / "metrics" / "index.html",
                 *sorted((site / "entries").glob("*.html"))]
        seen: set[Path] = set()
        for html in pages:
            page.goto(html.as_uri())
            hrefs = page.evaluate("() => [...document.querySelectorAll('a[href]')]"
                                  ".map(a => a.href)")
            for href in hrefs:
                target = _local(href.split("#")[0])
                assert target is not None, f"{html.name}: link {href} leaves the site"
                assert target.is_file(), f"{html.name}: link {href} resolves to no file"
                seen.add(target)
        for target in sorted(seen):                          # every linked page loads cleanly
            if target.suffix == ".html":
                page.goto(target.as_uri())
        browser.close()
    assert outside == []
    assert errors == []
    assert any(t.parent.parent.name == "runs" for t in seen)   # the copied run reports
