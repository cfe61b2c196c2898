"""``dataset.shard=i/n``: the n shards of a selection are disjoint, cover it exactly, differ in
size by at most one, are the same on every call, and interleave back to the unsharded order;
bad values fail at compose time in one line."""

from __future__ import annotations

import pytest

from conftest import run_cli
from visphy_core.config.check import ConfigError, check_overrides, compose
from visphy_core.execute.datasets import load_dataset
from visphy_core.infra.shard import interleave, parse_shard, select_shard


@pytest.mark.parametrize("size", [0, 1, 2, 7, 12])
@pytest.mark.parametrize("count", [1, 2, 3, 5])
def test_shards_partition_the_selection(size, count):
    items = [f"scene{k:02d}" for k in range(size)]
    shards = [select_shard(items, i, count) for i in range(count)]
    flat = [x for shard in shards for x in shard]
    assert sorted(flat) == sorted(items) and len(flat) == len(set(flat))  # covering, disjoint
    assert max(map(len, shards)) - min(map(len, shards)) <= 1
    assert interleave(shards) == items  # the unsharded order comes back
    assert shards == [select_shard(list(items), i, count) for i in range(count)]


@pytest.mark.parametrize("text, expected", [
    (None, None), ("", None), ("0/1", (0, 1)), ("3/4", (3, 4)), (" 1 / 2 ", (1, 2))])
def test_parse_shard(text, expected):
    assert parse_shard(text) == expected


@pytest.mark.parametrize("text, message", [
    ("4/4", "shard indices are 0-based, 0/4 … 3/4"),
    ("1/0", "the number of shards must be at least 1"),
    ("half", "is not of the form i/n"),
    ("-1/2", "is not of the form i/n"),
])
def test_bad_shards_fail_at_compose_time_in_one_line(text, message):
    with pytest.raises(ConfigError) as info:
        check_overrides([f"dataset.shard={text}"])
    assert message in str(info.value) and "\n" not in str(info.value)


def test_a_sweep_with_one_bad_shard_fails_before_any_job():
    with pytest.raises(ConfigError, match="dataset.shard=2/2"):
        check_overrides(["dataset.shard=0/2,1/2,2/2"])


def test_the_dataset_loader_selects_the_shard_after_the_limit(tmp_path):
    def ids(*overrides: str) -> list[str]:
        cfg = compose(["dataset=tiny", *overrides])
        return [s.scene_id for s in load_dataset(cfg.dataset, tmp_path, progress=False)]

    everything = ids()
    assert len(everything) == 3
    assert ids("dataset.shard=0/2") == everything[0::2]
    assert ids("dataset.shard=1/2") == everything[1::2]
    assert ids("dataset.limit=2", "dataset.shard=1/2") == everything[1:2]
    assert interleave([ids("dataset.shard=0/2"), ids("dataset.shard=1/2")]) == everything
    with pytest.raises(ValueError, match="selected no scenes .*shard=3/4"):
        ids("dataset.shard=3/4")


def test_the_cli_reports_a_bad_shard_in_one_line(tmp_path):
    proc = run_cli("dataset=tiny", "model=static", "dataset.shard=2/2", home=tmp_path,
                   check=False)
    assert proc.returncode == 2
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert lines == ["error: dataset.shard=2/2: shard indices are 0-based, 0/2 … 1/2"]


def test_dataset_scenes_selects_even_when_the_plugin_returns_every_scene(tmp_path, monkeypatch):
    """``dataset.scenes`` is applied by the core: a third-party dataset plugin that returns all
    its scenes still runs only the ones named."""
    import copy

    from visphy_core.api.registry import get_registry
    from visphy_plugins.datasets.tiny import TinyDataset

    class EveryScene(TinyDataset):
        def load(self, cfg, data_dir, progress=True):
            everything = copy.deepcopy(cfg)
            everything.scenes = None
            return super().load(everything, data_dir, progress)

    monkeypatch.setitem(get_registry().datasets, "every_scene",
                        (EveryScene, *get_registry().datasets["tiny"][1:]))
    cfg = compose(["dataset=tiny"])
    all_ids = [s.scene_id for s in load_dataset(cfg.dataset, tmp_path, progress=False)]
    cfg = compose(["dataset=tiny", f"dataset.scenes=[{all_ids[1]}]"])
    cfg.dataset.source = "every_scene"
    assert [s.scene_id for s in load_dataset(cfg.dataset, tmp_path, progress=False)] == \
        [all_ids[1]]
