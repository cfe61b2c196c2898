"""The docs' MLflow screenshots: the experiment's runs list and the compare-runs page.

    .venv/bin/python scripts/mlflow_screenshot.py --make-runs    # small offline runs, then shoot
    .venv/bin/python scripts/mlflow_screenshot.py --home visphy-out

``--make-runs`` first runs, into ``--home`` (a scratch folder by default), three single runs
(the oracle, the static baseline and the flow extrapolation on threejs) and the leaderboard
study (the oracle and the static baseline on threejs and p5), two scenes of the mini split
each, a few metrics of five families, normalised. Then it serves the home's MLflow store with
``mlflow server`` on loopback and, in headless Chromium (Debian's, through playwright), saves

* ``mlflow_runs.png``: the runs list, names ``model · engine · dataset`` (a study's jobs
  under it, named by their swept values), with the columns headline, its interval, the family
  means and the success rate (set in the page's saved state, as the Columns menu would);
* ``mlflow_compare_runs.png``: the compare page of the three newest single runs, the parallel
  coordinates plot showing ``model.name`` against the headline and the family means, the
  params and metrics that differ.

Needs the full ``mlflow`` package (the core install has it).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.parse
import urllib.request
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
#: A few metrics of five families (the headline's components among them), normalised (the
#: family means need it), two scenes of the mini split.
CHEAP = ["metrics.names=[psnr,ssim,ms_ssim,flow_epe_dis,spatiotemporal_iou,"
         "weighted_spatial_iou,track_pos_err]", "metrics.spec_track=false",
         "metrics.variance_norm=true", "run.progress=false", "dataset=mini", "dataset.limit=2"]
SINGLES = (["model=oracle"], ["model=static"], ["model=flow_extrapolate"])
STUDY = ["-m", "experiment=leaderboard", "model=oracle,static", "engine=threejs,p5"]
#: The runs list's columns, in order (the family columns follow the headline's interval).
HEAD_COLUMNS = ("headline", "headline.lo", "headline.hi")
TAIL_COLUMNS = ("model_success_rate",)
#: What the MLflow UI opens with: no assistant panel.
QUIET_UI = {"mlflow.assistant.panelOpen_v1": "false",
            "mlflow.assistant.fab.autoOpenedOnFirstLoad_v1": "true"}


def make_runs(home: Path) -> None:
    for args in (*[["engine=threejs", *a] for a in SINGLES], STUDY):
        cmd = [sys.executable, "-m", "visphy_core", *args, *CHEAP]
        print("running", " ".join(cmd[3:]), flush=True)
        subprocess.run(cmd, cwd=REPO, env=dict(os.environ, VISPHY_HOME=str(home)), check=True,
                       stdout=subprocess.DEVNULL)


def find_runs(uri: str) -> tuple[str, list[str], list[str], list[str]]:
    """(experiment id, the three newest single runs, the study parents, the family metrics)."""
    from mlflow.tracking import MlflowClient

    client = MlflowClient(tracking_uri=uri)
    exp = client.get_experiment_by_name("visphy")
    if exp is None:
        raise SystemExit(f"no experiment 'visphy' in {uri}: make runs first (--make-runs)")
    runs = client.search_runs([exp.experiment_id], order_by=["attributes.start_time DESC"])
    singles = [r.info.run_id for r in runs if "mlflow.parentRunId" not in r.data.tags
               and r.data.tags.get("visphy.role") != "study"][:3]
    parents = [r.info.run_id for r in runs if r.data.tags.get("visphy.role") == "study"]
    families = sorted({k for r in runs for k in r.data.metrics if k.startswith("family.")})
    if len(singles) < 2 or not families:
        raise SystemExit(f"{uri}: no two single runs with family means (--make-runs)")
    return exp.experiment_id, singles, parents, families


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def serve(home: Path, port: int) -> subprocess.Popen:
    mlflow = Path(sys.executable).with_name("mlflow")
    proc = subprocess.Popen([str(mlflow), "server", "--host", "127.0.0.1", "--port", str(port),
                             "--workers", "1", "--backend-store-uri",
                             f"sqlite:///{home.resolve() / 'mlflow.db'}",
                             "--default-artifact-root", (home.resolve() / "mlartifacts").as_uri()],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)  # a group: the server and its worker
    deadline = time.monotonic() + 180
    while time.monotonic() < deadline:
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/health", timeout=2):
                return proc
        except OSError:
            if proc.poll() is not None:
                raise SystemExit("mlflow server exited; is the full mlflow package installed?")
            time.sleep(0.3)
    os.killpg(proc.pid, signal.SIGTERM)
    raise SystemExit("mlflow server did not answer /health within 180 s")


def runs_list_state(exp_id: str, parents: list[str], families: list[str]) -> dict[str, str]:
    """The experiment page's saved state (local storage) that the Columns menu would leave:
    the headline, its interval, the family means and the success rate as columns, a wide run
    name, the studies expanded."""
    columns = [f"metrics.`{k}`" for k in (*HEAD_COLUMNS, *families, *TAIL_COLUMNS)]
    state = {"searchFilter": "", "orderByKey": "attributes.start_time", "orderByAsc": False,
             "startTime": "ALL", "lifecycleFilter": "Active", "datasetsFilter": [],
             "modelVersionFilter": "All Runs", "selectedColumns": columns,
             "columnOrder": ["attributes.`Run Name`", *columns],
             "columnWidths": {"attributes.`Run Name`": 270,
                              **{c: 108 for c in columns}},
             "runsExpanded": {p: True for p in parents}, "runsPinned": [], "runsHidden": [],
             "runsVisibilityMap": {}, "runsHiddenMode": "FIRST_10_RUNS",
             "viewMaximized": False, "runListHidden": False, "groupBy": None,
             "groupsExpanded": {}, "autoRefreshEnabled": False}
    return {**QUIET_UI,
            f'MLflowLocalStorage-1.1-ExperimentPage-["{exp_id}"]-ReactComponentState':
                json.dumps(state)}


def _browser(p):
    from visphy_core.sandbox.browser import find_chromium

    return p.chromium.launch(executable_path=find_chromium(), args=[
        "--disable-background-networking", "--disable-component-update", "--disable-sync",
        "--no-first-run"])


def _page(browser, width: int, height: int, storage: dict[str, str]):
    page = browser.new_page(viewport={"width": width, "height": height},
                            device_scale_factor=1)
    page.add_init_script(f"Object.entries({json.dumps(storage)})"
                         ".forEach(([k, v]) => localStorage.setItem(k, v));")
    return page


def _fold_sidebar(page) -> None:
    page.get_by_role("button", name="Toggle sidebar").first.click()


def shoot_runs_list(p, url: str, storage: dict[str, str], out: Path, width: int) -> None:
    page = _page(_browser(p), width, 540, storage)
    page.goto(url)
    # the list is there once it shows a single run's name (the UI polls: never network-idle)
    page.get_by_text(" · threejs · mini", exact=False).first.wait_for(timeout=180_000)
    page.get_by_text("model=oracle engine=p5", exact=False).first.wait_for(timeout=60_000)
    _fold_sidebar(page)
    time.sleep(2)
    page.screenshot(path=str(out))


def shoot_compare(p, url: str, families: list[str], out: Path, width: int) -> None:
    page = _page(_browser(p), width, 1500, QUIET_UI)
    page.goto(url)
    page.get_by_text(" · threejs · mini", exact=False).first.wait_for(timeout=180_000)
    _fold_sidebar(page)
    time.sleep(2)
    # the parallel coordinates plot: model.name (its default diff params, model.style left
    # out: only the oracle has one) against the headline (its default metric) and the families
    select = ".du-bois-light-select"  # MLflow's design system's (antd's) select
    chips = page.locator(f"{select}-selection-item-content")
    metrics = page.locator(select).nth(1)
    for _ in range(3):  # a click while the list re-renders is lost or lands on another option
        for family in [f for f in families if f not in chips.all_inner_texts()]:
            metrics.click()
            page.keyboard.type(family)
            time.sleep(0.5)  # the options filtered by what was typed
            page.locator(f'{select}-item-option[title="{family}"]').click()
            time.sleep(0.5)
        page.keyboard.press("Escape")
    style = page.locator(f"{select}-selection-item", has_text="model.style")
    if style.count():
        style.locator(f"{select}-selection-item-remove").click()
        time.sleep(0.5)
    chosen = chips.all_inner_texts()
    if not set(families) <= set(chosen):
        raise SystemExit(f"the plot's metrics are {chosen}, not the families {families}")
    for section in ("Parameters", "Metrics", "Tags"):  # what differs between the runs
        page.get_by_role("switch", name=f"{section} - Show diff only").click()
    page.get_by_role("button", name="Artifacts").click()  # fold the previews away
    page.get_by_text("Comparing", exact=False).first.scroll_into_view_if_needed()
    time.sleep(2)
    page.mouse.move(0, 0)
    page.screenshot(path=str(out), full_page=False)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--home", type=Path, default=None,
                        help="a VISPHY_HOME holding mlflow.db (default: a scratch folder)")
    parser.add_argument("--make-runs", action="store_true")
    parser.add_argument("--out-dir", type=Path, default=REPO / "docs" / "img")
    parser.add_argument("--width", type=int, default=1600)
    args = parser.parse_args()
    home = args.home or Path(tempfile.mkdtemp(prefix="visphy-mlflow-shot-"))
    if args.make_runs:
        make_runs(home)
    exp_id, singles, parents, families = find_runs(
        f"sqlite:///{home.resolve() / 'mlflow.db'}")
    port = free_port()
    server = serve(home, port)
    args.out_dir.mkdir(parents=True, exist_ok=True)
    runs_png = args.out_dir / "mlflow_runs.png"
    compare_png = args.out_dir / "mlflow_compare_runs.png"
    try:
        from playwright.sync_api import sync_playwright

        base = f"http://127.0.0.1:{port}/#"
        query = urllib.parse.urlencode({"runs": json.dumps(singles),
                                        "experiments": json.dumps([exp_id])})
        with sync_playwright() as p:
            shoot_runs_list(p, f"{base}/experiments/{exp_id}/runs",
                            runs_list_state(exp_id, parents, families), runs_png, args.width)
            shoot_compare(p, f"{base}/compare-runs?{query}", families, compare_png, args.width)
    finally:
        os.killpg(server.pid, signal.SIGTERM)
        server.wait(timeout=30)
    print(f"{runs_png}\n{compare_png}: {len(singles)} runs compared")


if __name__ == "__main__":
    main()
