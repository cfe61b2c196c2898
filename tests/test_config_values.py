"""Bad config values and bad input end in one line on stderr, exit status 2, before any work.

Each case runs the real CLI (`python -m visphy_core ...`) with a scratch VISPHY_HOME: stderr is
exactly one line starting with ``error: ``, there is no traceback, the message names the key and
what is valid, and nothing was built or run (no runs dir; for the checks made before the run, no
VISPHY_HOME at all).
"""

from __future__ import annotations

import json
import shlex
from dataclasses import dataclass, field

import pytest

from conftest import run_cli
from visphy_core.config.check import ConfigError, check_overrides

#: (overrides, fragments the one-line message must contain). All fail before any work.
BAD_INPUTS = [
    ("tracking.backend=mlfow",
     ["tracking.backend=mlfow is not a valid choice; valid: mlflow, none"]),
    ("dataset.source=orignal",
     ["dataset.source=orignal is not an installed dataset; valid: generated, hf, original, tiny"]),
    ("engine=blender engine.render_engine=cyclez",
     ["engine.render_engine=cyclez is not a valid choice; valid: workbench, cycles, eevee"]),
    ("engine=blender engine.timeout_s=0",
     ["engine.timeout_s=0 is out of range: must be ≥ 1"]),
    ("dataset.limit=-1", ["dataset.limit=-1 is out of range: must be ≥ 1"]),
    ("dataset.limit=0", ["dataset.limit=0 is out of range: must be ≥ 1"]),
    ("dataset.limit=two", ["dataset.limit=two is not a valid integer"]),
    ("engine.timeout_s=-5", ["engine.timeout_s=-5 is out of range: must be ≥ 1 and ≤ 3600"]),
    ("engine.timeout_s=1e9", ["engine.timeout_s=1e+09 is out of range: must be ≥ 1 and ≤ 3600"]),
    ("engine.timeout_s=fast", ["engine.timeout_s=fast is not a valid float"]),
    ("metrics.names=[psnrr]",
     ["metrics.names=[psnrr]: psnrr is not an installed metric; installed: ", "psnr", "ssim"]),
    ("metrics.names=[]", ["metrics.names=[] names no metric; installed: "]),
    ("judge=gemini judge.gemini.name=nope",
     ["judge.gemini.name=nope is not an installed judge; installed: ", "gemini"]),
    ("judge=gemin", ["judge=gemin is not an option of 'judge'; valid: ", "gemini", "none"]),
    ("judge=[gemini,gptx]", ["judge=gptx is not an option of 'judge'; valid: ", "gpt_frames"]),
    ("run.cost_cap_usd=-1", ["run.cost_cap_usd=-1 is out of range: must be ≥ 0"]),
    ("model.name=gpt-9", ["model.name=gpt-9 is not an installed model; installed: ", "oracle"]),
    ("engine.name=threejz",
     ["engine.name=threejz is not an installed engine; installed: ", "threejs"]),
    ("prompt.frames=[0,10]", ["prompt.frames=[0, 10] is out of range: each item must be ≥ 1"]),
    ("prompt.frames=[]", ["prompt.frames=[] needs at least 1 item"]),
    ("prompt.frames=10", ["prompt.frames=10 must be a list, e.g. prompt.frames=[1,10]"]),
    ("run.seed=-1", ["run.seed=-1 is out of range: must be ≥ 0"]),
    ("dataset.seed=-3", ["dataset.seed=-3 is out of range: must be ≥ 0"]),
    ("run.retry=maybe", ["run.retry=maybe is not a valid boolean; valid: true, false"]),
    ("sandbox.allow_unisolated=yes_please",
     ["sandbox.allow_unisolated=yes_please is not a valid boolean"]),
    ("tracking.uri=sqlte:///runs.db",
     ["tracking.uri=sqlte:///runs.db has an unknown scheme 'sqlte'; valid: a local path or ",
      "sqlite:"]),
    ("tracking.uri=sqlite://runs.db", ["tracking.uri=sqlite://runs.db is not a sqlite URI"]),
    ("tracking.uri=http://", ["tracking.uri=http:// names no host"]),
    ("dataset=original dataset.root=/nonexistent",
     ["dataset.root=/nonexistent is not a directory"]),
    ("dataset.root=/nonexistent",   # the generated benchmark has no root: not silently ignored
     ["dataset.root=/nonexistent is not used by the generated VisPhyBench", "paths.data_dir"]),
    ("model=replay", ["model.source must be set (model=replay leaves it open): add "
                      "model.source=<value>"]),
    ("prompt.forecast_only=true prompt.frames=[1,10]",
     ["prompt.forecast_only=true shows only the first of prompt.frames=[1, 10] (frame 1)"]),
    ("tracking=mlfow", ["tracking=mlfow is not an option of 'tracking'; valid: mlflow, none"]),
    ("engine=threejz", ["engine=threejz is not an option of 'engine'; valid: ", "threejs"]),
    ("engine.timout_s=3", ["unknown key 'engine.timout_s'; valid keys of 'engine': name, "
                           "timeout_s"]),
    ("+engine.timout_s=3", ["unknown key 'engine.timout_s'; valid keys of 'engine': name, "
                            "timeout_s"]),
    ("engine=blender engine.sample=3", ["unknown key 'engine.sample'; valid keys of 'engine': ",
                                        "samples"]),
    ("bogus=1", ["unknown key 'bogus'; valid top-level keys: ", "sandbox"]),
    ("engine.timeout_s=[", ["cannot parse the override 'engine.timeout_s=['"]),
    ("-m engine.timeout_s=10,-5", ["engine.timeout_s=-5 is out of range: must be ≥ 1"]),
    ("-m run.seed=range(-1,2)", ["run.seed=-1 is out of range: must be ≥ 0"]),
    ("-m engine=threejs,p5 metrics.names=[psnr],[psnrr]",
     ["psnrr is not an installed metric"]),
    ("-m engine=threejs,blender engine.timeout_s=0.5",
     ["engine.timeout_s=0.5 is out of range: must be ≥ 1"]),
]


def _assert_one_line(proc, fragments: list[str]) -> str:
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-3000:])
    assert "Traceback" not in proc.stderr and "Traceback" not in proc.stdout
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, proc.stderr[-3000:]
    line = lines[0]
    assert line.startswith("error: ")
    for fragment in fragments:
        assert fragment in line, (fragment, line)
    return line


@pytest.mark.parametrize("args, fragments", BAD_INPUTS,
                         ids=[c[0] for c in BAD_INPUTS])
def test_bad_input_is_one_line_exit_2_before_any_work(args, fragments, tmp_path):
    home = tmp_path / "home"
    proc = run_cli(*shlex.split(args), home=home, check=False, timeout=120)
    line = _assert_one_line(proc, fragments)
    assert not home.exists(), f"{args}: something was written before the error ({line})"
    _record(args, line)


# ------------------------------------------------------------------------ errors of the run


def _original_layout(root, videos: list[str]):
    (root / "sub" / "videos").mkdir(parents=True)
    for sid in videos:
        (root / "sub" / "videos" / f"{sid}.mp4").write_bytes(b"not read before selection")
    return root


RUNTIME_INPUTS = [
    # (name, overrides given the tmp dir, fragments); raised once the run has started
    ("unknown-scene-id-original",
     lambda d: ["dataset=original", f"dataset.root={_original_layout(d / 'o', ['task00001_001'])}",
                "dataset.scenes=[nope]", "tracking=none"],
     ["has no scene(s) nope"]),
    ("empty-selection",
     lambda d: ["dataset=original", f"dataset.root={_original_layout(d / 'o', [])}",
                "tracking=none"],
     ["selected no scenes"]),
    ("missing-videos-folder",
     lambda d: ["dataset=original",
                f"dataset.root={(d / 'o' / 'sub').mkdir(parents=True) or d / 'o'}",
                "tracking=none"],
     ["missing videos folder"]),
    ("missing-split-folder",
     lambda d: ["dataset=original", f"dataset.root={_original_layout(d / 'o', [])}",
                "dataset.split=test", "tracking=none"],
     ["dataset.split=test: no folder ", "folders in dataset.root: sub"]),
]


@pytest.mark.parametrize("name, make_args, fragments", RUNTIME_INPUTS,
                         ids=[c[0] for c in RUNTIME_INPUTS])
def test_dataset_errors_of_the_run_are_one_line(name, make_args, fragments, tmp_path):
    home = tmp_path / "home"
    args = make_args(tmp_path)
    proc = run_cli(*args, home=home, check=False, timeout=120)
    line = _assert_one_line(proc, fragments)
    assert not (home / "runs").exists()
    _record(f"{' '.join(a.replace(str(tmp_path), '$TMP') for a in args)}  ({name})",
            line.replace(str(tmp_path), "$TMP"))


def test_scene_ids_and_split_are_checked_against_a_built_catalogue(tmp_path):
    """With the generated benchmark's catalogue on disk, unknown ids fail before the run."""
    from visphy_plugins.datasets.visphybench.build import BUILDER_VERSION, dataset_root

    home = tmp_path / "home"
    root = dataset_root(home / "data", 0)
    root.mkdir(parents=True)
    catalogue = {"builder": BUILDER_VERSION, "seed": 0, "rejected": {},
                 "splits": {"mini": ["vpb3-s0-2d-t001-v00", "vpb3-s0-2d-t002-v00"], "sub": []},
                 "scenes": [{"spec": {"scene_id": s}, "digest": "", "attempts": 1,
                             "rejected": 0} for s in ("vpb3-s0-2d-t001-v00",
                                                      "vpb3-s0-2d-t002-v00")]}
    (root / "catalogue.json").write_text(json.dumps(catalogue))
    before = sorted(p.relative_to(home) for p in home.rglob("*"))
    proc = run_cli("dataset.scenes=[nope]", "tracking=none", home=home, check=False)
    line = _assert_one_line(proc, ["dataset.scenes: split 'mini' has no scene(s) nope; valid: "
                                   "vpb3-s0-2d-t001-v00, vpb3-s0-2d-t002-v00"])
    _record("dataset.scenes=[nope]  (catalogue built)", line)
    proc = run_cli("dataset.split=mni", "tracking=none", home=home, check=False)
    line = _assert_one_line(proc, ["dataset.split=mni is not a split of the generated "
                                   "benchmark; valid: mini, sub"])
    _record("dataset.split=mni  (catalogue built)", line)
    assert sorted(p.relative_to(home) for p in home.rglob("*")) == before


def test_scene_ids_are_checked_against_the_shipped_catalogue_on_a_fresh_home(tmp_path):
    """No catalogue on disk: the one shipped with visphy says which ids exist, before anything
    is written."""
    home = tmp_path / "fresh"
    proc = run_cli("dataset=visphybench", "dataset.scenes=[vpb3-s0-2d-t001-v00,nope]",
                   "tracking=none", home=home, check=False)
    line = _assert_one_line(proc, ["dataset.scenes: split 'sub' has no scene(s) nope; valid: "
                                   "vpb3-s0-2d-t001-v00, "])
    _record("dataset.scenes=[…,nope]  (fresh home)", line)
    assert not home.exists()


def test_a_plugin_that_fails_to_load_is_one_line(tmp_path):
    site = tmp_path / "site"
    dist = site / "visphy_broken_plugin-0.1.dist-info"
    dist.mkdir(parents=True)
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: visphy-broken-plugin\n"
                                   "Version: 0.1\n")
    (dist / "entry_points.txt").write_text("[visphy]\nbroken = visphy_no_such_module_xyz\n")
    home = tmp_path / "home"
    proc = run_cli("tracking=none", home=home, check=False, env={"PYTHONPATH": str(site)})
    line = _assert_one_line(proc, ["plugin 'broken' (visphy_no_such_module_xyz) failed to load"])
    _record("a plugin whose module does not import", line)
    assert not home.exists()


def test_traceback_flag_and_env_show_the_traceback(tmp_path):
    home = tmp_path / "home"
    for args, env in ((["--traceback", "tracking.backend=mlfow"], None),
                      (["tracking.backend=mlfow"], {"VISPHY_TRACEBACK": "1"})):
        proc = run_cli(*args, home=home, check=False, env=env)
        assert proc.returncode != 0
        assert "Traceback" in proc.stderr
        assert "ConfigError: tracking.backend=mlfow is not a valid choice" in proc.stderr


# ------------------------------------------------------------------------ in process


def test_enum_values_compare_as_strings():
    from visphy_core.config.check import compose

    cfg = compose(["tracking=none", "dataset=original"])
    assert cfg.tracking.backend == "none" and f"{cfg.tracking.backend}" == "none"
    assert cfg.dataset.source == "original" and str(cfg.dataset.source) == "original"
    assert json.dumps([cfg.dataset.source]) == '["original"]'
    assert cfg.sandbox.allow_unisolated is False
    assert compose(["sandbox.allow_unisolated=true"]).sandbox.allow_unisolated is True


def test_every_swept_value_is_checked_not_only_the_first():
    check_overrides(["engine.timeout_s=10,20,30"])
    with pytest.raises(ConfigError, match=r"engine.timeout_s=0 is out of range"):
        check_overrides(["engine.timeout_s=10,20,0"])
    with pytest.raises(ConfigError, match=r"tracking.backend=mlfow is not a valid choice"):
        check_overrides(["tracking.backend=none,mlfow"])


def test_plugin_schemas_get_the_same_range_checks():
    """A plugin schema's own metadata is read, and a redefined core field keeps its range."""
    from hydra.core.config_store import ConfigStore

    from visphy_core.api.config_schema import EngineConfig

    @dataclass
    class RangedEngineConfig(EngineConfig):
        name: str = "threejs"
        timeout_s: float = 30.0                                      # no metadata: inherited
        samples: int = field(default=4, metadata={"max": 64})

    ConfigStore.instance().store(group="engine", name="zz_test_ranged", node=RangedEngineConfig)
    check_overrides(["engine=zz_test_ranged", "engine.samples=64"])
    with pytest.raises(ConfigError, match=r"engine.samples=65 is out of range: must be ≤ 64"):
        check_overrides(["engine=zz_test_ranged", "engine.samples=65"])
    with pytest.raises(ConfigError, match=r"engine.timeout_s=0 is out of range: must be ≥ 1"):
        check_overrides(["engine=zz_test_ranged", "engine.timeout_s=0"])


def test_user_error_classification():
    from visphy_core.api.errors import UserError
    from visphy_core.api.registry import PluginError
    from visphy_core.cli.main import is_user_error
    from visphy_core.sandbox.browser import BrowserUnavailable

    assert is_user_error(ConfigError("x")) and is_user_error(UserError("x"))
    assert is_user_error(PluginError("x")) and is_user_error(BrowserUnavailable("x"))
    assert not is_user_error(RuntimeError("a bug")) and not is_user_error(KeyError("k"))
    try:
        int("not a number")  # a ValueError raised outside dataset loading is a bug
    except ValueError as exc:
        assert not is_user_error(exc)


# ------------------------------------------------------------------------ the README table

_ROWS: dict[str, str] = {}


def _record(args: str, line: str) -> None:
    _ROWS[args] = line


@pytest.fixture(scope="module", autouse=True)
def _write_table():
    """With VISPHY_ERROR_TABLE=path, write "bad input → exact message" as a Markdown table."""
    import os

    yield
    path = os.environ.get("VISPHY_ERROR_TABLE")
    if path and _ROWS:
        lines = ["| bad input | message (stderr, exit status 2) |", "|---|---|"]
        for args, line in _ROWS.items():
            lines.append(f"| `{args}` | `{line}` |")
        with open(path, "w") as fh:
            fh.write("\n".join(lines) + "\n")


def test_a_list_of_judges_is_checked_item_by_item():
    (cfg,) = check_overrides(["judge=[gemini,gpt_frames]"])
    assert sorted(cfg.judge) == ["gemini", "gpt_frames"]
    with pytest.raises(ConfigError, match=r"judge=nope is not an option of 'judge'"):
        check_overrides(["judge=[gemini,nope]"])
