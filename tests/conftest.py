"""Shared fixtures: a built mini dataset, a scratch VISPHY_HOME, and a helper to run the CLI."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

# ------------------------------------------------------------------------------ require-all
#: ``VISPHY_REQUIRE_ALL=1`` (set by CI, `.ci/run`) turns every skip into a failure: a test of
#: the sandbox or of a metric that skips because bubblewrap, Chromium, Node.js, Manim, Blender's
#: venv or a Python package is missing would otherwise pass CI green while testing nothing.
#: It covers every way a test can skip: `pytest.skip` / `pytest.importorskip` in a test or a
#: fixture, `skip`/`skipif` marks (the browser auto-skip below included) and module-level skips
#: (`allow_module_level=True`, a module-level `importorskip`), which become collection errors.
#:
#: A skip that never hides a missing dependency (another platform) carries
#: ``@pytest.mark.skip_ok(reason=...)`` and stays a skip; keep that list tiny (today: the glibc
#: allocator tests of test_heap.py on non-Linux systems). xfail is not affected.
REQUIRE_ALL_ENV = "VISPHY_REQUIRE_ALL"


def require_all() -> bool:
    return os.environ.get(REQUIRE_ALL_ENV, "").strip().lower() not in ("", "0", "false", "no")


def _skip_reason(longrepr) -> str:
    if isinstance(longrepr, tuple) and len(longrepr) == 3:  # (path, lineno, reason)
        path, lineno, reason = longrepr
        return f"{reason.removeprefix('Skipped: ')} ({path}:{lineno})"
    return str(longrepr)


def _as_failure(report) -> None:
    report.longrepr = (f"{REQUIRE_ALL_ENV}=1: this skip would hide a missing dependency: "
                       f"{_skip_reason(report.longrepr)}")
    report.outcome = "failed"


def pytest_configure(config):
    config.addinivalue_line(
        "markers", "skip_ok(reason): this test's skip is not about a missing dependency (e.g. "
        "another platform): it stays a skip under VISPHY_REQUIRE_ALL=1 (tests/conftest.py)")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    report = outcome.get_result()
    if (report.skipped and not hasattr(report, "wasxfail") and require_all()
            and item.get_closest_marker("skip_ok") is None):
        _as_failure(report)


@pytest.hookimpl(hookwrapper=True)
def pytest_make_collect_report(collector):
    outcome = yield
    report = outcome.get_result()
    if report.skipped and require_all():  # a module-level skip: the whole file would vanish
        _as_failure(report)


def chromium_available() -> bool:
    from visphy_core.sandbox.browser import BrowserUnavailable, find_chromium

    try:
        find_chromium()
    except BrowserUnavailable:
        return False
    return True


#: The longest test files (seconds on 2 cores, `--durations=0`), run first so that parallel
#: workers (`make test TEST_WORKERS=2`) do not end on one of them while the other idles.
LONGEST_FIRST = ("test_engines_browser.py", "test_experiments.py", "test_hostile_browser.py",
                 "test_resume.py", "test_models_e2e.py", "test_launchers.py",
                 "test_metric_suite_e2e.py", "test_hostile_process.py", "test_analysis_runs.py",
                 "test_config_values.py", "test_workers.py", "test_run_faults.py",
                 "test_judges.py", "test_render_paths.py", "test_browser_engine.py",
                 "test_shipped_catalogue.py")


def _file_rank(item) -> int:
    name = item.path.name
    return LONGEST_FIRST.index(name) if name in LONGEST_FIRST else len(LONGEST_FIRST)


def pytest_collection_modifyitems(config, items):
    items.sort(key=_file_rank)  # stable: each file keeps its own order
    if chromium_available():
        return
    # a skip, so that machines without Chromium can still run the rest; under
    # VISPHY_REQUIRE_ALL=1 each of these skips fails (pytest_runtest_makereport above)
    skip = pytest.mark.skip(reason="Chromium not installed (run `make setup`)")
    for item in items:
        if "browser" in item.keywords:
            item.add_marker(skip)


@pytest.fixture(scope="session")
def mini_root(tmp_path_factory) -> Path:
    """The generated benchmark with its `mini` split rendered, built once per test session
    (its catalogue is the one shipped with visphy: nothing is simulated).

    Built **lossless** (exact RGB clips) and placed where a default run looks for it: the
    tests compare reference programs, oracles and metrics with the exact ground truth, not
    with the published-style crf-23 encoding (tested on its own in test_ground_truth.py).

    Under pytest-xdist every worker shares one build: the first worker to take the lock in
    the session's common temp dir builds it, the others wait and reuse it (read-only)."""
    from filelock import FileLock

    from visphy_plugins.datasets.visphybench.build import build_dataset, dataset_root

    if os.environ.get("PYTEST_XDIST_WORKER") is None:
        data = tmp_path_factory.mktemp("data")
        exact = build_dataset(data, split="mini", progress=False, lossless=True)
        return exact.rename(dataset_root(data))
    shared = tmp_path_factory.getbasetemp().parent / "shared-mini"
    shared.mkdir(exist_ok=True)
    with FileLock(str(shared / ".lock")):
        done = shared / "data" / ".built"
        root = dataset_root(shared / "data")
        if not done.exists():
            shutil.rmtree(shared / "data", ignore_errors=True)
            exact = build_dataset(shared / "data", split="mini", progress=False, lossless=True)
            exact.rename(root)
            done.touch()
    return root


@pytest.fixture(scope="session")
def mini_scenes(mini_root):
    from visphy_plugins.datasets.visphybench.loader import load_generated

    return load_generated(mini_root, split="mini")


@pytest.fixture
def visphy_home(tmp_path, mini_root) -> Path:
    """A fresh VISPHY_HOME whose data dir already holds the mini dataset (no rebuild per test)."""
    home = tmp_path / "home"
    shutil.copytree(mini_root, home / "data" / mini_root.name)
    return home


#: Runs that are not about the metrics score only these (loading the learned metrics in every
#: CLI subprocess would cost minutes over the suite); tests of the metric suite name their own.
FAST_METRICS = ("metrics.names=[psnr,ssim]", "metrics.spec_track=false",
                "metrics.variance_norm=false")
SUBCOMMANDS = ("plugins", "setup", "build-dataset", "normalise", "render", "metrics",
               "intervene", "rate", "score", "analyse", "merge", "ground-truth")


def with_fast_metrics(args: tuple[str, ...]) -> tuple[str, ...]:
    """``args`` plus `FAST_METRICS` when they start a run or a multirun (``-m``) that names no
    ``metrics`` setting; subcommands and other flags (``--cfg``, ``--help``) are left alone."""
    if not args or args[0] in SUBCOMMANDS:
        return args
    if args[0].startswith("-") and args[0] not in ("-m", "--multirun"):
        return args
    if any(a.lstrip("+~").startswith("metrics") for a in args):
        return args
    return (*args, *FAST_METRICS)


def run_cli(*args: str, home: Path, env: dict | None = None, timeout: int = 600,
            check: bool = True) -> subprocess.CompletedProcess:
    """Run `python -m visphy_core ARGS` as a user would, with VISPHY_HOME=home."""
    full_env = dict(os.environ, VISPHY_HOME=str(home), **(env or {}))
    args = with_fast_metrics(args)
    proc = subprocess.run([sys.executable, "-m", "visphy_core", *args], cwd=REPO,
                          env=full_env, capture_output=True, text=True, timeout=timeout)
    if check and proc.returncode != 0:
        raise AssertionError(f"visphy exited {proc.returncode}\nstdout:\n{proc.stdout[-4000:]}\n"
                             f"stderr:\n{proc.stderr[-4000:]}")
    return proc
