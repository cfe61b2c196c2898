"""HTML building blocks of the reports: escaping, numbers, tables and the page shell.

Everything a model, a judge or a dataset wrote is untrusted: it enters a page only through
`esc` (text) or `attr` (attribute values). As a second wall, every page carries a Content
Security Policy that lets only the report's own inline script run (by its SHA-256), loads media
only from the report's folder, and allows no network request at all, so even a missed escape
could neither run a script nor reach the network.
"""

from __future__ import annotations

import base64
import hashlib
import html
from importlib import resources
from typing import Any, Iterable
from urllib.parse import quote

from visphy_core.infra.numbers import number

ARROWS = {"higher": "↑", "lower": "↓"}


def esc(value: Any) -> str:
    """Text content, escaped (``<``, ``>``, ``&`` and both quotes)."""
    return html.escape("" if value is None else str(value), quote=True)


def attr(value: Any) -> str:
    """An attribute value, escaped and quoted."""
    return f'"{esc(value)}"'


def url(relative_path: str) -> str:
    """A relative URL for a file of the report folder (every path segment percent-encoded)."""
    return quote(relative_path, safe="/")


def fmt(value: Any, digits: int = 4) -> str:
    """A score for people, as the console writes it (`visphy_core.infra.numbers.number`):
    ``digits`` significant figures; ``—`` for none; NaN/inf spelled; no negative zero."""
    return number(value, digits)


def rate(part: int | None, whole: int | None) -> str:
    if not whole:
        return f"{part or 0}/0"
    return f"{part}/{whole} ({100.0 * (part or 0) / whole:.1f}%)"


def arrow(direction: str | None) -> str:
    symbol = ARROWS.get(str(direction), "")
    if not symbol:
        return ""
    better = "higher" if direction == "higher" else "lower"
    return f'<span class="dir" title="{better} is better">{symbol}</span>'


def table(headers: Iterable[str], rows: Iterable[Iterable[str]], cls: str = "",
          attrs: str = "") -> str:
    """A table from cells that are already HTML (callers escape what they put in)."""
    head = "".join(f"<th>{h}</th>" for h in headers)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>" for row in rows)
    cls_attr = f" class={attr(cls)}" if cls else ""
    return f"<table{cls_attr}{attrs}><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def details(summary: str, body: str, open_: bool = False, cls: str = "") -> str:
    """A folded block; ``summary`` is HTML (escape it first)."""
    cls_attr = f" class={attr(cls)}" if cls else ""
    return (f"<details{cls_attr}{' open' if open_ else ''}><summary>{summary}</summary>"
            f"{body}</details>")


def pre(text: str, cls: str = "") -> str:
    """Untrusted text (a program, a reply, a log) shown verbatim."""
    cls_attr = f" class={attr(cls)}" if cls else ""
    return f"<pre{cls_attr}><code>{esc(text)}</code></pre>"


def asset(name: str) -> str:
    return resources.files("visphy_core.report").joinpath("assets", name).read_text("utf-8")


def csp(script: str) -> str:
    """The Content-Security-Policy of a page that runs exactly ``script`` (by its digest) and
    loads nothing from outside its folder."""
    digest = base64.b64encode(hashlib.sha256(script.encode("utf-8")).digest()).decode()
    return ("default-src 'none'; "
            f"script-src 'sha256-{digest}'; style-src 'unsafe-inline'; "
            "img-src 'self' file: data:; media-src 'self' file:; "
            "base-uri 'none'; form-action 'none'")


def page(title: str, body: str, with_script: bool = True) -> str:
    """A complete page: the stylesheet and the script inline, nothing fetched from anywhere."""
    script = asset("report.js") if with_script else ""
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<meta http-equiv=\"Content-Security-Policy\" content={attr(csp(script))}>"
            "<meta name=\"referrer\" content=\"no-referrer\">"
            "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
            f"<title>{esc(title)}</title><style>{asset('report.css')}</style></head>"
            f"<body>{body}" + (f"<script>{script}</script>" if script else "")
            + "</body></html>\n")
