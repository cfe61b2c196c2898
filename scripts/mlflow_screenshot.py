"""The README's MLflow screenshot: the compare-runs page with the jobs of two studies side by side.

    .venv/bin/python scripts/mlflow_screenshot.py --make-studies   # two small studies, then shoot
    .venv/bin/python scripts/mlflow_screenshot.py --home visphy-out --studies leaderboard baselines

``--make-studies`` first runs two small offline studies into ``--home`` (a scratch folder by
default): the leaderboard (the oracle and the static baseline on threejs and p5) and the
baselines (static and flow extrapolation), two mini scenes each, cheap metrics. Then it serves
the home's MLflow store with ``mlflow server`` on loopback, opens the compare-runs page of the
newest run of each study's children in headless Chromium (Debian's, through playwright) and
saves a PNG. Needs the full ``mlflow`` package (the ``ui`` or ``test`` extra).
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
CHEAP = ["metrics.names=[psnr,ssim,flow_epe_dis]", "metrics.spec_track=false",
         "metrics.variance_norm=false", "run.progress=false", "dataset=mini", "dataset.limit=2"]
STUDY_RUNS = {"leaderboard": ["model=oracle,static", "engine=threejs,p5"],
              "baselines": ["model=static,flow_extrapolate"]}


def make_studies(home: Path, studies: list[str]) -> None:
    for study in studies:
        cmd = [sys.executable, "-m", "visphy_core", "-m", f"experiment={study}",
               *STUDY_RUNS.get(study, []), *CHEAP]
        print("running", " ".join(cmd[3:]), flush=True)
        subprocess.run(cmd, cwd=REPO, env=dict(os.environ, VISPHY_HOME=str(home)), check=True,
                       stdout=subprocess.DEVNULL)


def study_children(uri: str, studies: list[str]) -> tuple[str, list[str]]:
    """(experiment id, run ids): the children of the newest parent run of each study."""
    from mlflow.tracking import MlflowClient

    client = MlflowClient(tracking_uri=uri)
    exp = client.get_experiment_by_name("visphy")
    if exp is None:
        raise SystemExit(f"no experiment 'visphy' in {uri}: run studies first (--make-studies)")
    runs: list[str] = []
    for study in studies:
        parents = client.search_runs(
            [exp.experiment_id], f"tags.`visphy.study` = '{study}' and tags.`visphy.role` = "
            "'study'", order_by=["attributes.start_time DESC"], max_results=1)
        if not parents:
            raise SystemExit(f"no study '{study}' in {uri}")
        children = client.search_runs(
            [exp.experiment_id], f"tags.`mlflow.parentRunId` = '{parents[0].info.run_id}'",
            order_by=["attributes.run_name ASC"])
        runs += [r.info.run_id for r in children]
    return exp.experiment_id, runs


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


def shoot(url: str, out: Path, width: int, height: int) -> None:
    from playwright.sync_api import sync_playwright

    from visphy_core.sandbox.browser import find_chromium

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=find_chromium(), args=[
            "--disable-background-networking", "--disable-component-update", "--disable-sync",
            "--no-first-run"])
        page = browser.new_page(viewport={"width": width, "height": height},
                                device_scale_factor=1)
        page.goto(url)
        # the compare table is there once it shows a run's name (a child is named by its
        # swept values, "model=... engine=..."); the UI keeps polling, never network-idle
        page.get_by_text("model=", exact=False).first.wait_for(timeout=180_000)
        close = page.get_by_role("button", name="Close")  # the assistant side panel
        if close.count():
            close.first.click()
        page.get_by_role("button", name="Visualizations").click()  # fold the chart away
        for section in ("Parameters", "Metrics", "Tags"):  # what differs between the runs
            page.get_by_role("switch", name=f"{section} - Show diff only").click()
        page.get_by_role("button", name="Artifacts").click()  # fold the previews away
        page.get_by_text("Comparing", exact=False).first.scroll_into_view_if_needed()
        time.sleep(3)
        out.parent.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(out))
        browser.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--home", type=Path, default=None,
                        help="a VISPHY_HOME holding mlflow.db (default: a scratch folder)")
    parser.add_argument("--studies", nargs=2, default=["leaderboard", "baselines"])
    parser.add_argument("--make-studies", action="store_true")
    parser.add_argument("--out", type=Path, default=REPO / "docs" / "mlflow_compare.png")
    parser.add_argument("--size", default="1600x1560")
    args = parser.parse_args()
    home = args.home or Path(tempfile.mkdtemp(prefix="visphy-mlflow-shot-"))
    if args.make_studies:
        make_studies(home, args.studies)
    exp_id, runs = study_children(f"sqlite:///{home.resolve() / 'mlflow.db'}", args.studies)
    port = free_port()
    server = serve(home, port)
    try:
        query = urllib.parse.urlencode({"runs": json.dumps(runs),
                                        "experiments": json.dumps([exp_id])})
        width, height = (int(v) for v in args.size.split("x"))
        shoot(f"http://127.0.0.1:{port}/#/compare-runs?{query}", args.out, width, height)
    finally:
        os.killpg(server.pid, signal.SIGTERM)
        server.wait(timeout=30)
    print(f"{args.out}: {len(runs)} runs of {' and '.join(args.studies)} compared")


if __name__ == "__main__":
    main()
