"""Split a model reply into analysis A, scene specification S and program C.

Shared by every engine: engines only say which fence languages they accept and whether a bare
``<html>…</html>`` document counts as a program.
"""

from __future__ import annotations

import json
import re

from visphy_core.api.engine import FailureClass, ProgramRejected

_FENCE = re.compile(r"^[ \t]*```[ \t]*([A-Za-z0-9_+.-]*)[^\n]*\n", re.M)
_CLOSE = re.compile(r"^[ \t]*```[ \t]*$", re.M)


def fenced_blocks(text: str) -> tuple[list[tuple[str, str]], str | None]:
    """Complete fenced blocks as (language, body), and the language of an unclosed last fence."""
    blocks: list[tuple[str, str]] = []
    pos = 0
    while True:
        m = _FENCE.search(text, pos)
        if m is None:
            return blocks, None
        close = _CLOSE.search(text, m.end())
        if close is None:
            return blocks, m.group(1).lower() or "text"
        blocks.append((m.group(1).lower(), text[m.end():close.start()]))
        pos = close.end()


def extract_code(text: str, languages: tuple[str, ...], html_fallback: bool = False) -> str:
    """The program in a reply: the longest fenced block in one of ``languages``.

    Falls back to the outermost ``<html>…</html>`` for browser engines. Raises `ProgramRejected`
    with no_code, truncated or wrong_language.
    """
    if not text or not text.strip():
        raise ProgramRejected(FailureClass.NO_CODE, "empty reply")
    blocks, unclosed = fenced_blocks(text)
    wanted = [body for lang, body in blocks if lang in languages and body.strip()]
    if wanted:
        return max(wanted, key=len)
    if unclosed is not None and (unclosed in languages or unclosed == "text"):
        raise ProgramRejected(FailureClass.TRUNCATED,
                              f"the ```{unclosed} block is never closed (reply cut off?)")
    if html_fallback:
        low = text.lower()
        start = low.find("<html")
        if start != -1:
            end = low.rfind("</html>")
            if end == -1:
                raise ProgramRejected(FailureClass.TRUNCATED, "<html> document without </html>")
            return text[start:end + len("</html>")]
    other = sorted({lang or "unlabelled" for lang, body in blocks
                    if lang not in ("json",) and body.strip()})
    if other:
        raise ProgramRejected(FailureClass.WRONG_LANGUAGE,
                              f"expected a ```{languages[0]} block, found: {', '.join(other)}")
    raise ProgramRejected(FailureClass.NO_CODE, f"no ```{languages[0]} block in the reply")


def extract_spec(text: str) -> dict | None:
    """The reply's JSON scene specification S (the first ```json block that parses), or None."""
    blocks, _ = fenced_blocks(text or "")
    for lang, body in blocks:
        if lang == "json":
            try:
                value = json.loads(body)
            except json.JSONDecodeError:
                continue
            if isinstance(value, dict):
                return value
    return None


def extract_analysis(text: str) -> str:
    """The motion analysis A: the prose before the first fence (the whole reply if none)."""
    m = _FENCE.search(text or "")
    prose = (text or "")[: m.start()] if m else (text or "")
    return re.sub(r"^#+\s*analysis\s*:?\s*$", "", prose.strip(), flags=re.I | re.M).strip()
