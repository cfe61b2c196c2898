"""Re-scoring a finished run: other metrics or judges on the clips it already made.

``python -m visphy_core score RUN_DIR [overrides]`` reads the run's rows, its clips
(``scenes/<id>/video.mp4``: the model's own or the fallback), the replies the analysis and S were
extracted from, and the reference-program clips it rendered (``spec_video.mp4`` for the spec
track, ``twin_video.mp4`` for normalisation), then scores every evaluable row again with the
same code a run uses (`visphy_core.scoring.scene_scores`). No model is called and nothing is
rendered:
a clip the run did not make leaves its columns unavailable, saying why. Scores and verdicts
come from the content-addressed cache when the same metric or judge has seen the same clips.

Results go to a new run directory ``<name>.rescored-<time>`` next to the original (scene
folders hard-linked, files rewritten atomically, so the original never changes), or with
``--in-place`` into the run itself after a backup of everything rewritten
(``rescore-backup-<time>/``). The manifest records ``rescored_from`` and what changed; the
tracking hooks open a new MLflow run tagged ``visphy.rescored_from``. An interrupted run is
re-scored over its finished rows only, and keeps its status (rerunning the new config resumes
the rest).
"""

from __future__ import annotations

import datetime as dt
import os
import shutil
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from omegaconf import DictConfig

from visphy_core.api.engine import FailureClass, Program, RenderContract
from visphy_core.api.extract import extract_analysis, extract_spec
from visphy_core.api.run_context import RunContext
from visphy_core.api.scene import Scene
from visphy_core.calls.generation import ModelCaller
from visphy_core.calls.judging import JudgeCaller
from visphy_core.calls.references import ReferenceWriter
from visphy_core.calls.usage import UsageLedger
from visphy_core.config.rescore import rescore_config
from visphy_core.execute.console import print_summary, print_where_to_look, stage_progress
from visphy_core.execute.pipeline import mark_not_evaluable
from visphy_core.infra import files
from visphy_core.infra.cache import Cache
from visphy_core.infra.errors import SceneDataError, UserError
from visphy_core.infra.video import decode_video, load_clip_for
from visphy_core.results import layout
from visphy_core.results.layout import CALLS, DERIVED_FILES, LOCK, SCORABLE_FILES
from visphy_core.results.row import SceneResult
from visphy_core.results.run_dir import (
    FINISHED,
    INTERRUPTED,
    RUNNING,
    RunDir,
    RunLock,
    config_hash,
    kept_attempt,
)
from visphy_core.results.summary import summarise
from visphy_core.scoring.ground_truth import open_store, store_path
from visphy_core.scoring.headline import Headline
from visphy_core.scoring.paper_protocol import frames_needed
from visphy_core.scoring.reference_clips import ReferenceClipUnavailable
from visphy_core.scoring.scene_scores import (
    ScoringServices,
    score_columns_of,
    score_outputs,
    write_scores,
)
from visphy_core.scoring.score import ScoringProtocol, score_columns, select_metrics


class RunDirClips:
    """`visphy_core.scoring.scene_scores.ReferenceClips` read back from a scene folder: re-scoring
    never renders, so a clip the run did not make is unavailable, with the run's own reason
    when it had one."""

    def __init__(self, before: SceneResult):
        self.before = before

    def spec_replay(self, scene: Scene, spec: dict, contract: RenderContract,
                    scene_dir: Path) -> np.ndarray:
        path = scene_dir / layout.SPEC_VIDEO
        if path.is_file():
            return decode_video(path)[0]
        if self.before.spec_track == "failed" and self.before.spec_track_error:
            raise ReferenceClipUnavailable(self.before.spec_track_error)
        raise ReferenceClipUnavailable(
            "re-scoring renders nothing and the run has no spec_video.mp4 for this scene (its "
            "spec track was off): start a new run with metrics.spec_track=true")

    def twin_identity(self, scene: Scene, contract: RenderContract) -> None:
        return None  # the run dir holds the twin's frames, not what made them

    def copy_twin(self, scene: Scene, contract: RenderContract, scene_dir: Path) -> bool:
        return (scene_dir / layout.TWIN_VIDEO).is_file()

    def twin(self, scene: Scene, contract: RenderContract, scene_dir: Path) -> np.ndarray:
        path = scene_dir / layout.TWIN_VIDEO
        if path.is_file():
            return decode_video(path)[0]
        for why in self.before.unavailable.values():
            if why.startswith("normalisation: "):
                raise ReferenceClipUnavailable(why)
        raise ReferenceClipUnavailable(
            "normalisation: re-scoring renders nothing and the run has no twin_video.mp4 for "
            "this scene: start a new run with metrics.variance_norm=true")


@dataclass
class Rescored:
    """What `rescore_run` made: the run directory written and its summary."""

    run_dir: Path
    summary: dict
    results: list[SceneResult]


# ------------------------------------------------------------------------------ reading a run


def check_run_dir(path: Path) -> Path:
    """``path`` resolved, or a `UserError` saying why it is not a run directory."""
    path = Path(path)
    if not path.exists():
        raise UserError(f"score: no run directory at {path}")
    missing = RunDir(path).missing(SCORABLE_FILES)
    if not path.is_dir() or missing:
        raise UserError(f"score: {path} is not a visphy run directory (missing "
                        f"{', '.join(missing) or 'everything'}); pass a folder under "
                        "<VISPHY_HOME>/runs/")
    files.refuse_tree(path, "run directory")
    return path.resolve()


def _data_dir(cfg: DictConfig) -> Path:
    """The run's data directory; where it was relative to another working directory, the
    current ``$VISPHY_HOME/data`` (the dataset plugin says what is missing, if anything)."""
    recorded = Path(str(cfg.paths.data_dir))
    here = Path(os.environ.get("VISPHY_HOME", "visphy-out")) / "data"
    return (here if not recorded.is_dir() and here.is_dir() else recorded).resolve()


def _final_reply(scene_dir: Path, attempts: int) -> tuple[str | None, dict | None]:
    """(analysis A, spec S) as the pipeline kept them: from the last reply that was not an
    error (`visphy_core.results.run_dir.kept_attempt`)."""
    attempt = kept_attempt(scene_dir, attempts)
    if attempt is None:
        return None, None
    reply = (scene_dir / layout.attempt_file(layout.RESPONSE, attempt, "txt")).read_text()
    return extract_analysis(reply), extract_spec(reply)


def _decoded_reply(scene_dir: Path, result: SceneResult, scene: Scene,
                   protocol: ScoringProtocol) -> np.ndarray | None:
    """A video model's own reply as decoded (by index), for the ``paper`` protocol: the same
    frames the run scored (`visphy_core.execute.pipeline`), read from ``reply*.mp4``."""
    if not (protocol.paper and result.model_success and result.output_kind == "video"):
        return None
    path = scene_dir / layout.attempt_file(layout.REPLY, result.attempts, "mp4")
    if not path.is_file():
        return None
    keep: list = []
    load_clip_for(path, scene.clip, keep_decoded=keep,
                  keep_max=frames_needed(scene.clip.n_frames, protocol.paper_params.sample_every,
                                         protocol.paper_params.max_offset))
    return np.stack(keep) if keep else None


def _program(scene_dir: Path, result: SceneResult) -> Program | None:
    """The program whose clip the row reports (the model's own, first or repaired)."""
    if not result.model_success or result.output_kind != "program":
        return None
    for ext, language in (("html", "html"), ("py", "python")):
        path = scene_dir / layout.attempt_file(layout.PROGRAM, result.attempts, ext)
        if path.is_file():
            return Program(language=language, source=path.read_text())
    return None


# ------------------------------------------------------------------------------ one row


def rescore_row(before: SceneResult, scene: Scene, scene_dir: Path, services: ScoringServices,
                cfg: DictConfig, columns: list[str]) -> SceneResult:
    """The row scored again under ``services``; everything but its scores, verdicts, spec
    track and reference description is kept. Rows the run could not evaluate stay as they
    were (with the new, empty, columns)."""
    result = replace(before, scores=dict.fromkeys(columns), unavailable={}, judge_errors={},
                     flags=list(before.flags), spec_problems=list(before.spec_problems),
                     frame_digests=list(before.frame_digests))
    if not before.evaluable:
        return result
    for name in layout.SCORE_FILES:
        (scene_dir / name).unlink(missing_ok=True)
    result.spec_track = result.spec_track_error = result.reference_source = None
    frames = cfg.prompt.frames[:1] if cfg.prompt.forecast_only else cfg.prompt.frames
    contract = RenderContract.for_scene(scene, timeout_s=float(cfg.engine.timeout_s),
                                        seed=int(cfg.run.seed))
    scoring = replace(services, clips=RunDirClips(before))
    try:
        reference = scene.check_inputs(tuple(frames) or (1,))
        analysis, spec = _final_reply(scene_dir, before.attempts)
        generated = None
        if before.system_success:
            video = scene_dir / layout.VIDEO
            if not video.is_file():
                raise UserError(f"score: {video} is missing although the row has a clip; the "
                                "run directory is damaged")
            generated = decode_video(video)[0]
        score_outputs(scene, reference, generated, analysis, spec, scoring, scene_dir, result,
                      contract, _program(scene_dir, before),
                      spec_track=before.output_kind == "program",
                      as_decoded=_decoded_reply(scene_dir, before, scene, services.protocol))
    except UserError:
        raise
    except SceneDataError as exc:
        mark_not_evaluable(result, FailureClass.DATA_ERROR, str(exc))
    except Exception as exc:  # noqa: BLE001 - one scene's fault never aborts the re-scoring
        mark_not_evaluable(result, FailureClass.INFRA_ERROR, f"{type(exc).__name__}: {exc}")
    write_scores(scene_dir, result)
    return result


# ------------------------------------------------------------------------------ the run


def _link_tree(src: Path, dst: Path) -> None:
    """``dst`` mirrors ``src`` with hard links (copies across file systems)."""
    for path in sorted(src.rglob("*")):
        target = dst / path.relative_to(src)
        if path.is_dir():
            target.mkdir(parents=True, exist_ok=True)
            continue
        target.parent.mkdir(parents=True, exist_ok=True)
        try:
            os.link(path, target)
        except OSError:
            shutil.copy2(path, target)


def _stamp() -> str:
    return dt.datetime.now().strftime("%Y-%m-%d_%H-%M-%S")


def _new_copy(src: Path) -> Path:
    """``<name>.rescored-<time>`` beside ``src``: its scene folders hard-linked, its other
    files copied (``calls.jsonl`` grows with the new judge calls, so it is never linked)."""
    base = src.name.split(".rescored-")[0]
    out = src.parent / f"{base}.rescored-{_stamp()}"
    n = 1
    while out.exists():
        n += 1
        out = src.parent / f"{base}.rescored-{_stamp()}.{n}"
    out.mkdir(parents=True)
    for path in src.iterdir():
        if path.is_file() and path.name not in DERIVED_FILES and path.name != LOCK:
            shutil.copy2(path, out / path.name)
    if RunDir(src).scenes.is_dir():
        _link_tree(RunDir(src).scenes, RunDir(out).scenes)
    return out


def _backup(run_dir: Path) -> Path:
    """Everything an in-place re-scoring rewrites, under ``rescore-backup-<time>/``."""
    backup = run_dir / f"rescore-backup-{_stamp()}"
    backup.mkdir()
    for path in RunDir(run_dir).present((*DERIVED_FILES, CALLS)):
        shutil.copy2(path, backup / path.name)
    for path in sorted(RunDir(run_dir).scenes.glob("*/*")):
        if path.name in layout.SCORE_FILES:
            target = RunDir(backup).scene_dir(path.parent.name) / path.name
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(path, target)
    return backup


def _restore(backup: Path, run_dir: Path) -> None:
    """Undo an in-place re-scoring that did not finish."""
    for path in sorted(backup.rglob("*")):
        if path.is_file():
            target = run_dir / path.relative_to(backup)
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(path, target)


def rescore_run(run_dir: Path, overrides: list[str], in_place: bool = False) -> Rescored:
    """Score a finished (or interrupted) run again under ``overrides``; see the module
    docstring. Raises `UserError` (one line) for a bad run directory or override."""
    from visphy_core.api.registry import get_registry
    from visphy_core.execute.run_setup import build_judges, reference_model_of

    src = check_run_dir(run_dir)
    run_cfg = RunDir(src).read_config()
    registry = get_registry()
    cfg, changed = rescore_config(run_cfg, overrides)
    judges = build_judges(cfg, registry)
    reference_model = reference_model_of(cfg, registry)
    for thing in [*(j for _, j in judges), reference_model]:
        if thing is not None:
            thing.check_ready()
    lock = RunLock(src)
    if not lock.acquire():
        raise UserError(f"score: {src} is in use by a live visphy process; re-score it once "
                        "that run has finished or been interrupted")
    try:
        out = src if in_place else _new_copy(src)
        backup = _backup(src) if in_place else None
        try:
            return _rescore_into(src, out, cfg, run_cfg, changed, overrides, judges,
                                 reference_model, backup)
        except BaseException:
            if backup is not None:
                _restore(backup, out)
            elif out != src:
                shutil.rmtree(out, ignore_errors=True)
            raise
    finally:
        lock.release()


def _rescore_into(src: Path, out: Path, cfg: DictConfig, run_cfg: DictConfig, changed: dict,
                  overrides: list[str], judges, reference_model, backup: Path | None
                  ) -> Rescored:
    from visphy_core.api.registry import get_registry
    from visphy_core.execute.datasets import load_dataset

    registry = get_registry()
    cache = Cache(Path(str(cfg.paths.cache_dir)).resolve(), enabled=bool(cfg.run.cache))
    ledger = UsageLedger(RunDir(out).calls_file)
    scenes = load_dataset(cfg.dataset, _data_dir(cfg), progress=bool(cfg.run.progress))
    by_id = {s.scene_id: s for s in scenes}
    before = [r for r in RunDir(src).read_rows()[0] if r.scene_id in by_id]
    order = {s.scene_id: i for i, s in enumerate(scenes)}
    before.sort(key=lambda r: order[r.scene_id])
    metrics = select_metrics(registry, cfg.metrics)
    services = ScoringServices(
        metrics=metrics, cache=cache,
        protocol=ScoringProtocol.from_cfg(cfg.metrics), clips=None,  # per row: RunDirClips
        headline=Headline.for_run(cfg.metrics, metrics),
        ground_truth=open_store(store_path(cfg, _data_dir(cfg)), enabled=bool(cfg.run.cache)),
        judges=JudgeCaller(judges, cache, ledger) if judges else None,
        references=ReferenceWriter(cfg.reference, cache, reference_model,
                                   ModelCaller(reference_model, cache, ledger)
                                   if reference_model is not None else None))
    columns = score_columns_of(services)
    stages = ["score"] + (["judge"] if judges else [])
    calls_before = {k: t["calls"] for k, t in ledger.totals().items()}
    results = []
    try:
        with stage_progress(len(before), stages, enabled=bool(cfg.run.progress)) as progress:
            services.progress = progress
            for row in before:
                results.append(rescore_row(row, by_id[row.scene_id],
                                           RunDir(out).scene_dir(row.scene_id), services, cfg,
                                           columns))
                progress.scene_finished(row.scene_id)
    finally:
        if services.judges is not None:
            services.judges.close()
    made = {k: t["calls"] - calls_before.get(k, 0) for k, t in ledger.totals().items()
            if k != "all" and t["calls"] > calls_before.get(k, 0)}
    return _write_run(src, out, cfg, run_cfg, changed, overrides, scenes, results, services,
                      ledger, backup, [k for k, _ in judges], made)


def _write_run(src: Path, out: Path, cfg: DictConfig, run_cfg: DictConfig, changed: dict,
               overrides: list[str], scenes: list[Scene], results: list[SceneResult],
               services: ScoringServices, ledger: UsageLedger, backup: Path | None,
               judge_keys: list[str], made: dict[str, int]) -> Rescored:

    from visphy_core.api.registry import get_plugin_manager
    from visphy_core.execute.run_record import write_report
    from visphy_core.execute.run_setup import headline_column

    source, run = RunDir(src), RunDir(out)
    manifest = source.read_manifest()
    old_summary = source.read_summary() if source.summary_file.is_file() else {}
    status = manifest.get("status") or FINISHED
    status = INTERRUPTED if status == RUNNING else status  # killed: no process holds it
    chash = config_hash(cfg)
    previous_mlflow = ((manifest.get("tracking") or {}).get("mlflow") or {}).get("run_id")
    rescored_from = {"run_dir": str(src), "mlflow_run_id": previous_mlflow,
                     "at": dt.datetime.now().isoformat(timespec="seconds")}
    run.write_config(cfg)  # no credentials in URLs
    run.write_rows(results)
    summary = summarise(results, services.metrics,
                        score_columns(services.metrics, services.protocol),
                        cache_stats=services.cache.stats(), judges=judge_keys,
                        usage=ledger.totals(), headline=headline_column(services.headline))
    summary.update({
        "status": status, "run_dir": str(out), "model": run_cfg.model.name,
        "engine": run_cfg.engine.name, "dataset": run_cfg.dataset.name,
        "n_selected": len(scenes), "config_hash": chash,
        "isolation_levels": old_summary.get("isolation_levels", manifest.get("isolation")),
        "rescored_from": str(src), "rescored_rows": len(results),
        "rescore_calls": made})
    for key in ("cost_cap", "interrupted_by", "resumed_rows"):
        if key in old_summary:
            summary[key] = old_summary[key]
    manifest.update({
        "status": status, "config_hash": chash, "rescored_from": rescored_from,
        "rescore": {"overrides": list(overrides), "changed": changed, "rows": len(results),
                    "in_place": out == src, "backup": str(backup) if backup else None},
        "metrics": [m.describe() for m in services.metrics], "judges": judge_keys})
    manifest.pop("tracking", None)
    run.write_summary(summary)
    run.write_manifest(manifest)
    ctx = RunContext(cfg=cfg, run_dir=out, root=Path(str(cfg.paths.root)).resolve(),
                     scenes=scenes, model_name=str(run_cfg.model.name),
                     engine_name=str(run_cfg.engine.name), metrics=services.metrics,
                     cache=services.cache, judges=judge_keys, config_hash=chash,
                     rescored_from=rescored_from)
    pm = get_plugin_manager()
    pm.hook.visphy_run_start(run=ctx)
    if ctx.tracking:
        manifest["tracking"] = dict(ctx.tracking)
        run.write_manifest(manifest)
    by_id = {s.scene_id: s for s in scenes}
    for result in results:
        ctx.results.append(result)
        pm.hook.visphy_scene_done(run=ctx, scene=by_id[result.scene_id], result=result)
    pm.hook.visphy_run_end(run=ctx, summary=summary)
    run.write_summary(summary)
    print_summary(summary, results, calls_heading=(
        f"calls recorded in {out.name} (the original run's included; the calls made by this "
        "re-score are counted below):"))
    calls = ", ".join(f"{n} {stage}" for stage, n in made.items()) or "none"
    note = f"re-scored {len(results)} row(s) of {src} · calls made now: {calls}"
    if status != FINISHED:
        note += f" (the run was {status}: its finished rows only)"
    print(note + ("; backup of what changed in " + str(backup) if backup else ""))
    print_where_to_look(write_report(out), ctx.where_to_look)
    return Rescored(run_dir=out, summary=summary, results=results)
