"""Run directories are claimed atomically: runs started in the same second with configs that
differ only under ``run.*`` (the same digest) never share a directory."""

from __future__ import annotations

import multiprocessing as mp
from pathlib import Path

from omegaconf import OmegaConf

from visphy_core.results.run_dir import new_run_dir

CFG = {"model": {"name": "replay"}, "engine": {"name": "threejs"}, "run": {"retry": True},
       "paths": {"home": "/nowhere"}}


def _claim(args) -> str:
    runs_dir, retry, barrier = args
    cfg = OmegaConf.create({**CFG, "run": {"retry": retry}})
    barrier.wait()
    return str(new_run_dir(cfg, Path(runs_dir)))


def test_same_second_same_digest_gets_distinct_created_dirs(tmp_path):
    cfg = OmegaConf.create(CFG)
    first, second = new_run_dir(cfg, tmp_path / "runs"), new_run_dir(cfg, tmp_path / "runs")
    assert first != second and first.is_dir() and second.is_dir()


def test_concurrent_processes_never_share_a_run_dir(tmp_path):
    ctx = mp.get_context("fork")
    with ctx.Manager() as manager:
        barrier = manager.Barrier(6)
        with ctx.Pool(6) as pool:
            dirs = pool.map(_claim, [(str(tmp_path), i % 2 == 0, barrier) for i in range(6)])
    assert len(set(dirs)) == 6
    assert all(Path(d).is_dir() for d in dirs)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(Path(d).name for d in dirs)
