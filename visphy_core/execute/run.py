"""One run: a dataset split × model × engine × prompt mode × metric set, end to end.

Scenes go through the stages side by side (`visphy_core.execute.scheduler`: ``run.workers`` of them
render or score at once, more wait on their replies or verdicts) and come back in scene order.
The run directory is written as the run goes (``results.jsonl`` grows one row per scene, in
scene order, flushed and fsynced), so a crash loses at most the scenes in flight. Rerunning the
same command resumes the newest unfinished run directory with the same config hash: its
finished rows are kept (a truncated last line is dropped), only the remaining scenes are
processed, and the cache answers every model call already made. SIGINT/SIGTERM close the run
(the scenes in flight are abandoned): results and a partial summary (``"status":
"interrupted"``) are written, tracking is marked KILLED, and the process exits with 128 + the
signal number (130 / 143).

This module holds the run's lifecycle in the order it happens; its pieces are built in
`visphy_core.execute.run_setup`, its model calls prefetched and closed in
`visphy_core.execute.prefetch`, its signals handled in `visphy_core.execute.run_signals`, and
its manifest, summary and closing lines written by `visphy_core.execute.run_record`.
"""

from __future__ import annotations

import datetime as dt
import logging
import os
import sys
import time
from contextlib import nullcontext
from pathlib import Path
from typing import Any

from omegaconf import DictConfig

from visphy_core.api.registry import get_plugin_manager, get_registry
from visphy_core.api.run_context import RunContext
from visphy_core.api.scene import Scene
from visphy_core.calls.generation import ModelCaller
from visphy_core.calls.judging import JudgeCaller
from visphy_core.calls.prompts.build import PromptSettings
from visphy_core.calls.references import ReferenceWriter
from visphy_core.calls.usage import CostCapReached, UsageLedger, call_cost_bound
from visphy_core.execute.console import stage_progress
from visphy_core.execute.datasets import load_dataset
from visphy_core.execute.pipeline import PipelineSettings, SceneServices, process_scene
from visphy_core.execute.prefetch import _close_calls, _Prefetch, _wait_for_calls
from visphy_core.execute.run_record import (
    _ClosingWrites,
    _host_fault_line,
    _open_run,
    _print_end,
    _run_summary,
)
from visphy_core.execute.run_setup import (
    RunSetup,
    _check_ready,
    _isolation,
    build_judges,
    reference_model_of,
)
from visphy_core.execute.run_signals import (
    RunInterrupted,
    _deferred_signals,
    _signals_close_the_run,
)
from visphy_core.execute.scheduler import (
    SceneScheduler,
    StageGates,
    pin_torch_threads,
    resolve_workers,
    work_order,
)
from visphy_core.infra.cache import Cache
from visphy_core.infra.errors import HostFault, host_fault
from visphy_core.infra.heap import release_free_memory
from visphy_core.infra.secrets import install_log_redaction
from visphy_core.results.row import SceneResult
from visphy_core.results.rows import jsonl_line
from visphy_core.results.run_dir import (
    COST_CAP,
    FAILED,
    FINISHED,
    INTERRUPTED,
    RunDir,
    RunLock,
    claim_run_dir,
    config_hash,
    find_resumable,
    new_run_dir,
)
from visphy_core.scoring.ground_truth import open_store, store_path
from visphy_core.scoring.headline import Headline
from visphy_core.scoring.score import ScoringProtocol, select_metrics

log = logging.getLogger("visphy.run")


def run_stages(services: SceneServices) -> list[str]:
    """The stages a scene of this run goes through (progress lines): no render for a model
    that returns videos, no judge stage without judges."""
    stages = ["generate"]
    if services.model.output_kind == "program":
        stages.append("render")
    stages.append("score")
    if services.judges is not None:
        stages.append("judge")
    return stages


def run_experiment(cfg: DictConfig) -> dict:
    """Evaluate every selected scene; returns the summary (also in ``summary.json``).

    Resumes the newest unfinished run of the same config (see the module docstring). Raises
    `RunInterrupted` (exit status 130/143) after closing the run on SIGINT/SIGTERM.
    """
    install_log_redaction()  # also in a launcher's job process (joblib, submitit, Ray)
    workers = resolve_workers(cfg.run.get("workers", "auto"))  # a bad value: before any work
    torch_threads = pin_torch_threads()
    registry = get_registry()
    pm = get_plugin_manager()
    model = registry.get("models", cfg.model.name)(cfg.model)
    judges = build_judges(cfg, registry)
    reference_model = reference_model_of(cfg, registry)
    _check_ready(cfg, model, judges, reference_model)  # a missing key: one line, no work done
    root = Path(cfg.paths.root).resolve()
    data_dir, runs_dir = Path(cfg.paths.data_dir).resolve(), Path(cfg.paths.runs_dir).resolve()
    cache = Cache(Path(cfg.paths.cache_dir).resolve(), enabled=bool(cfg.run.cache))
    scenes = load_dataset(cfg.dataset, data_dir, progress=bool(cfg.run.progress))
    isolation = _isolation(cfg)
    engine = registry.get("engines", cfg.engine.name)(cfg.engine)
    metrics = select_metrics(registry, cfg.metrics)
    chash = config_hash(cfg)
    resume = str(cfg.run.get("resume") or "auto")
    found = (None if resume == "never" else find_resumable(runs_dir, chash)
             if resume == "auto" else claim_run_dir(Path(resume), chash))
    setup = RunSetup(config_hash=chash, isolation=isolation, model=model.describe(),
                     workers={"workers": workers, "torch_threads": torch_threads},
                     resumed_from={})
    if found is not None:
        run_dir, lock = found
        restored = RunDir(run_dir).restore_rows([s.scene_id for s in scenes])
        # tracking plugins close the killed process's run (left RUNNING by SIGKILL)
        setup.resumed_from = RunDir(run_dir).tracking()
        print(f"resuming {run_dir} ({len(restored)}/{len(scenes)} scenes already done)",
              file=sys.stderr)
    else:
        run_dir = new_run_dir(cfg, runs_dir)
        lock = RunLock(run_dir)
        lock.acquire()
        restored = []
    ledger = UsageLedger(RunDir(run_dir).calls_file, cap_usd=cfg.run.get("cost_cap_usd"),
                         first_call_usd=call_cost_bound(cfg.model))
    settings = PipelineSettings(prompt=PromptSettings.from_cfg(cfg.prompt), retry=cfg.run.retry,
                                fallback=cfg.run.fallback, timeout_s=cfg.engine.timeout_s,
                                seed=cfg.run.seed)
    caller = ModelCaller(model, cache, ledger)
    services = SceneServices(
        model=model, caller=caller, engine=engine, metrics=metrics, settings=settings,
        protocol=ScoringProtocol.from_cfg(cfg.metrics),
        headline=Headline.for_run(cfg.metrics, metrics),
        ground_truth=open_store(store_path(cfg, data_dir), enabled=bool(cfg.run.cache)),
        cache=cache, judges=JudgeCaller(judges, cache, ledger) if judges else None,
        references=ReferenceWriter(cfg.reference, cache, reference_model,
                                   ModelCaller(reference_model, cache, ledger)
                                   if reference_model is not None else None))
    try:
        return _run(cfg, pm, root, cache, scenes, services, run_dir, restored, setup, ledger)
    finally:
        lock.release()


def _ground_truth_stage(cfg: DictConfig, services: SceneServices, scenes: list[Scene],
                        workers: int):
    """The run's ``ground truth`` stage, before any scene is scored: the anchors its scoring
    reads (every frame/sequence metric's floor and ceiling with normalisation on, else the
    headline components' floors) filled into the ground-truth store for ``scenes``
    (`visphy_core.execute.prepare_truth.fill_store`), with its cost on one line. None when the
    run needs no anchor."""
    from visphy_core.execute.prepare_truth import fill_store
    from visphy_core.scoring.ground_truth import writable

    norm = services.protocol.variance_norm
    metrics = (services.metrics if norm else
               services.headline.metrics_of(services.metrics) if services.headline else [])
    if not scenes or not metrics or not (writable(services.ground_truth)
                                         or services.cache.enabled):
        return None  # run.cache=false: nothing would keep the anchors for the scenes to read
    progress = bool(cfg.run.progress)
    filled = fill_store(scenes, services.engine, metrics, services.cache, services.ground_truth,
                        ceiling=norm, timeout_s=float(cfg.engine.timeout_s),
                        seed=int(cfg.run.seed), workers=workers, progress=progress)
    if progress:
        print(filled.line(), file=sys.stderr, flush=True)
    return filled


def _write_row(rows, result: SceneResult, ctx: RunContext) -> None:
    """Append the scene's row to results.jsonl (flushed, fsynced) and to the run's results.
    The row on disk and the row in memory go together: a signal between them would leave a
    summary that misses a row results.jsonl holds."""
    line = jsonl_line(result)
    with _deferred_signals() as held:
        try:
            rows.write(line)
            rows.flush()
            os.fsync(rows.fileno())
        except OSError as exc:  # what a "disk full" line names (infra/errors.py)
            exc.visphy_path, exc.visphy_needed = rows.name, len(line.encode())
            raise
        ctx.results.append(result)
    if held:
        raise RunInterrupted(held[0])


#: Seconds the run waits for a render in flight before closing the engine under it.
CLOSE_WAIT_S = 10.0


def _close_engine(engine, cfg: DictConfig, gates: StageGates | None) -> None:
    """Close the engine once no scene renders: the run holds the render lane while closing
    (the scenes were cancelled, so none starts a render after); a render that does not end in
    `CLOSE_WAIT_S` is closed under (it fails, and its scene is abandoned anyway)."""
    lane = gates.render_lane(CLOSE_WAIT_S) if gates is not None else nullcontext(True)
    with lane:
        try:
            engine.close()
        except Exception as exc:  # noqa: BLE001
            log.warning("closing engine %s failed: %s: %s", cfg.engine.name,
                        type(exc).__name__, exc)


#: Seconds the run waits for its abandoned scenes' threads to reach their next stage.
STOP_WAIT_S = 60.0


def _let_scenes_stop(scheduler: SceneScheduler) -> None:
    """Wait for the worker threads of abandoned scenes (cancelled: each stops at its next stage
    entrance, within the metric or render it is in): the run's files are final only once no
    scene writes, and a process that exits under a thread inside torch aborts."""
    if scheduler.join(1.0):
        print(f"waiting for {scheduler.join(0)} scene(s) in flight to stop", file=sys.stderr)
        left = scheduler.join(STOP_WAIT_S)
        if left:
            log.warning("%d scene thread(s) still running after %.0f s", left, STOP_WAIT_S)


def _close_services(services: SceneServices, engine, cfg: DictConfig,
                    gates: StageGates | None, scheduler: SceneScheduler | None) -> None:
    """Close model calls and the engine, and let the scenes still in flight stop."""
    try:
        _close_calls(services)
    except Exception as exc:  # noqa: BLE001
        log.warning("closing model calls failed: %s: %s", type(exc).__name__, exc)
    _close_engine(engine, cfg, gates)
    if scheduler is not None:
        _let_scenes_stop(scheduler)


def _run(cfg: DictConfig, pm, root: Path, cache: Cache, scenes: list[Scene],
         services: SceneServices, run_dir: Path, restored: list[SceneResult], setup: RunSetup,
         ledger: UsageLedger) -> dict:
    started = time.monotonic()  # the summary's wall time

    metrics, engine = services.metrics, services.engine
    judge_keys = [k for k, _ in services.judges.judges] if services.judges else []
    files = RunDir(run_dir)
    ctx, manifest = _open_run(cfg, root, cache, scenes, metrics, judge_keys, files, run_dir,
                              restored, setup)
    done = {r.scene_id for r in restored}
    pending = work_order([s for s in scenes if s.scene_id not in done])
    prefetch = _Prefetch(pending, services, int(cfg.run.get("prefetch", 0)))
    status, raised, cost_stop = FINISHED, None, None
    ground_truth: dict[str, Any] | None = None
    gates: StageGates | None = None
    scheduler: SceneScheduler | None = None
    try:
        with _signals_close_the_run():
            pm.hook.visphy_run_start(run=ctx)
            if ctx.tracking:  # so a resumed run can close this one if it is killed
                manifest["tracking"] = dict(ctx.tracking)
                files.write_manifest(manifest)
            filled = _ground_truth_stage(cfg, services, pending, setup.workers["workers"])
            if filled is not None:
                ground_truth = filled.as_dict()
            with stage_progress(len(pending), run_stages(services),
                                enabled=bool(cfg.run.progress)) as progress, \
                    files.open_rows() as rows:
                gates = StageGates(progress, setup.workers["workers"],
                                   serial_calls=prefetch.window == 0)
                services.progress = gates

                def process(scene: Scene) -> SceneResult:
                    result = process_scene(scene, services, files.scene_dir(scene.scene_id))
                    progress.scene_finished(scene.scene_id)
                    release_free_memory()  # the scene's clips and buffers, back to the system
                    return result

                scheduler = SceneScheduler(pending, key=lambda s: s.scene_id, process=process,
                                           gates=gates, on_dispatch=prefetch.advance)
                try:
                    for scene, result in scheduler.results():
                        if isinstance(result, CostCapReached):
                            # no new scene; those in flight finish (or meet the cap too)
                            cost_stop = cost_stop or result
                            scheduler.drain()
                            continue
                        if isinstance(result, BaseException):
                            raise result
                        _write_row(rows, result, ctx)
                        pm.hook.visphy_scene_done(run=ctx, scene=scene, result=result)
                finally:
                    prefetch.stop()     # before the wait for calls in flight: none starts later
                    scheduler.cancel()  # the scenes still in flight are abandoned
            if cost_stop is not None:
                status = COST_CAP
    except RunInterrupted as exc:
        status, raised = INTERRUPTED, exc
    except Exception as exc:  # noqa: BLE001 - close the run, then re-raise
        status, raised = FAILED, exc
    if status != FAILED:
        _wait_for_calls(services.caller)
    with _deferred_signals() as pending_signals:
        _close_services(services, engine, cfg, gates, scheduler)
        order = {s.scene_id: i for i, s in enumerate(scenes)}
        ctx.results.sort(key=lambda r: order.get(r.scene_id, len(order)))
        faults: list[OSError] = [f for f in [host_fault(raised)] if f is not None]
        closing = _ClosingWrites(faults)
        closing.do(files.write_rows, ctx.results, jsonl=False)  # lines written as it went
        summary = _run_summary(ctx, cfg, services, setup, ledger, cache, len(restored), status,
                               raised, cost_stop, ground_truth)
        closing.do(files.write_summary, summary)
        if faults and status == FINISHED:  # the run's files are not all written: not finished
            status = summary["status"] = FAILED
        manifest.update(status=status, ended=dt.datetime.now().isoformat(timespec="seconds"))
        closing.do(files.write_manifest, manifest)
        try:
            pm.hook.visphy_run_end(run=ctx, summary=summary)
        except Exception as exc:  # noqa: BLE001
            if raised is None and not faults:
                raise
            log.warning("visphy_run_end failed while closing a %s run: %s", status, exc)
        closing.do(files.write_summary, summary)
    if faults:
        raise HostFault(_host_fault_line(faults[0], run_dir, ctx.results, scenes)) \
            from (raised if raised is not None else faults[0])
    _print_end(summary, ctx, cfg, status, started)
    if raised is not None:
        raise raised
    if pending_signals:
        raise RunInterrupted(pending_signals[0])
    return summary
