"""Every config file composes; misspelt options and keys fail at compose time in one line."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from conftest import REPO, run_cli
from visphy_core.config.check import ConfigError, check_overrides, compose

CONF = REPO / "conf"
GROUP_FILES = sorted(p for p in CONF.rglob("*.yaml") if p.name != "config.yaml")


def _override(path: Path) -> str:
    rel = path.relative_to(CONF).with_suffix("")
    return f"{rel.parent.as_posix()}={rel.name}"


def test_the_tree_has_every_required_group():
    groups = {p.relative_to(CONF).parent.as_posix() for p in GROUP_FILES}
    assert {"dataset", "model", "engine", "metrics", "judge", "tracking", "experiment",
            "hydra/launcher"} <= groups


def _missing_from(own, got, where: str) -> list[str]:
    """Where the values a config file sets (``own``) are not in the composed config (``got``);
    a file's mandatory ``???`` is not a value, and the schema may add keys beside the file's."""
    if isinstance(own, dict):
        if not isinstance(got, dict):
            return [f"{where}: {got!r} is not a mapping"]
        return [m for k, v in own.items()
                for m in (_missing_from(v, got[k], f"{where}.{k}") if k in got
                          else [f"{where}.{k}: missing"])]
    if own == "???" or own == got:
        return []
    return [f"{where}: {got!r} instead of {own!r}"]


@pytest.mark.parametrize("path", GROUP_FILES, ids=lambda p: _override(p))
def test_every_config_file_composes(path):
    override = _override(path)
    if override.startswith("hydra/"):
        check_overrides([override])  # launcher configs compose with the launcher plugins
        return
    cfg = compose([override])
    OmegaConf.to_container(cfg, resolve=True)  # every interpolation resolves
    group, option = override.split("=")
    # the option is the one composed: every value the file sets is in the config, at its package
    package = re.search(r"^# @package (\S+)", path.read_text(), re.M)
    package = package.group(1) if package else group
    node = cfg if package == "_global_" else OmegaConf.select(cfg, package)
    assert node is not None, package
    own = OmegaConf.to_container(OmegaConf.load(path), resolve=False)
    defaults = own.pop("defaults", None) or []
    own.pop("hydra", None)  # the launcher's settings: not part of the job's config
    composed = OmegaConf.to_container(node, resolve=False)
    assert _missing_from(own, composed, package) == []
    if not own and package != "_global_":  # judge=none sets nothing: no judge is selected
        assert composed == {}, (override, node)
    # an experiment's `override /group: option` selects that option (its values, where the
    # experiment sets none of its own)
    for entry in defaults:
        for key, choice in (entry.items() if isinstance(entry, dict) else ()):
            if not key.startswith("override /") or not isinstance(choice, str):
                continue
            other = key.removeprefix("override /")
            theirs = OmegaConf.to_container(OmegaConf.load(CONF / other / f"{choice}.yaml"),
                                            resolve=False)
            theirs = {k: v for k, v in theirs.items()
                      if k != "defaults" and k not in (own.get(other) or {})}
            assert _missing_from(theirs, composed[other], other) == [], (key, choice)


def test_default_config_values():
    cfg = compose([])
    assert cfg.model.name == "oracle" and cfg.engine.name == "threejs"
    assert cfg.dataset.name == "mini"
    names = list(cfg.metrics.names)  # the default suite (conf/metrics/default.yaml)
    assert names[:2] == ["psnr", "ssim"]
    assert {"flow_epe_dis", "track_pos_err", "param_gravity_err", "rouge_l",
            *cfg.metrics.headline.components} <= set(names)
    assert not {"st_lpips", "fsim", "vsi", "ms_ssim", "bertscore_minilm"} & set(names)
    offline = list(compose(["metrics=appearance"]).metrics.names)  # the whole offline suite
    assert set(names) < set(offline) and {"st_lpips", "bertscore_minilm"} <= set(offline)
    full = set(compose(["metrics=full"]).metrics.names)
    assert set(offline) <= full and {"lpips", "clip_img", "raft_epe"} <= full
    assert cfg.metrics.spec_track is True and cfg.metrics.weights_dir is None
    assert list(cfg.prompt.frames) == [1, 10] and cfg.prompt.timed is False


@pytest.mark.parametrize("override, message", [
    ("engine=threejz", "engine=threejz is not an option of 'engine'; valid: "),
    ("model=orcle", "model=orcle is not an option of 'model'; valid: "),
    ("engine.timout_s=3", "unknown key 'engine.timout_s'; valid keys of 'engine': name, timeout_s"),
    ("run.retyr=false",
     "unknown key 'run.retyr'; valid keys of 'run': cache, cost_cap_usd, fallback"),
    ("bogus=1", "unknown key 'bogus'; valid top-level keys: dataset"),
    ("engine=threejs,threejz", "engine=threejz is not an option"),
])
def test_misspellings_fail_with_one_line_listing_choices(override, message):
    with pytest.raises(ConfigError) as info:
        check_overrides([override])
    text = str(info.value)
    assert message in text and "\n" not in text


def test_schema_rejects_wrong_types():
    with pytest.raises(ConfigError):
        check_overrides(["engine.timeout_s=fast"])


def test_cli_reports_a_misspelt_option_in_one_line(tmp_path):
    proc = run_cli("engine=threejz", home=tmp_path, check=False)
    assert proc.returncode == 2
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(lines) == 1
    assert lines[0].startswith("error: engine=threejz is not an option of 'engine'; valid: ")
    assert "threejs" in lines[0].split("valid: ")[1].split(", ")


def test_experiment_overrides_apply():
    cfg = compose(["experiment=smoke"])
    assert cfg.dataset.limit == 1 and cfg.run.retry is False and cfg.tracking.backend == "none"
