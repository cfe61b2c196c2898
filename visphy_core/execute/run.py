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
"""
# size: one run's lifecycle (open, resume, schedule, close), in the order it happens

from __future__ import annotations

import datetime as dt
import errno
import logging
import os
import platform
import signal
import sys
import threading
import time
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any, Iterator

from omegaconf import DictConfig

from visphy_core.api.registry import get_plugin_manager, get_registry
from visphy_core.api.run_context import RunContext
from visphy_core.api.scene import Scene
from visphy_core.calls.generation import ModelCaller, get_service
from visphy_core.calls.judging import JudgeCaller
from visphy_core.calls.prompts.build import PromptSettings
from visphy_core.calls.references import ReferenceWriter
from visphy_core.calls.usage import CostCapReached, UsageLedger, call_cost_bound
from visphy_core.execute.console import print_summary, print_where_to_look, stage_progress
from visphy_core.execute.datasets import load_dataset
from visphy_core.execute.pipeline import PipelineSettings, SceneServices, first_call, process_scene
from visphy_core.execute.scheduler import (
    SceneScheduler,
    StageGates,
    pin_torch_threads,
    resolve_workers,
    work_order,
)
from visphy_core.infra.cache import Cache
from visphy_core.infra.errors import ConfigError, HostFault, describe_host_fault, host_fault
from visphy_core.infra.heap import release_free_memory
from visphy_core.infra.secrets import install_log_redaction
from visphy_core.results.row import SceneResult
from visphy_core.results.rows import jsonl_line
from visphy_core.results.run_dir import (
    COST_CAP,
    FAILED,
    FINISHED,
    INTERRUPTED,
    RUNNING,
    RunDir,
    RunLock,
    claim_run_dir,
    config_hash,
    find_resumable,
    new_run_dir,
)
from visphy_core.results.summary import HeadlineColumn, summarise
from visphy_core.scoring.ground_truth import open_store, store_path
from visphy_core.scoring.headline import Headline, summary_entry
from visphy_core.scoring.score import ScoringProtocol, score_columns, select_metrics

log = logging.getLogger("visphy.run")



class RunInterrupted(SystemExit):
    """SIGINT/SIGTERM during a run. A `SystemExit` (exit status 128 + signal number), so no
    ``except Exception`` in a scene's code swallows it and the CLI exits without a traceback."""

    def __init__(self, signum: int):
        super().__init__(128 + signum)
        self.signum = signum


@dataclass
class RunSetup:
    """How the run was set up, as its manifest and summary record it."""

    config_hash: str
    isolation: dict[str, Any]
    model: dict[str, Any]
    workers: dict[str, int]
    #: A resumed run: where the killed process's run was tracked (its manifest's ``tracking``).
    resumed_from: dict[str, dict[str, Any]]


def headline_column(headline: Headline | None) -> HeadlineColumn | None:
    """The run's headline as its summary reports it (`visphy_core.results.summary.summarise`)."""
    return HeadlineColumn(headline.name, partial(summary_entry, headline)) \
        if headline is not None else None


def _isolation(cfg: DictConfig) -> dict[str, Any]:
    """Configure the sandboxes from ``sandbox.*`` and record the isolation they provide.

    ``allow_unisolated=false`` leaves the choice to ``$VISPHY_ALLOW_UNISOLATED`` (either opt-out
    suffices); the probes run once per process.
    """
    from visphy_core.sandbox import browser, process

    allow = bool(cfg.sandbox.allow_unisolated)
    process.configure(allow_unisolated=True if allow else None)
    browser.configure(allow_unisolated=True if allow else None,
                      memory_mb=int(cfg.sandbox.browser_memory_mb))
    return {"allow_unisolated": allow or process.unisolated_allowed(),
            "process": process.isolation_level(), "browser": browser.browser_isolation_level()}


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


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("visphy")
    except PackageNotFoundError:
        return "source"


@contextmanager
def _signals_close_the_run() -> Iterator[None]:
    """SIGINT/SIGTERM raise `RunInterrupted` in the main thread (the scene in progress is
    abandoned: it is redone on resume); a second signal while the run closes exits at once."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    state: dict[str, int | None] = {"signum": None}

    def handler(signum, frame):
        if state["signum"] is None:
            state["signum"] = signum
            raise RunInterrupted(signum)
        os._exit(128 + signum)

    previous = {sig: signal.signal(sig, handler) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        state["signum"] = state["signum"] or -1  # closing: a further signal exits at once
        for sig, old in previous.items():
            signal.signal(sig, old)


@contextmanager
def _deferred_signals() -> Iterator[list[int]]:
    """Hold SIGINT/SIGTERM while the run's files are closed; re-delivered afterwards."""
    if threading.current_thread() is not threading.main_thread():
        yield []
        return
    pending: list[int] = []
    previous = {sig: signal.signal(sig, lambda s, f: pending.append(s))
                for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield pending
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


def build_judges(cfg: DictConfig, registry) -> list[tuple[str, Any]]:
    """The selected judges as (selection key, Judge) pairs (a run and re-scoring alike)."""
    judges = []
    for key, node in (cfg.get("judge") or {}).items():
        judges.append((str(key), registry.get("judges", str(node.name))(node)))
    return judges


def reference_model_of(cfg: DictConfig, registry):
    """The captioning model of ``reference.source=llm`` (a model config from conf/model/)."""
    if str(cfg.reference.source) != "llm":
        return None
    if not cfg.reference.model:
        raise ConfigError("reference.source=llm needs reference.model=<a model config name>, "
                          "e.g. reference.model=gemini25pro")
    from visphy_core.config.check import compose

    node = compose([f"model={cfg.reference.model}"]).model
    return registry.get("models", str(node.name))(node)


def _check_ready(cfg: DictConfig, model, judges, reference_model) -> None:
    """Before any work: keys present, and a cost cap only where every call has a price."""
    for thing in [model, *(j for _, j in judges), reference_model]:
        if thing is not None:
            thing.check_ready()
    cap = cfg.run.get("cost_cap_usd")
    if cap is None:
        return
    reference = ([(f"reference.model={cfg.reference.model}", reference_model.cfg)]
                 if reference_model is not None and reference_model.cfg is not None else [])
    for what, node in [(f"model={cfg.model.name}", cfg.model),
                       *((f"judge={k}", j.cfg) for k, j in judges), *reference]:
        price = node.get("price") if hasattr(node, "get") else None
        if price is not None and (price.get("input_usd_per_mtok") is None
                                  or price.get("output_usd_per_mtok") is None):
            raise ConfigError(f"run.cost_cap_usd={cap:g} needs prices for every call, but "
                              f"{what} has no price (set its price.input_usd_per_mtok and "
                              "price.output_usd_per_mtok)")


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


class _Prefetch:
    """Starts the first model call of the next ``window`` scenes while earlier ones render.

    A scene is prefetched only after its inputs check out (`_sendable`: a ``data_error`` scene
    is never sent to the model); the pipeline later asks for the same request and joins the call
    in flight. Called by the scheduler's workers as they take scenes (thread-safe).
    """

    def __init__(self, scenes: list[Scene], services: SceneServices, window: int):
        self.scenes = scenes
        self.services = services
        self.window = window
        self.next = 0
        self._taken = -1  # the scheduler takes scenes in order: all up to here are taken
        self._stopped = False
        self._lock = threading.Lock()

    def stop(self) -> None:
        """No call is submitted after this (the run is ending: a call sent now would be neither
        waited for nor cached, and the next run would pay for it again)."""
        with self._lock:
            self._stopped = True

    def advance(self, position: int) -> None:
        """Called as scene ``position`` is taken: prefetch the scenes after it. A scene already
        taken by a worker is never prefetched (its pipeline makes its own call): the check and
        the submission hold the lock its dispatch takes, so a slow look at one scene's inputs
        cannot send a second call after that scene's own call has finished."""
        settings = self.services.settings
        frames = settings.prompt.frames[:1] if settings.prompt.forecast_only \
            else settings.prompt.frames
        with self._lock:
            self._taken = max(self._taken, position)
        while True:
            with self._lock:  # the scenes after ``position``: its own call is its own
                if self._stopped:
                    return
                self.next = max(self.next, position + 1)
                if self.next >= min(len(self.scenes), position + 1 + self.window):
                    return
                index = self.next
                scene = self.scenes[index]
                self.next += 1
            try:
                if not _sendable(scene, tuple(frames) or (1,)):
                    continue
                request = first_call(scene, self.services).request
                with self._lock:
                    if index > self._taken and not self._stopped:
                        self.services.caller.submit(request)
            except Exception:  # noqa: BLE001 - the pipeline classifies this scene itself
                continue


def _sendable(scene: Scene, key_frames: tuple[int, ...]) -> bool:
    """Whether a scene's inputs look sound enough to send it to the model ahead of its turn:
    what `Scene.check_inputs` checks, with the ground-truth clip probed (frame count and size
    from its header) instead of decoded, so each clip is decoded once, by its scene."""
    import av

    if scene.load_error:
        return False
    try:
        scene.detection, scene.spec, scene.trajectory  # noqa: B018 - read (and kept) now
        with av.open(str(scene.video_path)) as container:
            stream = container.streams.video[0]
            n, width, height = int(stream.frames), stream.width, stream.height
    except Exception:  # noqa: BLE001 - check_inputs names the fault when the scene runs
        return False
    c = scene.clip
    return (n == c.n_frames and n >= max(key_frames) and (width, height) == (c.width, c.height))


def _wait_for_calls(caller: ModelCaller) -> None:
    """Let the model calls in flight finish: each reply is cached on arrival, so a resumed run
    never pays for it again. A (further) SIGINT/SIGTERM abandons them."""
    pending = caller.pending()
    if not pending:
        return
    print(f"waiting for {pending} model call(s) in flight (their replies are cached for the "
          "next run; interrupt again to abandon them)", file=sys.stderr)
    abandon = threading.Event()
    previous = {}
    if threading.current_thread() is threading.main_thread():
        previous = {sig: signal.signal(sig, lambda s, f: abandon.set())
                    for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        while caller.pending() and not abandon.is_set():
            caller.wait_pending(0.2)
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


def _close_calls(services: SceneServices) -> None:
    """Close the clients of the model, the reference writer and the judges."""
    for thing in (services.model, services.references.model if services.references else None):
        if thing is not None:
            try:
                get_service().run(thing.aclose())
            except Exception as exc:  # noqa: BLE001
                log.warning("closing %s failed: %s", thing.name, exc)
    if services.judges is not None:
        services.judges.close()


def _ground_truth_stage(cfg: DictConfig, services: SceneServices, scenes: list[Scene],
                        workers: int):
    """The run's ``ground truth`` stage, before any scene is scored: the anchors its scoring
    reads (every frame/sequence metric's floor and ceiling with normalisation on, else the
    headline components' floors) filled into the ground-truth store for ``scenes``
    (`visphy_core.execute.ground_truth.fill_store`), with its cost on one line. None when the
    run needs no anchor."""
    from visphy_core.execute.ground_truth import fill_store
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
