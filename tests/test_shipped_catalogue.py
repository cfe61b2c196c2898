"""The catalogue shipped with visphy (`visphy_plugins.datasets.visphybench.shipped`): it is what
the generator simulates (the one test that pays for a whole simulation), a fresh root gets it
without simulating, a damaged copy is named once and simulated instead, another seed is
simulated, and ``--rebuild-catalogue`` simulates it and renders again what changed."""

from __future__ import annotations

import gzip
import json
import logging
import shutil
from pathlib import Path

import pytest

from visphy_plugins.datasets.visphybench import build, shipped
from visphy_plugins.datasets.visphybench.catalogue import Catalogue, Entry


@pytest.mark.slow
@pytest.mark.timeout(1200)
def test_the_shipped_catalogue_is_what_the_generator_simulates():
    """Every scene drawn, simulated, screened, labelled and split again (1–2 minutes on two
    cores): byte for byte the shipped file."""
    raw = shipped.shipped_bytes(0)
    simulated = build.catalogue_bytes(build.simulate_catalogue(seed=0, workers=2,
                                                               progress=False))
    assert simulated == raw, ("the generator no longer gives the shipped catalogue: run "
                              "`.venv/bin/python scripts/ship_catalogue.py` (and bump "
                              "GENERATOR_VERSION if users' scenes change)")


def test_the_shipped_file_is_its_recorded_build():
    """The file decompresses to the bytes whose digest the manifest records, which parse to a
    whole catalogue of this builder and seed and serialise back to themselves."""
    name = shipped.shipped_name(0)
    record = shipped.read_manifest()[name]
    assert record["builder"] == build.BUILDER_VERSION and record["seed"] == 0
    raw = shipped.shipped_bytes(0)
    assert raw is not None and len(raw) == record["bytes"]
    catalogue = build._parse_catalogue(json.loads(raw), 0)
    assert isinstance(catalogue, Catalogue) and len(catalogue.entries) == record["scenes"] == 209
    assert {k: len(v) for k, v in catalogue.splits.items()} == {"sub": 209, "test": 49, "mini": 4}
    assert build.catalogue_bytes(catalogue) == raw
    assert shipped.shipped_bytes(1) is None  # only the default seed ships


def _fake_simulator(calls: list):
    def simulate(seed: int = 0, workers: int = 2, progress: bool = True) -> Catalogue:
        calls.append(seed)
        entry = Entry(spec={"scene_id": "fake-0", "dim": "2d"}, digest="0" * 64, attempts=1,
                      rejected={})
        return Catalogue(seed=seed, entries=[entry], rejected={}, splits={"mini": ["fake-0"]})
    return simulate


def test_a_fresh_root_gets_the_shipped_catalogue_without_simulating(tmp_path, monkeypatch):
    calls: list = []
    monkeypatch.setattr(build, "simulate_catalogue", _fake_simulator(calls))
    catalogue = build.load_or_build_catalogue(tmp_path / "bench", seed=0, progress=False)
    assert calls == [] and len(catalogue.entries) == 209
    assert (tmp_path / "bench" / "catalogue.json").read_bytes() == shipped.shipped_bytes(0)
    other = build.load_or_build_catalogue(tmp_path / "seed1", seed=1, progress=False)
    assert calls == [1] and other.splits == {"mini": ["fake-0"]}  # no shipped one: simulated


def _damage(kind: str, data: Path) -> None:
    name = shipped.shipped_name(0)
    path = data / name
    packed = path.read_bytes()
    if kind == "truncated":
        path.write_bytes(packed[: len(packed) // 2])
    elif kind == "flipped":
        middle = len(packed) // 2
        path.write_bytes(packed[:middle] + bytes([packed[middle] ^ 0xFF]) + packed[middle + 1:])
    elif kind == "altered":  # a well-formed gzip of other content: only the digest tells
        raw = gzip.decompress(packed).replace(b'"attempts": 1,', b'"attempts": 2,', 1)
        path.write_bytes(gzip.compress(raw, mtime=0))
    elif kind == "missing":
        path.unlink()
    elif kind == "manifest":
        (data / shipped.MANIFEST_NAME).write_text("{not json")
    elif kind == "unlisted":
        (data / shipped.MANIFEST_NAME).write_text("{}")


@pytest.mark.parametrize("kind", ["truncated", "flipped", "altered", "missing", "manifest",
                                  "unlisted"])
def test_a_damaged_shipped_catalogue_is_named_once_and_simulated(tmp_path, monkeypatch, caplog,
                                                                  kind):
    data = tmp_path / "data"
    shutil.copytree(shipped.DATA, data)
    _damage(kind, data)
    monkeypatch.setattr(shipped, "DATA", data)
    calls: list = []
    monkeypatch.setattr(build, "simulate_catalogue", _fake_simulator(calls))
    root = tmp_path / "bench"
    with caplog.at_level(logging.WARNING, logger="visphy.bench"):
        catalogue = build.load_or_build_catalogue(root, seed=0, progress=False)
        again = build.load_or_build_catalogue(root, seed=0, progress=False)
    warned = [r.getMessage() for r in caplog.records if r.name == "visphy.bench"]
    assert len(warned) == 1 and "shipped with visphy" in warned[0], warned
    assert "simulating it instead" in warned[0]
    assert calls == [0] and catalogue.splits == again.splits == {"mini": ["fake-0"]}


def test_rebuild_simulates_and_renders_again_only_what_changed(tmp_path, monkeypatch, caplog):
    """``build-dataset --rebuild-catalogue``: simulated whatever is on disk or shipped; a
    scene whose entry differs loses its rendered mark, the others keep theirs."""
    root = tmp_path / "bench"
    first = build.load_or_build_catalogue(root, seed=0, progress=False)
    (root / "meta").mkdir()
    kept, changed = (e.spec["scene_id"] for e in first.entries[:2])
    for sid in (kept, changed):
        (root / "meta" / f"{sid}.json").write_text("{}")

    def simulate(seed: int = 0, workers: int = 2, progress: bool = True) -> Catalogue:
        again = build._parse_catalogue(json.loads(shipped.shipped_bytes(0)), 0)
        again.entries[1].digest = "f" * 64
        return again

    monkeypatch.setattr(build, "simulate_catalogue", simulate)
    with caplog.at_level(logging.WARNING, logger="visphy.bench"):
        rebuilt = build.load_or_build_catalogue(root, seed=0, progress=False, rebuild=True)
    assert rebuilt.entries[1].digest == "f" * 64
    assert json.loads((root / "catalogue.json").read_bytes())["scenes"][1]["digest"] == "f" * 64
    assert (root / "meta" / f"{kept}.json").is_file()
    assert not (root / "meta" / f"{changed}.json").exists()
    (line,) = [r.getMessage() for r in caplog.records if r.name == "visphy.bench"]
    assert "differs from the one it replaces in 1 scene(s)" in line
