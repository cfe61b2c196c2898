"""Run directories: naming, the lock a live run holds, and resuming an unfinished one.

A run directory is named ``<date>_<model>_<engine>_<hash>``; its manifest records the full config
hash and a status. Rerunning a command resumes the newest unfinished run directory with the same
config hash that no live process holds (`find_resumable`), keeping the rows it already wrote
(`read_rows`).
"""

from __future__ import annotations

import datetime as dt
import json
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from visphy_core.infra.cache import content_key
from visphy_core.infra.files import atomic_write
from visphy_core.results.row import SceneResult

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
        self.path = run_dir / ".lock"
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
            manifest = json.loads((run_dir / "manifest.json").read_text())
        except (OSError, ValueError):
            continue
        if not isinstance(manifest, dict) or manifest.get("config_hash") != chash:
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
        manifest = json.loads((run_dir / "manifest.json").read_text())
    except (OSError, ValueError):
        raise ConfigError(f"run.resume={run_dir}: not a run directory with a readable "
                          "manifest.json") from None
    if not isinstance(manifest, dict) or manifest.get("config_hash") != chash:
        raise ConfigError(f"run.resume={run_dir}: that run's config differs from this "
                          "command's; resume it with its own command (its config.yaml)")
    if manifest.get("status", FINISHED) == FINISHED:
        raise ConfigError(f"run.resume={run_dir}: that run is finished; nothing to resume")
    lock = RunLock(run_dir)
    if not lock.acquire():
        raise ConfigError(f"run.resume={run_dir}: another process is working in it")
    return run_dir, lock


def read_rows(path: Path, scene_ids: list[str]) -> list[SceneResult]:
    """Finished rows of an interrupted run, one per selected scene (first wins). A line that
    does not parse (the half-written last line of a killed run) is dropped and the file is
    rewritten without it."""
    if not path.is_file():
        return []
    wanted = set(scene_ids)
    kept: dict[str, tuple[str, SceneResult]] = {}
    dirty = False
    raw = path.read_bytes()
    for line in raw.decode("utf-8", errors="replace").splitlines():
        if not line.strip():
            dirty = True
            continue
        try:
            row = json.loads(line)
            result = SceneResult.from_row(row)
        except (ValueError, TypeError, KeyError):
            dirty = True
            continue
        if result.scene_id not in wanted or result.scene_id in kept:
            dirty = True
            continue
        kept[result.scene_id] = (line, result)
    if not raw.endswith(b"\n") and raw:
        dirty = True
    if dirty:
        atomic_write(path, "".join(line + "\n" for line, _ in kept.values()), fsync=True)
    return [result for _, result in kept.values()]
