"""What a run writes about itself (`visphy_core.execute.run`): its config and manifest when it
opens, its summary when it closes (`_run_summary`), the closing writes that survive a full disk
(`_ClosingWrites`, `_host_fault_line`), the HTML report, and the lines a person reads at the
end (`_print_end`)."""

from __future__ import annotations

import datetime as dt
import errno
import logging
import os
import platform
import signal
import sys
import time
from pathlib import Path
from typing import Any

from omegaconf import DictConfig

from visphy_core.api.registry import get_plugin_manager
from visphy_core.api.run_context import RunContext
from visphy_core.api.scene import Scene
from visphy_core.calls.usage import CostCapReached, UsageLedger
from visphy_core.execute.console import print_summary, print_where_to_look
from visphy_core.execute.pipeline import SceneServices
from visphy_core.execute.run_setup import RunSetup, headline_column
from visphy_core.infra.cache import Cache
from visphy_core.infra.errors import describe_host_fault, host_fault
from visphy_core.results.row import SceneResult
from visphy_core.results.run_dir import COST_CAP, FAILED, FINISHED, INTERRUPTED, RUNNING, RunDir
from visphy_core.results.summary import summarise
from visphy_core.scoring.score import score_columns

log = logging.getLogger("visphy.run")


def _manifest(ctx: RunContext, setup: RunSetup) -> dict:
    pm = get_plugin_manager()
    from visphy_core.api.registry import describe_plugins

    return {
        "visphy_version": _version(),
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "argv": sys.argv,
        "started": dt.datetime.now().isoformat(timespec="seconds"),
        "status": RUNNING,
        "config_hash": setup.config_hash,
        "isolation": setup.isolation,
        "plugins": {p.name: {"distribution": p.distribution, "version": p.version}
                    for p in describe_plugins(pm)},
        "scenes": [s.scene_id for s in ctx.scenes],
        "datasets": sorted({s.dataset for s in ctx.scenes if s.dataset}),
        "metrics": [m.describe() for m in ctx.metrics],
        "model": setup.model,
        "judges": ctx.judges,
        "cost_cap_usd": ctx.cfg.run.get("cost_cap_usd"),
        "workers": setup.workers,
    }


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("visphy")
    except PackageNotFoundError:
        return "source"


def write_report(run_dir: Path) -> Path | None:
    """The run's HTML report (`visphy_core.report.write_run_report`) when that module is
    installed; a report that fails is a warning, never a failed run."""
    from importlib.util import find_spec

    if find_spec("visphy_core.report") is None:
        return None
    try:
        from visphy_core.report import write_run_report

        return Path(write_run_report(run_dir))
    except Exception as exc:  # noqa: BLE001 - the run's results are already written
        log.warning("the HTML report of %s failed: %s: %s", run_dir, type(exc).__name__, exc)
        return None


def _open_run(cfg: DictConfig, root: Path, cache: Cache, scenes: list[Scene], metrics,
              judge_keys: list[str], files: RunDir, run_dir: Path,
              restored: list[SceneResult], setup: RunSetup) -> tuple[RunContext, dict]:
    """Write the run's config and manifest; the context the lifecycle hooks receive, with the
    rows a resume restored."""
    files.write_config(cfg)  # no credentials in URLs
    ctx = RunContext(cfg=cfg, run_dir=run_dir, root=root, scenes=scenes,
                     model_name=cfg.model.name, engine_name=cfg.engine.name, metrics=metrics,
                     cache=cache, judges=judge_keys, config_hash=setup.config_hash,
                     resumed_from=dict(setup.resumed_from))
    manifest = _manifest(ctx, setup)
    if restored:
        manifest["resumed_rows"] = len(restored)
    files.write_manifest(manifest)
    ctx.results.extend(restored)
    return ctx, manifest


class _ClosingWrites:
    """The run's closing writes: a fault of the machine (a full disk) in one is recorded and
    the others are still tried (the rows in results.jsonl are already safe); any other error
    is raised."""

    def __init__(self, faults: list[OSError]):
        self.faults = faults

    def do(self, write, *args, **kwargs) -> None:
        try:
            write(*args, **kwargs)
        except OSError as exc:
            fault = host_fault(exc)
            if fault is None:
                raise
            self.faults.append(fault)


def _tree_bytes(path: Path) -> int:
    total = 0
    for folder, _, names in os.walk(path):
        for name in names:
            try:
                total += os.lstat(os.path.join(folder, name)).st_size
            except OSError:
                continue
    return total


def _host_fault_line(fault: OSError, run_dir: Path, results: list[SceneResult],
                     scenes: list[Scene]) -> str:
    """One line: the machine's refusal (`describe_host_fault`), what is kept, what the rest
    of the run needs, and how to go on."""
    left = len(scenes) - len(results)
    need = ""
    if results and left and fault.errno in (errno.ENOSPC, errno.EDQUOT):
        per_scene = sum(_tree_bytes(RunDir(run_dir).scene_dir(r.scene_id)) for r in results) \
            / len(results)
        need = (f"; the {left} scene(s) left need about "
                f"{max(per_scene * left, 1) / 2**20:.1f} MB in the run directory, plus the "
                "cache's share")
    what = "free some space" if fault.errno in (errno.ENOSPC, errno.EDQUOT) else "fix that"
    return (f"{describe_host_fault(fault)}; {len(results)}/{len(scenes)} scenes kept in "
            f"{run_dir}{need}: {what}, then rerun the same command to resume")


def _run_summary(ctx: RunContext, cfg: DictConfig, services: SceneServices, setup: RunSetup,
                 ledger: UsageLedger, cache: Cache, resumed_rows: int, status: str,
                 raised: BaseException | None, cost_stop: CostCapReached | None,
                 ground_truth: dict[str, Any] | None) -> dict:
    """The run's summary: `summarise` of its rows, with how the run ended."""
    scenes, metrics = ctx.scenes, services.metrics
    summary = summarise(ctx.results, metrics, score_columns(metrics, services.protocol),
                        cache_stats=cache.stats(), judges=ctx.judges, usage=ledger.totals(),
                        headline=headline_column(services.headline))
    summary.update({"status": status, "run_dir": str(ctx.run_dir), "model": cfg.model.name,
                    "model_output": services.model.output_kind,
                    "model_baseline": services.model.baseline,
                    "engine": cfg.engine.name, "dataset": cfg.dataset.name,
                    "n_selected": len(scenes), "resumed_rows": resumed_rows,
                    "config_hash": setup.config_hash,
                    "isolation_levels": setup.isolation})
    if ground_truth:
        summary["ground_truth"] = ground_truth
    if cost_stop is not None:
        done_ids = {r.scene_id for r in ctx.results}
        summary["cost_cap"] = {
            "cap_usd": cost_stop.cap_usd, "spent_usd": ledger.spent_usd,
            "not_run": [s.scene_id for s in scenes if s.scene_id not in done_ids],
            "message": f"{cost_stop}; {len(scenes) - len(done_ids)} of {len(scenes)} "
                       "scenes not run: raise run.cost_cap_usd and rerun the same command "
                       "to continue"}
    if cache.warnings:
        summary["cache_warnings"] = list(cache.warnings)
    if status == INTERRUPTED:
        summary["interrupted_by"] = signal.Signals(raised.signum).name
    elif status == FAILED:
        summary["error"] = f"{type(raised).__name__}: {raised}"
    return summary


def _print_end(summary: dict, ctx: RunContext, cfg: DictConfig, status: str,
               started: float) -> None:
    """What a person reads when the run ends: the summary and where to look, or why it
    stopped."""
    scenes, run_dir = ctx.scenes, ctx.run_dir
    if status in (FINISHED, COST_CAP):
        print_summary(summary, ctx.results, mode=str(cfg.run.get("summary", "short")),
                      wall_s=time.monotonic() - started)
        print_where_to_look(write_report(run_dir), ctx.where_to_look)
    if summary.get("tracking_failed"):
        print(summary["tracking_failed"], file=sys.stderr)
    if status == COST_CAP:
        print(f"stopped: {summary['cost_cap']['message']}", file=sys.stderr)
    elif status != FINISHED:
        print(f"run {status} after {len(ctx.results)}/{len(scenes)} scenes; partial results in "
              f"{run_dir} (rerun the same command to resume)", file=sys.stderr)
