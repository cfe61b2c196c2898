"""Which scenes a run takes (`visphy_core.api.selection`): ``dataset.limit=N`` spreads over the
split's dimensions, difficulties and templates, keeps the ``mini`` split's order, and the
generated benchmark renders the ground truth of the selected scenes only, from the catalogue
shipped with visphy (nothing simulated)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from visphy_core.api.selection import Traits, scene_traits, select_scenes, spread
from visphy_core.config.check import compose
from visphy_core.execute.datasets import load_dataset
from visphy_core.infra.shard import select_shard


def _traits(item: tuple) -> Traits:
    sid, dim, difficulty, template = item
    return Traits(sid, dim, difficulty, template)


@pytest.fixture(scope="module")
def shipped():
    """The shipped catalogue (no simulation): ``(by id, splits)``."""
    from visphy_plugins.datasets.visphybench.build import shipped_catalogue

    catalogue = shipped_catalogue(0)
    assert catalogue is not None
    return {e.spec["scene_id"]: e for e in catalogue.entries}, catalogue.splits


def _split(shipped, name: str) -> list:
    from visphy_plugins.datasets.visphybench.build import entry_traits

    by_id, splits = shipped
    return [entry_traits(by_id[sid]) for sid in splits[name]]


def test_mini_keeps_its_order_for_every_limit(shipped):
    """Its four templates are distinct and its labels (easy, easy, medium, easy) come in
    proportion along it, so every limit is a prefix: the tests' mini fixtures stay valid."""
    mini = _split(shipped, "mini")
    for n in range(1, len(mini) + 2):
        assert spread(mini, n, lambda t: t) == mini[:n]


def test_a_limit_on_the_test_split_spreads_over_templates_labels_and_dims(shipped):
    test = _split(shipped, "test")
    two = spread(test, 2, lambda t: t)
    assert [t.scene_id for t in two] == ["vpb3-s0-2d-t001-v00", "vpb3-s0-2d-t003-v00"]
    assert len({t.template for t in two}) == 2 and {t.difficulty for t in two} == \
        {"easy", "medium"}
    assert [t.scene_id for t in test[:2]] == ["vpb3-s0-2d-t001-v00", "vpb3-s0-2d-t001-v01"]
    for n in range(1, len(test) + 1):
        chosen = spread(test, n, lambda t: t)
        assert len(chosen) == n and chosen == [t for t in test if t in chosen]  # split order
        assert spread(chosen, n, lambda t: t) == chosen  # idempotent
        if n <= 40:  # 43 templates; the labels' quotas reach repeated ones from 42 scenes on
            assert len({(t.dim, t.template) for t in chosen}) == n
    five = spread(test, 5, lambda t: t)
    assert {t.dim for t in five} == {"2d", "3d"}  # 5 of 49 scenes are 3D: one in ten picks
    ten = spread(test, 10, lambda t: t)
    assert sum(t.dim == "3d" for t in ten) == 1
    assert sum(t.difficulty == "medium" for t in ten) in (3, 4)  # 17 of 49


def test_spread_is_proportional_and_deterministic():
    items = [(f"a{i}", "2d", "easy", f"t{i // 3}") for i in range(9)]  # 3 templates × 3
    items += [(f"b{i}", "3d", "hard", None) for i in range(3)]  # no template: their own
    four = spread(items, 4, _traits)
    assert [i[0] for i in four] == ["a0", "a3", "a6", "b0"]
    assert spread(items, 4, _traits) == four
    # 9:3 → 4.5:1.5 picks, the tie to the group that comes first; a template again once each
    # template of its group has one
    assert [i[0] for i in spread(items, 6, _traits)] == ["a0", "a1", "a3", "a4", "a6", "b0"]
    plain = [(f"s{i}", None, None, None) for i in range(5)]  # nothing known: the first N
    assert spread(plain, 3, _traits) == plain[:3]


def test_select_scenes_names_then_limits_then_shards():
    items = [(f"s{i}", "2d", "easy", f"t{i % 2}") for i in range(6)]  # t0 t1 t0 t1 t0 t1
    assert [i[0] for i in select_scenes(items, _traits, limit=2)] == ["s0", "s1"]
    assert [i[0] for i in select_scenes(items, _traits, scenes=["s2", "s4", "s5"], limit=2)] \
        == ["s2", "s5"]
    limited = select_scenes(items, _traits, limit=4)
    assert select_scenes(items, _traits, limit=4, shard="1/2") == select_shard(limited, 1, 2)
    with pytest.raises(ValueError, match="has no scene\\(s\\) nope"):
        select_scenes(items, _traits, scenes=["nope"], name="x")
    with pytest.raises(ValueError, match="selected no scenes .*shard=5/6"):
        select_scenes(items[:2], _traits, shard="5/6", name="x")


def _no_simulation(monkeypatch):
    from visphy_plugins.datasets.visphybench import build

    def refuse(**_):
        raise AssertionError("the catalogue was simulated")

    monkeypatch.setattr(build, "simulate_catalogue", refuse)


def test_a_limited_run_renders_only_its_scenes(tmp_path, monkeypatch):
    """A fresh data dir, ``dataset=visphybench_test dataset.limit=2``: the shipped catalogue
    is written, nothing is simulated, and exactly the two scenes taken are rendered, from two
    templates."""
    _no_simulation(monkeypatch)
    cfg = compose(["dataset=visphybench_test", "dataset.limit=2"])
    scenes = load_dataset(cfg.dataset, tmp_path, progress=False)
    (root,) = tmp_path.iterdir()
    ids = [s.scene_id for s in scenes]
    assert ids == ["vpb3-s0-2d-t001-v00", "vpb3-s0-2d-t003-v00"]
    assert len({s.template_id for s in scenes}) == 2
    assert sorted(p.stem for p in (root / "videos").glob("*.mp4")) == ids
    assert sorted(p.stem for p in (root / "meta").glob("*.json")) == ids
    catalogue = json.loads((root / "catalogue.json").read_text())
    assert len(catalogue["scenes"]) == 209 and len(catalogue["splits"]["test"]) == 49
    # the core's own selection (for a plugin that does not select) picks the same scenes
    assert [s.scene_id for s in select_scenes(scenes, scene_traits, limit=2)] == ids


def test_a_shard_of_a_limit_renders_only_the_shard(tmp_path, monkeypatch):
    _no_simulation(monkeypatch)

    def ids(data: Path, *overrides: str) -> list[str]:
        cfg = compose(["dataset=visphybench_test", *overrides])
        return [s.scene_id for s in load_dataset(cfg.dataset, data, progress=False)]

    shard = ids(tmp_path / "a", "dataset.limit=4", "dataset.shard=1/2")
    (root,) = (tmp_path / "a").iterdir()
    assert sorted(p.stem for p in (root / "meta").glob("*.json")) == sorted(shard)
    assert len(shard) == 2
    whole = ids(tmp_path / "a", "dataset.limit=4")
    assert shard == select_shard(whole, 1, 2)


def test_named_scenes_of_the_generated_benchmark_are_checked_against_the_split(tmp_path,
                                                                              monkeypatch):
    _no_simulation(monkeypatch)
    cfg = compose(["dataset=mini", "dataset.scenes=[vpb3-s0-2d-t044-v00]"])
    with pytest.raises(ValueError, match="dataset 'mini' has no scene\\(s\\) vpb3-s0-2d-t044"):
        load_dataset(cfg.dataset, tmp_path, progress=False)
    (root,) = tmp_path.iterdir()
    assert not list(root.glob("meta/*.json"))  # refused before rendering anything


def test_a_shards_run_finds_all_its_scenes_again(tmp_path, monkeypatch):
    """Re-scoring, intervening on or rating a shard's run loads the scenes it names, all of
    them: its ``dataset.shard`` selected them once and is not applied to them again."""
    from visphy_core.execute import run_scenes

    cfg = compose(["dataset=tiny", "dataset.shard=0/2", f"paths.data_dir={tmp_path}"])
    ran = [s.scene_id for s in load_dataset(cfg.dataset, tmp_path, progress=False)]
    assert len(ran) == 2
    monkeypatch.setattr(run_scenes, "read_run_config", lambda run_dir: cfg)
    assert sorted(run_scenes.load_run_scenes(tmp_path, ran)) == sorted(ran)
