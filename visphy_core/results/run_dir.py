"""Run directories: the typed `RunDir` (where each file of a run is, with the one reader and
the one writer of each), naming, the lock a live run holds, and resuming an unfinished one.

A run directory is named ``<date>_<model>_<engine>_<hash>``; its manifest records the full config
hash and a status. Rerunning a command resumes the newest unfinished run directory with the same
config hash that no live process holds (`find_resumable`), keeping the rows it already wrote
(`RunDir.restore_rows`).
"""

from __future__ import annotations

import datetime as dt
import json
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, Iterable

from omegaconf import DictConfig, OmegaConf

from visphy_core.infra.cache import content_key
from visphy_core.infra.files import atomic_write
from visphy_core.infra.secrets import public_yaml
from visphy_core.results import layout
from visphy_core.results.row import SceneResult
from visphy_core.results.rows import parse_line, read_results, write_results
from visphy_core.results.write import write_json


@dataclass(frozen=True)
class RunDir:
    """A run directory's files (`visphy_core.results.layout`): where each is, and the one reader
    and the one writer of each. Readers raise `OSError` for a missing or unreadable file and
    `ValueError` for one that is not what it should be; callers that read what a run has so far
    (`visphy_core.results.load.load_run`) catch them."""

    path: Path

    @property
    def config_file(self) -> Path:
        return self.path / layout.CONFIG

    @property
    def manifest_file(self) -> Path:
        return self.path / layout.MANIFEST

    @property
    def summary_file(self) -> Path:
        return self.path / layout.SUMMARY

    @property
    def rows_file(self) -> Path:
        """``results.jsonl``: the rows as the run goes."""
        return self.path / layout.RESULTS_JSONL

    @property
    def parquet_file(self) -> Path:
        return self.path / layout.RESULTS_PARQUET

    @property
    def calls_file(self) -> Path:
        """The call ledger (`visphy_core.calls.usage.UsageLedger`)."""
        return self.path / layout.CALLS

    @property
    def scenes(self) -> Path:
        return self.path / layout.SCENES

    def scene_dir(self, scene_id: str) -> Path:
        return self.scenes / scene_id

    def missing(self, names: Iterable[str]) -> list[str]:
        """Those of ``names`` (`layout.FINISHED_FILES`, …) that are not files of the run."""
        return [name for name in names if not (self.path / name).is_file()]

    def present(self, names: Iterable[str] = layout.RUN_FILES) -> list[Path]:
        """The files of ``names`` the run has, in that order."""
        return [self.path / name for name in names if (self.path / name).is_file()]

    def read_config(self) -> DictConfig:
        """``config.yaml``, as written (interpolations unresolved)."""
        cfg = OmegaConf.load(self.config_file)
        if not isinstance(cfg, DictConfig):
            raise ValueError(f"{self.config_file}: not a mapping")
        return cfg

    def write_config(self, cfg: DictConfig) -> None:
        """``config.yaml`` without credentials (`visphy_core.infra.secrets.public_yaml`)."""
        atomic_write(self.config_file, public_yaml(cfg))

    def read_manifest(self) -> dict[str, Any]:
        return _read_json(self.manifest_file)

    def write_manifest(self, manifest: dict[str, Any]) -> None:
        write_json(self.manifest_file, manifest)

    def read_summary(self) -> dict[str, Any]:
        return _read_json(self.summary_file)

    def write_summary(self, summary: dict[str, Any]) -> None:
        write_json(self.summary_file, summary)

    def tracking(self) -> dict[str, Any]:
        """Where tracking plugins recorded the run (the manifest's ``tracking``, by plugin);
        empty when the manifest says nothing or cannot be read."""
        try:
            tracking = self.read_manifest().get("tracking")
        except (OSError, ValueError):
            return {}
        return tracking if isinstance(tracking, dict) else {}

    def read_rows(self) -> tuple[list[SceneResult], int]:
        """The rows, first per scene (`visphy_core.results.rows.read_results`), with the number
        of lines that could not be read."""
        return read_results(self.path)

    def write_rows(self, results: list[SceneResult], *, jsonl: bool = True) -> None:
        """``results.parquet`` (and, with ``jsonl``, ``results.jsonl``) holding ``results``."""
        write_results(self.path, results, jsonl=jsonl)

    def open_rows(self) -> IO[str]:
        """``results.jsonl`` opened for appending (a row per line, `rows.jsonl_line`)."""
        return self.rows_file.open("a")

    def restore_rows(self, scene_ids: list[str]) -> list[SceneResult]:
        """Finished rows of an interrupted run, one per selected scene (first wins). A line that
        is not a row (the half-written last line of a killed run) is dropped and the file is
        rewritten without it."""
        path = self.rows_file
        if not path.is_file():
            return []
        wanted = set(scene_ids)
        kept: dict[str, tuple[str, SceneResult]] = {}
        raw = path.read_bytes()
        dirty = bool(raw) and not raw.endswith(b"\n")
        for line in raw.decode("utf-8", errors="replace").splitlines():
            result = parse_line(line) if line.strip() else None
            if result is None or result.scene_id not in wanted or result.scene_id in kept:
                dirty = True
                continue
            kept[result.scene_id] = (line, result)
        if dirty:
            atomic_write(path, "".join(line + "\n" for line, _ in kept.values()), fsync=True)
        return [result for _, result in kept.values()]


def kept_attempt(scene_dir: Path, attempts: int) -> int | None:
    """The attempt whose reply a scene's row kept (its analysis A and spec S): the last of
    ``attempts`` before the first whose reply is missing or was a provider error, as the
    pipeline's attempt loop keeps them; None when the first already is."""
    kept = None
    for attempt in range(1, max(attempts, 1) + 1):
        text = scene_dir / layout.attempt_file(layout.RESPONSE, attempt, "txt")
        meta = scene_dir / layout.attempt_file(layout.RESPONSE, attempt, "json")
        if not text.is_file() or (meta.is_file() and _read_json(meta).get("error")):
            break
        kept = attempt
    return kept


def _read_json(path: Path) -> dict[str, Any]:
    data = json.loads(path.read_bytes().decode("utf-8", errors="replace"))
    if not isinstance(data, dict):
        raise ValueError(f"{path}: not a JSON object")
    return data


#: Manifest statuses; every one but "finished" can be resumed by rerunning the same command
#: ("cost_cap": stopped by run.cost_cap_usd; raise the cap and rerun to continue).
FINISHED, RUNNING, INTERRUPTED, FAILED = "finished", "running", "interrupted", "failed"
COST_CAP = "cost_cap"
#: Keys of a model or judge config that change how calls are made, not what they return.
TRANSPORT_KEYS = ("base_url", "timeout_s", "retries", "concurrency", "api_key_env")


def config_hash(cfg: DictConfig) -> str:
    """Hash of everything that changes a run's rows: the config without where things are written
    (``paths``), without the keys that only change how the run looks or is paced
    (``run.progress``, ``run.summary``, ``run.cache``, ``run.cost_cap_usd``, ``run.prefetch``,
    ``run.workers``, ``run.resume``) and without the
    transport settings of models and judges (`TRANSPORT_KEYS`: a fake server on another port,
    a longer timeout). Two commands with the same hash produce the same rows."""
    resolved = OmegaConf.to_container(cfg, resolve=True)
    resolved.pop("paths", None)
    run = dict(resolved.pop("run", None) or {})
    for key in ("progress", "summary", "cache", "cost_cap_usd", "prefetch", "workers", "resume"):
        run.pop(key, None)
    resolved["run"] = run
    for node in [resolved.get("model"), *(resolved.get("judge") or {}).values()]:
        if isinstance(node, dict):
            for key in TRANSPORT_KEYS:
                node.pop(key, None)
    return content_key(resolved)


def new_run_dir(cfg: DictConfig, runs_dir: Path) -> Path:
    """A fresh run directory, created here: ``mkdir`` without ``exist_ok`` is the claim, so two
    runs started in the same second (same config up to ``run.*``) never share one."""
    resolved = OmegaConf.to_container(cfg, resolve=True)
    for key in ("paths", "run"):
        resolved.pop(key, None)
    digest = content_key(resolved)[:8]
    stamp = dt.datetime.now().strftime("%Y-%m-%d_%H-%M-%S")
    base = f"{stamp}_{cfg.model.name}_{cfg.engine.name}_{digest}"
    runs_dir.mkdir(parents=True, exist_ok=True)
    n = 1
    while True:
        path = runs_dir / (base if n == 1 else f"{base}.{n}")
        try:
            path.mkdir()
        except FileExistsError:
            n += 1
            continue
        return path


class RunLock:
    """An exclusive ``flock`` on ``<run dir>/.lock`` held while a process works in the run dir,
    so a run still going in another process is never resumed under its feet."""

    def __init__(self, run_dir: Path):
        self.path = run_dir / layout.LOCK
        self.fh = None

    def acquire(self) -> bool:
        import fcntl

        self.path.parent.mkdir(parents=True, exist_ok=True)
        fh = open(self.path, "a")
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            fh.close()
            return False
        self.fh = fh
        return True

    def release(self) -> None:
        if self.fh is not None:
            self.fh.close()
            self.fh = None


def find_resumable(runs_dir: Path, chash: str) -> tuple[Path, RunLock] | None:
    """The newest run dir with this config hash that did not finish and is not in use."""
    if not runs_dir.is_dir():
        return None
    for run_dir in sorted((p for p in runs_dir.iterdir() if p.is_dir()), reverse=True):
        try:
            manifest = RunDir(run_dir).read_manifest()
        except (OSError, ValueError):
            continue
        if manifest.get("config_hash") != chash:
            continue
        if manifest.get("status", FINISHED) == FINISHED:
            continue
        lock = RunLock(run_dir)
        if lock.acquire():
            return run_dir, lock
    return None


def claim_run_dir(run_dir: Path, chash: str) -> tuple[Path, RunLock]:
    """``run.resume=<run_dir>``: that run directory, locked, when it is an unfinished run of
    this config that no process holds; `ConfigError` (one line) otherwise."""
    from visphy_core.infra.errors import ConfigError

    run_dir = Path(run_dir).expanduser().resolve()
    try:
        manifest = RunDir(run_dir).read_manifest()
    except (OSError, ValueError):
        raise ConfigError(f"run.resume={run_dir}: not a run directory with a readable "
                          f"{layout.MANIFEST}") from None
    if manifest.get("config_hash") != chash:
        raise ConfigError(f"run.resume={run_dir}: that run's config differs from this "
                          "command's; resume it with its own command (its config.yaml)")
    if manifest.get("status", FINISHED) == FINISHED:
        raise ConfigError(f"run.resume={run_dir}: that run is finished; nothing to resume")
    lock = RunLock(run_dir)
    if not lock.acquire():
        raise ConfigError(f"run.resume={run_dir}: another process is working in it")
    return run_dir, lock
