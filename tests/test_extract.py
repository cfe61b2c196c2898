"""Reply parsing: analysis, JSON spec and program, and the failure classes of bad replies."""

from __future__ import annotations

import pytest

from visphy_core.api.engine import FailureClass, ProgramRejected
from visphy_core.api.extract import extract_analysis, extract_code, extract_spec

REPLY = """The red ball falls onto the bar and rolls right.

```json
{"bodies": [{"id": "red_ball"}]}
```

```html
<html><body><script>draw()</script></body></html>
```
"""


def test_a_complete_reply_splits_into_its_three_parts():
    assert extract_analysis(REPLY) == "The red ball falls onto the bar and rolls right."
    assert extract_spec(REPLY) == {"bodies": [{"id": "red_ball"}]}
    assert extract_code(REPLY, ("html",)).startswith("<html><body><script>")


def test_bare_html_document_is_accepted_for_browser_engines():
    text = "Here it is:\n<!DOCTYPE html><html><body><canvas></canvas></body></html> done"
    assert extract_code(text, ("html",), html_fallback=True) == \
        "<html><body><canvas></canvas></body></html>"


@pytest.mark.parametrize("text, failure", [
    ("", FailureClass.NO_CODE),
    ("I cannot help with that.", FailureClass.NO_CODE),
    ("analysis\n```html\n<html><script>let x = 1;\n", FailureClass.TRUNCATED),
    ("analysis\n<html><body><script>", FailureClass.TRUNCATED),
    ("analysis\n```python\nprint('hi')\n```\n", FailureClass.WRONG_LANGUAGE),
])
def test_bad_replies_are_classified(text, failure):
    with pytest.raises(ProgramRejected) as info:
        extract_code(text, ("html",), html_fallback=True)
    assert info.value.failure is failure


def test_malformed_json_spec_is_none_not_an_error():
    assert extract_spec("```json\n{not json\n```\n```html\n<html></html>\n```") is None
