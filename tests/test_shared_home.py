"""Processes sharing one home: the content-addressed cache and the generated benchmark's build.

Every concurrent test starts real processes (``python -c`` importing this module and running one
of its ``_child_*`` functions) that import what they need, say they are ready, and start the
contended step together when the test tells them to, so the step itself overlaps. The
benchmark's catalogue builder is replaced in the children by a fake that records each call and
takes half a second: the tests check the locking, not the generator (which simulates 209
scenes)."""

from __future__ import annotations

import json
import logging
import os
import shutil
import subprocess
import sys
import time
from dataclasses import asdict
from pathlib import Path

import pytest

from visphy_core.infra.cache import Cache, CorruptEntry, content_key, read_json

TESTS = Path(__file__).resolve().parent
CHILD = ("import sys; sys.path.insert(0, sys.argv[1]); import test_shared_home as t; "
         "t._child(*sys.argv[2:])")
#: A key whose bucket holds nothing else.
KEY = content_key("shared-home")
#: How long the fake catalogue builder and the wrapped scene writer take: long enough that
#: every other process reaches the same step while it runs.
HOLD_S = 0.5


# ------------------------------------------------------------------------------ processes


def _child(name: str, *args: str) -> None:
    """A child process: everything is imported; say so, wait for the go, run ``name``."""
    print("ready", flush=True)
    sys.stdin.readline()
    globals()[f"_child_{name}"](*args)


def _together(*commands: tuple[str, ...]) -> list[subprocess.Popen]:
    """Start one process per command; return once all are ready and told to go."""
    procs = [subprocess.Popen([sys.executable, "-c", CHILD, str(TESTS), *cmd],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for cmd in commands]
    for proc in procs:
        if proc.stdout.readline() != "ready\n":
            for other in procs:
                other.kill()
            raise AssertionError(f"a child did not start: {proc.communicate()[1]}")
    for proc in procs:
        proc.stdin.write("go\n")
        proc.stdin.flush()
    return procs


def _finish(procs: list[subprocess.Popen], timeout: float = 60) -> None:
    for proc in procs:
        _, err = proc.communicate(timeout=timeout)
        assert proc.returncode == 0, err


def _record(log: str) -> None:
    """Append this process's id to ``log`` (one ``write`` on an ``O_APPEND`` file: whole lines)."""
    fd = os.open(log, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, f"{os.getpid()}\n".encode())
    finally:
        os.close(fd)


def _lines(log: Path) -> list[str]:
    return log.read_text().splitlines() if log.is_file() else []


# ------------------------------------------------------------------------------ cache


def _payload(tag: str) -> dict[str, bytes]:
    """About 100 KB in three files, so a read takes long enough to meet a swap."""
    return {f"part{i}.bin": (f"{tag}:{i}:".encode() * 10_000) for i in range(3)}


def _child_put(root: str, tag: str, rounds: str) -> None:
    cache = Cache(root)
    for _ in range(int(rounds)):
        cache.put("render", KEY, _payload(tag))


def _parse(entry: Path) -> str:
    """A payload parser that checks its files belong together (one writer's)."""
    tags = {(entry / f"part{i}.bin").read_bytes().split(b":")[0] for i in range(3)}
    if len(tags) != 1:
        raise CorruptEntry(f"{entry}: parts of writers {sorted(tags)}")
    return tags.pop().decode()


def _child_load(root: str, stop: str, out: str) -> None:
    cache = Cache(root)
    served = set()
    while not os.path.exists(stop) or not served:
        served.add(cache.load("render", KEY, _parse))
    Path(out).write_text(json.dumps({"served": sorted(map(str, served)),
                                     "hits": cache.hits["render"],
                                     "dropped": sum(cache.dropped.values()),
                                     "warnings": cache.warnings}))


@pytest.mark.parametrize("content", ["identical", "different"])
def test_concurrent_puts_leave_one_whole_entry_and_readers_drop_nothing(tmp_path, content):
    """Four writers put one key over and over (the same bytes, or each its own as a recomputed
    model reply would be) while two readers loop on `Cache.load`: no reader ever drops the
    entry or is served parts of two writers' entries, and one whole entry remains with no
    temporary beside it."""
    root, stop = tmp_path / "cache", tmp_path / "stop"
    Cache(root).put("render", KEY, _payload("w0"))
    tags = [f"w{i if content == 'different' else 0}" for i in range(4)]
    readers = _together(*[("load", str(root), str(stop), str(tmp_path / f"r{i}.json"))
                          for i in range(2)])
    writers = _together(*[("put", str(root), tag, "25") for tag in tags])
    _finish(writers)
    stop.touch()
    _finish(readers)
    for i in range(2):
        seen = json.loads((tmp_path / f"r{i}.json").read_text())
        assert seen["dropped"] == 0 and seen["warnings"] == [], seen
        assert seen["hits"] > 0 and set(seen["served"]) <= {*tags, "None"}, seen
    bucket = root / "render" / KEY[:2]
    assert sorted(p.name for p in bucket.iterdir()) == [KEY]
    assert sorted(p.name for p in bucket.parent.iterdir()) == [KEY[:2], f"{KEY[:2]}.lock"]
    cache = Cache(root)
    entry = cache.get("render", KEY)
    assert entry is not None and cache.verify(entry) is None
    assert (entry / "part0.bin").read_bytes() in {_payload(t)["part0.bin"] for t in tags}


def test_a_reader_keeps_an_entry_replaced_between_its_check_and_its_drop(tmp_path, monkeypatch):
    """The reader's look at the entry fails (as when its reads straddle another process's swap)
    and meanwhile a writer puts a good entry in its place: under the lock the drop finds an
    entry that verifies, keeps it, reports nothing, and the read is a hit on it."""
    cache = Cache(tmp_path)
    cache.put("score", KEY, {"value.json": '{"value": 1}'})
    real_verify = cache.verify

    def straddled(entry):
        monkeypatch.setattr(cache, "verify", real_verify)  # only this first look is torn
        Cache(tmp_path).put("score", KEY, {"value.json": '{"value": 2}'})  # the other writer
        return "digest mismatch in value.json"

    monkeypatch.setattr(cache, "verify", straddled)
    entry = cache.get("score", KEY)
    assert entry == cache.path("score", KEY)
    assert read_json(entry / "value.json") == {"value": 2} and cache.verify(entry) is None
    assert not cache.warnings and not cache.dropped and cache.hits["score"] == 1


def test_a_payload_that_fails_to_parse_keeps_the_entry_that_replaced_it(tmp_path):
    """`Cache.load`: the payload read does not parse, but by the time of the drop another
    process has replaced the entry: the new entry stays and is served (parsed under the lock);
    an unparseable entry nobody replaced is still dropped."""
    cache, calls = Cache(tmp_path), []
    cache.put("response", KEY, {"response.json": '{"text": "old"}'})

    def parse(entry):
        calls.append(entry)
        if len(calls) == 1:
            Cache(tmp_path).put("response", KEY, {"response.json": '{"text": "new"}'})
            raise CorruptEntry(f"{entry}: torn read")
        return read_json(entry / "response.json")

    assert cache.load("response", KEY, parse) == {"text": "new"}
    assert not cache.warnings and not cache.dropped and cache.hits["response"] == 1

    def refuse(entry):
        raise CorruptEntry(f"{entry}: not a reply")

    assert cache.load("response", KEY, refuse) is None
    assert len(cache.warnings) == 1 and not cache.path("response", KEY).exists()
    assert cache.stats()["response"] == {"hits": 1, "misses": 1, "dropped": 1}


# ------------------------------------------------------------------------------ catalogue


def _fake_catalogue(log: str):
    """A stand-in for `build_catalogue`: records the call, holds `HOLD_S`, returns one scene."""
    from visphy_plugins.datasets.visphybench.catalogue import Catalogue, Entry

    def build(seed: int = 0, workers: int = 2, progress: bool = True) -> Catalogue:
        _record(log)
        time.sleep(HOLD_S)
        entry = Entry(spec={"scene_id": "fake-0", "dim": "2d"}, digest="0" * 64, attempts=1,
                      rejected={"overlap": 2})
        return Catalogue(seed=seed, entries=[entry], rejected={"overlap": 2},
                         splits={"mini": ["fake-0"]})
    return build


class _Lines(logging.Handler):
    def __init__(self):
        super().__init__(logging.WARNING)
        self.lines: list[str] = []

    def emit(self, record):
        self.lines.append(record.getMessage())


def _child_catalogue(root: str, log: str, out: str) -> None:
    from visphy_plugins.datasets.visphybench import build

    build.build_catalogue = _fake_catalogue(log)
    warned = _Lines()
    logging.getLogger("visphy.bench").addHandler(warned)
    catalogue = build.load_or_build_catalogue(Path(root), seed=0, progress=False, workers=1)
    Path(out).write_text(json.dumps({"catalogue": asdict(catalogue), "warnings": warned.lines}))


@pytest.mark.parametrize("state", ["missing", "garbage"])
def test_concurrent_callers_build_the_catalogue_once(tmp_path, state):
    """Four processes ask one root for its catalogue at once: one builds it (one call of the
    builder, one warning when the file was garbage), the others wait and read its file, and
    all four get the same catalogue."""
    root, log = tmp_path / "bench", tmp_path / "builds.log"
    if state == "garbage":
        root.mkdir()
        (root / "catalogue.json").write_bytes(b'{"builder": "visphy-bench/3", "sce')
    procs = _together(*[("catalogue", str(root), str(log), str(tmp_path / f"c{i}.json"))
                        for i in range(4)])
    _finish(procs)
    assert len(_lines(log)) == 1
    results = [json.loads((tmp_path / f"c{i}.json").read_text()) for i in range(4)]
    assert all(r["catalogue"] == results[0]["catalogue"] for r in results)
    assert results[0]["catalogue"]["splits"] == {"mini": ["fake-0"]}
    warnings = [w for r in results for w in r["warnings"]]
    assert len(warnings) == (1 if state == "garbage" else 0), warnings
    assert all(str(root / "catalogue.json") in w for w in warnings)
    assert json.loads((root / "catalogue.json").read_text())["scenes"][0]["spec"]["scene_id"] \
        == "fake-0"


@pytest.mark.parametrize("content", [b"\x00\xff garbage", b'{"builder": "visphy-bench/3", "se',
                                     b"[]", b'{"builder": "visphy-bench/3", "seed": 0}'])
def test_an_unreadable_catalogue_is_named_once_and_rebuilt(tmp_path, monkeypatch, caplog, content):
    """Garbage, a truncated file, or JSON that is no catalogue: one warning naming the file,
    then the catalogue is rebuilt; the scenes already rendered stay."""
    from visphy_plugins.datasets.visphybench import build

    root, log = tmp_path / "bench", tmp_path / "builds.log"
    (root / "meta").mkdir(parents=True)
    (root / "catalogue.json").write_bytes(content)
    (root / "meta" / "fake-0.json").write_text("{}")
    monkeypatch.setattr(build, "build_catalogue", _fake_catalogue(str(log)))
    with caplog.at_level(logging.WARNING, logger="visphy.bench"):
        catalogue = build.load_or_build_catalogue(root, seed=0, progress=False, workers=1)
        again = build.load_or_build_catalogue(root, seed=0, progress=False, workers=1)
    warned = [r.getMessage() for r in caplog.records if r.name == "visphy.bench"]
    assert len(warned) == 1 and str(root / "catalogue.json") in warned[0], warned
    assert "rebuilding" in warned[0]
    assert len(_lines(log)) == 1 and asdict(again) == asdict(catalogue)
    assert (root / "meta" / "fake-0.json").is_file()


# ------------------------------------------------------------------------------ scenes


def _child_scenes(data_dir: str, log: str) -> None:
    from visphy_plugins.datasets.visphybench import build

    real = build.write_scene

    def write_scene(*args, **kwargs):
        _record(log)
        time.sleep(HOLD_S)
        return real(*args, **kwargs)

    build.write_scene = write_scene
    build.build_dataset(Path(data_dir), progress=False, workers=1)


def test_two_processes_render_a_missing_scene_once_and_byte_identically(tmp_path, monkeypatch):
    """A one-scene benchmark (a real catalogue entry, simulated here) is built in this process;
    then two processes build a second root that has its catalogue but no scene: the scene is
    written once, and every file matches the single-process build byte for byte."""
    from visphy_plugins.datasets.visphybench import build
    from visphy_plugins.datasets.visphybench.catalogue import build_catalogue, units

    one = build_catalogue(seed=0, workers=1, progress=False,
                          only=[u for u in units() if u.dim == "2d"][:1])
    monkeypatch.setattr(build, "build_catalogue", lambda **_: one)
    alone = build.build_dataset(tmp_path / "alone", progress=False, workers=1)
    shared = build.dataset_root(tmp_path / "shared")
    shared.mkdir(parents=True)
    shutil.copyfile(alone / "catalogue.json", shared / "catalogue.json")
    log = tmp_path / "renders.log"
    _finish(_together(*[("scenes", str(tmp_path / "shared"), str(log)) for _ in range(2)]))
    assert len(_lines(log)) == 1
    timed = {"build_times.json", "DATASHEET.md", "datasheet.json"}  # hold the build's time

    def files(root: Path) -> dict[str, bytes]:
        return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
                if p.is_file() and p.suffix != ".lock" and p.name not in timed}

    built = files(alone)
    sid = one.entries[0].spec["scene_id"]
    assert f"videos/{sid}.mp4" in built and f"meta/{sid}.json" in built
    assert files(shared) == built
