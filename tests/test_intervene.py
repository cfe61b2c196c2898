"""``intervene``: named parameters of a scene spec changed, re-simulated, rendered side by side.

The end-to-end checks run the command on a 2D scene of the mini split (rendered once per
module, threejs reference program); the physics checks simulate edited specs directly, in 2D and
on one 3D scene of the generated catalogue (cannon-es), and measure the rollouts themselves."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import run_cli
from visphy_core.api.errors import UserError
from visphy_core.cli.intervene import intervene_command
from visphy_core.infra.video import decode_video
from visphy_core.spec.intervene import intervened_spec
from visphy_core.spec.spec_track import simulate

#: The red ball falls from rest onto a static tilted bar, bounces, rolls off (mini split).
SCENE_2D = "vpb3-s0-2d-t001-v00"
#: A red ball rolls down a ramp, flies off a table and drops into a container (3D, cannon-es).
SCENE_3D = "vpb3-s0-3d-t001-v00"
OUTPUTS = ("original.mp4", "intervened.mp4", "side_by_side.mp4", "spec.original.json",
           "spec.intervened.json", "changes.json", "effects.json", "trajectory.original.npz",
           "trajectory.intervened.npz")


@pytest.fixture(scope="module")
def home(mini_root, tmp_path_factory) -> Path:
    home = tmp_path_factory.mktemp("intervene") / "home"
    shutil.copytree(mini_root, home / "data" / mini_root.name)
    return home


@pytest.fixture(scope="module")
def doubled_gravity(home) -> tuple[Path, str]:
    out = home / "gravity_x2"
    proc = run_cli("intervene", "--scene", SCENE_2D, "--gt", "--set", "gravity=x2", "-o",
                   str(out), home=home)
    return out, proc.stdout


def _spec(mini_root: Path, scene_id: str) -> dict:
    spec = json.loads((mini_root / "specs" / f"{scene_id}.json").read_text())
    spec.pop("splits", None)
    return spec


def _spec_3d(mini_root: Path) -> dict:
    """A 3D scene's spec from the build's catalogue (the mini split renders 2D scenes only)."""
    catalogue = json.loads((mini_root / "catalogue.json").read_text())
    spec = next(s["spec"] for s in catalogue["scenes"] if s["spec"]["scene_id"] == SCENE_3D)
    spec.pop("splits", None)
    return spec


def _red_contacts(rollout, partner: str | None = None) -> list[dict]:
    return [e for e in rollout.events if "red_ball" in (e["a"], e["b"])
            and (partner is None or partner in (e["a"], e["b"]))]


# ----------------------------------------------------------------------------- end to end
@pytest.mark.browser
def test_gravity_doubled_end_to_end(doubled_gravity):
    out, stdout = doubled_gravity
    assert all((out / name).is_file() for name in OUTPUTS)
    original, info_o = decode_video(out / "original.mp4")
    intervened, info_i = decode_video(out / "intervened.mp4")
    side, info_s = decode_video(out / "side_by_side.mp4")
    n, h, w, _ = original.shape
    assert side.shape == (n, h, 2 * w, 3) and info_s.fps == info_o.fps == info_i.fps
    body = slice(40, h)  # below the labels; the halves are the two clips (one re-encode away)
    assert np.abs(side[:, body, :w - 2].astype(int) - original[:, body, :w - 2]).mean() < 1.5
    assert np.abs(side[:, body, w + 2:].astype(int) - intervened[:, body, 2:]).mean() < 1.5
    assert not np.array_equal(original, intervened)

    (change,) = json.loads((out / "changes.json").read_text())["changes"]
    assert change["parameter"] == "gravity" and change["object"] is None
    assert change["old"] == [0.0, -9.8] and change["new"] == [0.0, -19.6]
    spec = json.loads((out / "spec.intervened.json").read_text())
    assert spec["world"]["gravity_m_s2"] == [0.0, -19.6]
    assert spec["world"]["profile"] == "intervention"

    # The red ball falls from rest onto the bar: its fall time scales as 1/sqrt(g).
    effects = json.loads((out / "effects.json").read_text())
    red = effects["bodies"]["red_ball"]
    t_orig = red["first_contact_original"]["t_s"]
    t_new = red["first_contact_intervened"]["t_s"]
    assert red["first_contact_original"]["with"] == red["first_contact_intervened"]["with"]
    assert t_new < t_orig and t_new / t_orig == pytest.approx(1 / math.sqrt(2), abs=0.03)
    traj = np.load(out / "trajectory.intervened.npz")
    ids = list(traj["body_ids"])
    touching = traj["step_touching"][:, ids.index("red_ball")]
    assert int(np.argmax(touching)) * float(traj["dt_s"]) == pytest.approx(t_new, abs=1e-9)
    assert "red_ball" in stdout and "gravity: (0, -9.8) → (0, -19.6) m/s²" in stdout


@pytest.mark.browser
def test_unchanged_parameters_give_identical_frames(home, doubled_gravity, mini_root):
    """Setting parameters to the values they already have (explicit contact pairs written for
    the red ball, friction times one) changes no trajectory and no frame."""
    out = home / "no_op"
    run_cli("intervene", "--scene", SCENE_2D, "--gt", "--set", "restitution.red_ball=0.2",
            "--set", "friction=x1", "-o", str(out), home=home)
    spec = json.loads((out / "spec.intervened.json").read_text())
    assert len(spec["contacts"]["pairs"]) > len(_spec(mini_root, SCENE_2D)["contacts"]["pairs"])
    a, b = np.load(out / "trajectory.original.npz"), np.load(out / "trajectory.intervened.npz")
    assert np.array_equal(a["step_poses"], b["step_poses"])
    original, _ = decode_video(out / "original.mp4")
    intervened, _ = decode_video(out / "intervened.mp4")
    assert np.array_equal(original, intervened)
    # ... and the original is the same clip whatever the intervention (deterministic).
    assert (out / "original.mp4").read_bytes() == \
        (doubled_gravity[0] / "original.mp4").read_bytes()


def test_bad_parameter_name_exits_2_with_valid_names(home):
    proc = run_cli("intervene", "--scene", SCENE_2D, "--gt", "--set", "gravty=-20",
                   home=home, check=False)
    assert proc.returncode == 2
    (line,) = proc.stderr.strip().splitlines()
    assert "unknown parameter 'gravty'" in line
    assert "gravity, friction, restitution, mass, velocity, angular_velocity" in line


# ----------------------------------------------------------------------------- the edits
@pytest.mark.parametrize("assignment, expected", [
    ("mass.red_bal=2", "unknown object 'red_bal'; objects of scene vpb3-s0-2d-t001-v00: "
                       "red_ball, black_bar"),
    ("mass.black_bar=2", "'black_bar' is static; mass applies to dynamic bodies: red_ball"),
    ("friction=-0.5", "friction must be ≥ 0"),
    ("mass.red_ball=0", "mass must be > 0"),
    ("velocity.red_ball=3", "velocity takes 2 components"),
    ("gravity.red_ball=3", "gravity belongs to the world"),
    ("restitution.red_ball=abc", "is not a number"),
])
def test_bad_values_and_objects_are_one_line_errors(mini_root, assignment, expected):
    with pytest.raises(UserError) as err:
        intervened_spec(_spec(mini_root, SCENE_2D), [assignment])
    assert expected in str(err.value) and "\n" not in str(err.value)


def test_body_level_edits_in_si_units(mini_root):
    spec = _spec(mini_root, SCENE_2D)
    ppm = spec["world"]["units"]["px_per_m"]
    new, changes = intervened_spec(spec, ["mass.red_ball=2", "velocity.Red Ball=3,0",
                                          "friction.red_ball=0.1"])
    red = next(b for b in new["bodies"] if b["id"] == "red_ball")
    r_m = red["shape"]["radius_px"] / ppm
    assert red["material"]["density_kg_m2"] * math.pi * r_m ** 2 == pytest.approx(2.0)
    assert (red["velocity"]["vx_px_s"], red["velocity"]["vy_px_s"]) == (3 * ppm, 0.0)
    pairs = {frozenset((p["a"], p["b"])): p for p in new["contacts"]["pairs"]}
    others = [b["id"] for b in spec["bodies"] if b["id"] != "red_ball"]
    for partner in others + ["wall_bottom", "wall_left", "wall_right", "wall_top"]:
        pair = pairs[frozenset(("red_ball", partner))]
        assert pair["friction"] == 0.1 and pair["restitution"] == spec["contacts"]["default"][
            "restitution"]
    assert new["contacts"]["default"] == spec["contacts"]["default"]
    assert [c.parameter for c in changes] == ["mass", "velocity", "friction"]


def test_restitution_zero_stops_the_bounce_2d(mini_root):
    """After its first contact with the static bar the red ball is airborne again (a bounce)
    with the benchmark's restitution, never with restitution 0."""
    spec = _spec(mini_root, SCENE_2D)
    for assignments, bounces in (([], True), (["restitution=0"], False)):
        rollout = simulate(intervened_spec(spec, assignments)[0] if assignments else spec)
        first = _red_contacts(rollout)[0]
        assert first["b"] == "black_bar" or first["a"] == "black_bar"
        red = list(rollout.body_ids).index("red_ball")
        window = rollout.step_touching[first["step"]:first["step"] + 30, red]  # 0.5 s
        airborne = int((~window).sum())
        assert (airborne > 10) if bounces else (airborne == 0)


def test_gravity_and_restitution_3d(mini_root):
    """3D (cannon-es): with gravity doubled the ball reaches the container 1/sqrt(2) as late;
    with restitution 0 it lands in it once, without bouncing."""
    spec = _spec_3d(mini_root)
    base = simulate(spec)
    doubled = simulate(intervened_spec(spec, ["gravity=x2"])[0])
    flat = simulate(intervened_spec(spec, ["restitution=0"])[0])
    t0 = _red_contacts(base, "gray_container")[0]["t_s"]
    t2 = _red_contacts(doubled, "gray_container")[0]["t_s"]
    assert t2 / t0 == pytest.approx(1 / math.sqrt(2), abs=0.05)
    assert len(_red_contacts(base, "gray_container")) >= 2
    assert len(_red_contacts(flat, "gray_container")) == 1
    unchanged = simulate(intervened_spec(spec, ["friction=x1", "restitution.red_ball=x1"])[0])
    assert np.array_equal(unchanged.step_poses, base.step_poses)


@pytest.mark.browser
def test_from_a_runs_spec(home, doubled_gravity, monkeypatch):
    """``--run``: the oracle's S is the ground truth, so the intervention on it is the one on
    the ground truth, trajectory for trajectory; after a repair, the repaired reply's S; a
    scene without S is a one-line error."""
    run_cli("model=oracle", "dataset.limit=1", "tracking=none", home=home)
    (run_dir,) = (home / "runs").iterdir()
    out = home / "from_run"
    run_cli("intervene", "--scene", SCENE_2D, "--run", str(run_dir), "--set", "gravity=x2",
            "-o", str(out), home=home)
    changes = json.loads((out / "changes.json").read_text())
    assert changes["source"] == "the model's S" and changes["engine"] == "threejs"
    for name in ("original", "intervened"):
        ours = np.load(out / f"trajectory.{name}.npz")
        gt = np.load(doubled_gravity[0] / f"trajectory.{name}.npz")
        assert np.array_equal(ours["step_poses"], gt["step_poses"])
    # after a repair, the S of the kept (second) reply is the one the spec track used: here
    # the ground truth's with gravity doubled, so its trajectory is the doubled ground truth's
    scene_dir = run_dir / "scenes" / SCENE_2D
    repaired = json.loads((scene_dir / "spec.json").read_text())
    repaired["world"]["gravity_m_s2"] = [2 * g for g in repaired["world"]["gravity_m_s2"]]
    (scene_dir / "spec.attempt2.json").write_text(json.dumps(repaired))
    (scene_dir / "response.attempt2.txt").write_text(
        "Repaired.\n```json\n" + json.dumps(repaired) + "\n```\n")
    (scene_dir / "response.attempt2.json").write_text(json.dumps({"error": None}))
    rows = (run_dir / "results.jsonl").read_text().splitlines()
    rows = [json.dumps({**json.loads(r), "attempts": 2}) if SCENE_2D in r else r for r in rows]
    (run_dir / "results.jsonl").write_text("\n".join(rows) + "\n")
    out2 = home / "from_repair"
    run_cli("intervene", "--scene", SCENE_2D, "--run", str(run_dir), "--set", "gravity=x2",
            "-o", str(out2), home=home)
    ours = np.load(out2 / "trajectory.original.npz")
    gt = np.load(doubled_gravity[0] / "trajectory.intervened.npz")
    assert np.array_equal(ours["step_poses"], gt["step_poses"])
    # a repair that failed at the provider keeps the first reply's S
    (scene_dir / "response.attempt2.json").write_text(json.dumps({"error": "HTTP 500"}))
    out3 = home / "after_failed_repair"
    run_cli("intervene", "--scene", SCENE_2D, "--run", str(run_dir), "--set", "gravity=x2",
            "-o", str(out3), home=home)
    assert np.array_equal(np.load(out3 / "trajectory.original.npz")["step_poses"],
                          np.load(out / "trajectory.original.npz")["step_poses"])
    (scene_dir / "spec.json").unlink()
    monkeypatch.setenv("VISPHY_HOME", str(home))
    with pytest.raises(UserError, match="the model wrote no scene spec S"):
        intervene_command(["--scene", SCENE_2D, "--run", str(run_dir), "--set", "gravity=x2"])
