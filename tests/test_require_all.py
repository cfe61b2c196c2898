"""`VISPHY_REQUIRE_ALL=1` (tests/conftest.py, set by CI) turns every skip into a failure that
names the skip's reason: a skip in a test, in a fixture, from a mark, a module-level skip and
the browser auto-skip. Without it they stay skips; `skip_ok` keeps a skip a skip either way.

Each case runs pytest in a subprocess on a tiny generated test file next to a copy of the real
tests/conftest.py (so the hooks under test are the ones the suite uses)."""

from __future__ import annotations

import pytest

from conftest import REPO, REQUIRE_ALL_ENV

pytest_plugins = ["pytester"]

CASES = """
import pytest

def test_passes():
    pass

def test_skips_in_the_body():
    pytest.skip("bubblewrap is missing here")

@pytest.mark.skipif(True, reason="no such tool")
def test_skipif_mark():
    pass

@pytest.fixture
def needs_a_package():
    pytest.importorskip("visphy_no_such_package_xyz")

def test_skips_in_a_fixture(needs_a_package):
    pass

@pytest.mark.skip_ok(reason="another platform")
@pytest.mark.skipif(True, reason="glibc only")
def test_allowed_skip():
    pass

@pytest.mark.xfail(reason="a known bug", strict=True)
def test_xfail_is_not_a_skip():
    assert False
"""

MODULE_SKIP = """
import pytest

pytest.skip("Manim CE is not importable", allow_module_level=True)

def test_never_collected():
    pass
"""

MODULE_IMPORTORSKIP = """
import pytest

pytest.importorskip("visphy_no_such_package_xyz")

def test_never_collected():
    pass
"""

BROWSER = """
import pytest

@pytest.mark.browser
def test_needs_chromium():
    pass

def test_without_a_browser():
    pass
"""


@pytest.fixture
def run(pytester, monkeypatch):
    conftest = (REPO / "tests" / "conftest.py").read_text()

    def go(source: str, require_all: bool, no_chromium: bool = False):
        text = conftest
        if no_chromium:  # the auto-skip looks the name up at collection time
            text += "\n\ndef chromium_available() -> bool:\n    return False\n"
        pytester.makeconftest(text)
        pytester.makepyfile(test_generated=source)
        if require_all:
            monkeypatch.setenv(REQUIRE_ALL_ENV, "1")
        else:
            monkeypatch.delenv(REQUIRE_ALL_ENV, raising=False)
        return pytester.runpytest_subprocess("-p", "no:cacheprovider", "-p", "no:xdist", "-ra")

    return go


def test_without_the_switch_skips_stay_skips(run):
    result = run(CASES, require_all=False)
    result.assert_outcomes(passed=1, skipped=4, xfailed=1)


def test_with_the_switch_each_skip_fails_and_names_its_reason(run):
    result = run(CASES, require_all=True)
    # a skip at setup (a mark, a fixture) fails as an error, one in the test's body as a failure
    result.assert_outcomes(passed=1, failed=1, errors=2, skipped=1, xfailed=1)
    assert result.ret == pytest.ExitCode.TESTS_FAILED
    out = result.stdout.str()
    prefix = f"{REQUIRE_ALL_ENV}=1: this skip would hide a missing dependency: "
    for reason in ("bubblewrap is missing here", "no such tool",
                   "could not import 'visphy_no_such_package_xyz'"):
        assert prefix in out and reason in out, (reason, out[-3000:])
    assert "FAILED test_generated.py::test_skips_in_the_body" in out
    assert "ERROR test_generated.py::test_skipif_mark" in out
    assert "ERROR test_generated.py::test_skips_in_a_fixture" in out
    assert "SKIPPED" in out and "glibc only" in out  # skip_ok: still a skip


@pytest.mark.parametrize("source, reason", [
    (MODULE_SKIP, "Manim CE is not importable"),
    (MODULE_IMPORTORSKIP, "could not import 'visphy_no_such_package_xyz'"),
], ids=["skip", "importorskip"])
def test_a_module_level_skip_fails_collection(run, source, reason):
    result = run(source, require_all=False)
    result.assert_outcomes(skipped=1)
    assert result.ret == pytest.ExitCode.NO_TESTS_COLLECTED
    result = run(source, require_all=True)
    result.assert_outcomes(errors=1)
    assert result.ret != pytest.ExitCode.OK
    out = result.stdout.str()
    assert f"{REQUIRE_ALL_ENV}=1: this skip would hide a missing dependency: " in out
    assert reason in out


def test_the_browser_auto_skip_fails_under_the_switch(run):
    result = run(BROWSER, require_all=False, no_chromium=True)
    result.assert_outcomes(passed=1, skipped=1)
    result = run(BROWSER, require_all=True, no_chromium=True)
    result.assert_outcomes(passed=1, errors=1)
    assert result.ret == pytest.ExitCode.TESTS_FAILED
    assert "ERROR test_generated.py::test_needs_chromium" in result.stdout.str()
    assert "hide a missing dependency: Chromium not installed" in result.stdout.str()
