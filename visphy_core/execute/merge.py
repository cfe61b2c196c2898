"""Merging the shards of one large run into one run (``python -m visphy_core merge``).

A run split with ``dataset.shard=0/n … n-1/n`` (`visphy_core.infra.shard`) leaves n run
directories, each with the rows of its own scenes. `merge_runs` checks that they are shards of
one config (their configs hash alike once ``dataset.shard`` is left out: model, engine, prompt,
metrics, judges, dataset, seed — only where things were written may differ), that each
finished, that no scene is in two of them and that all n are there (``partial`` merges a subset
on purpose), and writes one run directory as the unsharded run would have: ``config.yaml``
(``dataset.shard: null``), ``results.jsonl`` / ``results.parquet`` in the unsharded scene order,
``calls.jsonl``, ``scenes/<id>/`` (hard links to the shards' files, copies across file
systems), a ``manifest.json`` that records ``merged_from``, and a ``summary.json`` computed
afresh from all rows by `visphy_core.results.summary.summarise` (so the means are over every
scene, never means of shard means).

The merged run goes through the lifecycle hooks like any run, with ``merged_from`` on its
context (each shard's run directory, config hash and MLflow run): the tracking plugin
(`visphy_core.tracking.shards`) makes each shard's MLflow run in the same store a child of the
merged one (``mlflow.parentRunId``), and when the shards were the jobs of one study, the merged
run takes their place as the study's child.
"""

from __future__ import annotations

import datetime as dt
import logging
import os
import shutil
import sys
from dataclasses import dataclass, field
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from visphy_core.api.run_context import RunContext
from visphy_core.infra import files
from visphy_core.infra.errors import UserError
from visphy_core.infra.shard import interleave, parse_shard
from visphy_core.results.layout import FINISHED_FILES
from visphy_core.results.load import flatten
from visphy_core.results.row import SceneResult
from visphy_core.results.run_dir import FINISHED, RunDir, config_hash
from visphy_core.results.summary import summarise
from visphy_core.scoring.headline import Headline

log = logging.getLogger("visphy.merge")


@dataclass
class Shard:
    """One shard's run directory, read."""

    run_dir: Path
    config: DictConfig
    manifest: dict
    summary: dict
    rows: dict[str, dict]           # scene id -> its row, as written
    index: tuple[int, int] | None   # (i, n) of dataset.shard

    @property
    def label(self) -> str:
        return f"{self.run_dir} (shard {self.index[0]}/{self.index[1]})" if self.index \
            else str(self.run_dir)

    @property
    def scene_order(self) -> list[str]:
        listed = [s for s in self.manifest.get("scenes") or [] if s in self.rows]
        return listed + [s for s in self.rows if s not in set(listed)]

    @property
    def mlflow(self) -> dict:
        return (self.summary.get("mlflow") or ((self.manifest.get("tracking") or {})
                                               .get("mlflow")) or {})


@dataclass
class Merged:
    run_dir: Path
    summary: dict
    results: list[SceneResult]
    linked: list[str]               # the shards' MLflow runs made children of the merged one
    where_to_look: list[str] = field(default_factory=list)  # RunContext.where_to_look


def read_shard(run_dir: Path) -> Shard:
    """A finished run directory's config, manifest, summary and rows (`UserError` otherwise)."""
    run_dir = Path(run_dir).resolve()
    run = RunDir(run_dir)
    missing = run.missing(FINISHED_FILES)
    if missing:
        raise UserError(f"merge: {run_dir} is not a finished visphy run directory (no "
                        f"{', '.join(missing)})")
    files.refuse_tree(run_dir, "run directory")
    manifest = run.read_manifest()
    summary = run.read_summary()
    status = summary.get("status") or manifest.get("status")
    if status != FINISHED:
        raise UserError(f"merge: {run_dir} is {status or 'unfinished'}: rerun its command to "
                        "finish it (it resumes where it stopped), then merge")
    config = run.read_config()
    results, skipped = run.read_rows()
    if skipped:
        raise UserError(f"merge: {run.rows_file}: {skipped} line(s) are not rows")
    rows = {r.scene_id: r.row() for r in results}
    index = parse_shard(OmegaConf.select(config, "dataset.shard", default=None))
    return Shard(run_dir, config, manifest, summary, rows, index)


def _unsharded(config: DictConfig) -> DictConfig:
    out = OmegaConf.create(OmegaConf.to_container(config, resolve=True))
    out.dataset.shard = None
    return out


def _differences(a: DictConfig, b: DictConfig, limit: int = 4) -> str:
    fa = flatten(OmegaConf.to_container(a, resolve=True))
    fb = flatten(OmegaConf.to_container(b, resolve=True))
    keys = sorted(k for k in set(fa) | set(fb)
                  if not k.startswith("paths.") and k != "dataset.shard"
                  and fa.get(k) != fb.get(k))
    shown = [f"{k}: {fa.get(k)} ≠ {fb.get(k)}" for k in keys[:limit]]
    return "; ".join(shown) + (f"; … {len(keys) - limit} more" if len(keys) > limit else "")


def check_shards(shards: list[Shard], partial: bool = False) -> list[Shard]:
    """The shards in shard order, after every check that makes them one run; `UserError`
    naming the run directories involved otherwise."""
    if not shards:
        raise UserError("merge: name the shards' run directories")
    first = shards[0]
    want = config_hash(_unsharded(first.config))
    for shard in shards:
        if shard.index is None:
            raise UserError(f"merge: {shard.run_dir} is not a shard (its dataset.shard is not "
                            "set): merge the runs of dataset.shard=0/n … n-1/n")
        if config_hash(_unsharded(shard.config)) != want:
            raise UserError(f"merge: {first.run_dir} and {shard.run_dir} are runs of different "
                            f"configs ({_differences(first.config, shard.config)}); only "
                            "dataset.shard may differ")
    counts = {s.index[1] for s in shards}
    if len(counts) > 1:
        raise UserError(f"merge: the shards split the run in different numbers of parts "
                        f"({', '.join(s.label for s in shards)})")
    count = counts.pop()
    seen: dict[int, Shard] = {}
    for shard in sorted(shards, key=lambda s: s.index[0]):
        if shard.index[0] in seen:
            raise UserError(f"merge: shard {shard.index[0]}/{count} is given twice: "
                            f"{seen[shard.index[0]].run_dir} and {shard.run_dir}")
        seen[shard.index[0]] = shard
    owner: dict[str, Path] = {}
    for shard in seen.values():
        for scene_id in shard.rows:
            if scene_id in owner:
                raise UserError(f"merge: scene {scene_id} is in {owner[scene_id]} and in "
                                f"{shard.run_dir}: a scene may be in one shard only")
            owner[scene_id] = shard.run_dir
    absent = [f"{i}/{count}" for i in range(count) if i not in seen]
    if absent and not partial:
        raise UserError(f"merge: shard(s) {', '.join(absent)} missing: name all {count} shards' "
                        "run directories (or --partial to merge these only)")
    return [seen[i] for i in sorted(seen)]


def study_groups(sweep_dir: Path) -> list[list[Path]]:
    """The run directories of a study's completed jobs that are shards, one list per run they
    are shards of (their config without ``dataset.shard``), in job order."""
    from visphy_core.results.layout import CONFIG, JOB_FILE
    from visphy_core.results.study_records import COMPLETED, read_jobs

    jobs = read_jobs(Path(sweep_dir))
    if not jobs:
        raise UserError(f"merge: {sweep_dir} holds no study jobs ({JOB_FILE}): name the "
                        "sweep folder a multirun printed ('study …: FOLDER')")
    groups: dict[str, list[Path]] = {}
    for job in jobs:
        run = RunDir(Path(job.get("run_dir") or ""))
        if job.get("status") != COMPLETED or run.missing([CONFIG]):
            continue
        config = run.read_config()
        if OmegaConf.select(config, "dataset.shard", default=None) is None:
            continue
        groups.setdefault(config_hash(_unsharded(config)), []).append(run.path)
    return list(groups.values())


def merged_name(shard: Shard) -> str:
    """``<model>_<engine>_<hash8>``: the folder name of a merged run under ``--study``."""
    cfg = _unsharded(shard.config)
    return f"{cfg.model.name}_{cfg.engine.name}_{config_hash(cfg)[:8]}"


def _link_or_copy(src: str, dst: str) -> None:
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def _sum_counts(dicts: list[dict]) -> dict:
    """Key-wise sums of nested dicts of counts (the shards' cache statistics)."""
    out: dict = {}
    for d in dicts:
        for key, value in (d or {}).items():
            if isinstance(value, dict):
                out[key] = _sum_counts([out.get(key) or {}, value])
            elif isinstance(value, (int, float)):
                out[key] = out.get(key, 0) + value
    return out


def merge_runs(shard_dirs: list[Path], out: Path, *, partial: bool = False) -> Merged:
    """Merge the shards' run directories into ``out`` (a new folder) and track the result."""
    out = Path(out).resolve()
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise UserError(f"merge: {out} already exists; name a new folder with -o")
    shards = check_shards([read_shard(Path(d)) for d in shard_dirs], partial=partial)
    cfg = _unsharded(shards[0].config)
    order = interleave([s.scene_order for s in shards])
    rows = {scene_id: row for s in shards for scene_id, row in s.rows.items()}
    results = [SceneResult.from_row(rows[scene_id]) for scene_id in order]
    out.mkdir(parents=True, exist_ok=True)
    try:
        return _write_merged(out, cfg, shards, results, partial)
    except BaseException:
        shutil.rmtree(out, ignore_errors=True)
        raise


def _merged_from(shards: list[Shard]) -> list[dict]:
    return [{"run_dir": str(s.run_dir), "shard": f"{s.index[0]}/{s.index[1]}",
             "config_hash": s.manifest.get("config_hash"), "n_scenes": len(s.rows),
             "mlflow_run_id": s.mlflow.get("run_id"),
             "mlflow_tracking_uri": s.mlflow.get("tracking_uri")} for s in shards]


def _write_merged(out: Path, cfg: DictConfig, shards: list[Shard],
                  results: list[SceneResult], partial: bool) -> Merged:
    from visphy_core.api.registry import get_plugin_manager, get_registry
    from visphy_core.calls.usage import UsageLedger
    from visphy_core.execute.run_setup import headline_column
    from visphy_core.infra.cache import Cache
    from visphy_core.scoring.score import ScoringProtocol, score_columns, select_metrics

    run = RunDir(out)
    for shard in shards:
        for scene_id in shard.rows:
            src = RunDir(shard.run_dir).scene_dir(scene_id)
            if src.is_dir():
                shutil.copytree(src, run.scene_dir(scene_id), copy_function=_link_or_copy)
    with open(run.calls_file, "w") as fh:
        for shard in shards:
            calls = RunDir(shard.run_dir).calls_file
            if calls.is_file():
                text = calls.read_text()
                fh.write(text if not text or text.endswith("\n") else text + "\n")
    run.write_config(cfg)  # no credentials in URLs
    run.write_rows(results)
    chash = config_hash(cfg)
    merged_from = _merged_from(shards)
    judges = list(shards[0].manifest.get("judges") or [])
    metrics = select_metrics(get_registry(), cfg.metrics)
    ledger = UsageLedger(run.calls_file)
    cache = Cache(Path(str(cfg.paths.cache_dir)), enabled=False)
    summary = summarise(results, metrics,
                        score_columns(metrics, ScoringProtocol.from_cfg(cfg.metrics)),
                        cache_stats=cache.stats(), judges=judges, usage=ledger.totals(),
                        headline=headline_column(Headline.for_run(cfg.metrics, metrics)))
    summary.update({
        "status": FINISHED, "run_dir": str(out), "model": cfg.model.name,
        **{key: shards[0].summary[key] for key in ("model_output", "model_baseline")
           if key in shards[0].summary},
        "engine": cfg.engine.name, "dataset": cfg.dataset.name,
        "n_selected": sum(int(s.summary.get("n_selected") or len(s.rows)) for s in shards),
        "resumed_rows": sum(int(s.summary.get("resumed_rows") or 0) for s in shards),
        "config_hash": chash,
        "isolation_levels": shards[0].summary.get("isolation_levels"),
        "cache": _sum_counts([s.summary.get("cache") or {} for s in shards]),
        "merged_from": merged_from})
    if partial:
        summary["partial"] = True
    now = dt.datetime.now().isoformat(timespec="seconds")
    manifest = dict(shards[0].manifest)
    manifest.pop("tracking", None)
    manifest.update({"argv": sys.argv, "started": now, "ended": now, "status": FINISHED,
                     "config_hash": chash, "scenes": [r.scene_id for r in results],
                     "merged_from": merged_from,
                     "resumed_rows": summary["resumed_rows"]})
    run.write_manifest(manifest)
    run.write_summary(summary)
    ctx = RunContext(cfg=cfg, run_dir=out, root=Path(str(cfg.paths.root)).resolve(), scenes=[],
                     model_name=str(cfg.model.name), engine_name=str(cfg.engine.name),
                     metrics=metrics, results=list(results), cache=cache, judges=judges,
                     config_hash=chash, merged_from=merged_from)
    pm = get_plugin_manager()
    pm.hook.visphy_run_start(run=ctx)
    if ctx.tracking:
        manifest["tracking"] = dict(ctx.tracking)
        run.write_manifest(manifest)
    pm.hook.visphy_run_end(run=ctx, summary=summary)
    run.write_summary(summary)
    linked = list((summary.get("mlflow") or {}).get("shard_runs") or [])
    return Merged(run_dir=out, summary=summary, results=results, linked=linked,
                  where_to_look=ctx.where_to_look)
