"""The spec track: S simulated by visphy's physics, replayed by the engine's reference program."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from conftest import run_cli
from visphy_core.spec.spec_track import SpecTrackError, merged_spec, simulate, spec_scene


def _reply_of(spec: dict) -> dict:
    """The parts of a ground-truth spec a model's S carries."""
    world = {"gravity_m_s2": list(spec["world"]["gravity_m_s2"])}
    if spec["dim"] == "2d":
        world["units"] = {"px_per_m": spec["world"]["units"]["px_per_m"]}
    return {"schema": spec["schema"], "dim": spec["dim"], "world": world,
            "bodies": copy.deepcopy(spec["bodies"]), "contacts": copy.deepcopy(spec["contacts"])}


def test_ground_truth_as_s_reproduces_the_ground_truth_trajectory(mini_scenes):
    for scene in mini_scenes[:2]:
        s_scene = spec_scene(scene, _reply_of(scene.spec))
        np.testing.assert_array_equal(s_scene.trajectory["frame_poses"],
                                      scene.trajectory["frame_poses"])
        assert s_scene.spec["world"]["profile"] == "spec-track"
        assert scene.spec["world"]["profile"] != "spec-track"  # the scene is left untouched


def test_stronger_gravity_makes_a_falling_body_fall_faster(mini_scenes):
    scene = next(s for s in mini_scenes if s.spec["ground_truth"]["identifiable"]["gravity"])
    reply = _reply_of(scene.spec)
    reply["world"]["gravity_m_s2"] = [g * 2.0 for g in reply["world"]["gravity_m_s2"]]
    gt = scene.trajectory["frame_poses"]
    heavy = spec_scene(scene, reply).trajectory["frame_poses"]
    assert heavy.shape == gt.shape
    dynamic = [i for i, b in enumerate(scene.spec["bodies"]) if b["dynamic"]]
    # y up: under doubled gravity some dynamic body is lower early in the clip
    assert any(heavy[3, i, 1] < gt[3, i, 1] - 0.5 for i in dynamic)


@pytest.mark.parametrize("break_it, why", [
    (lambda r: r.update(bodies=r["bodies"] * 40), "bodies"),
    (lambda r: r["bodies"][0].update(velocity={"vx_px_s": 1e12, "vy_px_s": 0.0,
                                               "omega_rad_s": 0.0}), "not physical"),
    (lambda r: r["contacts"]["pairs"].append({"a": "nobody", "b": r["bodies"][0]["id"],
                                             "friction": 0.1, "restitution": 0.1}),
     "unknown body id"),
    (lambda r: r["bodies"][0].update(category="triangle"), "category"),
    (lambda r: r.update(bodies="many"), "no bodies"),
    (lambda r: r["bodies"].append(copy.deepcopy(r["bodies"][0])), "duplicate"),
])
def test_an_unsimulatable_s_is_a_spec_track_error_with_the_reason(mini_scenes, break_it, why):
    scene = mini_scenes[0]
    reply = _reply_of(scene.spec)
    break_it(reply)
    with pytest.raises(SpecTrackError, match=why):
        merged_spec(scene.spec, reply)


@pytest.mark.parametrize("engine, why", [("cannon-es", "simulates 3d scenes; this spec is 2d"),
                                         ("havok", "unknown physics engine 'havok'")])
def test_the_spec_names_its_simulator_and_the_registry_judges_it(mini_scenes, engine, why):
    """The schema takes any simulator name (a plugin's dataset may name its own); a name no
    plugin registered, or one registered for the other dimension, fails when simulated."""
    from visphy_core.spec.spec2d import validate_spec

    spec = copy.deepcopy(mini_scenes[0].spec)
    spec.pop("splits", None)  # the dataset writer's addition, not part of the spec
    spec["world"]["engine"] = engine
    validate_spec(spec)
    with pytest.raises(SpecTrackError, match=why):
        simulate(spec)


def test_the_clip_contract_stays_the_ground_truths(mini_scenes):
    scene = mini_scenes[0]
    reply = _reply_of(scene.spec)
    reply["world"]["n_frames"] = 3  # not S's to set: ignored
    spec = merged_spec(scene.spec, reply)
    for key in ("n_frames", "video_fps", "dt_s", "steps_per_frame"):
        assert spec["world"][key] == scene.spec["world"][key]
    assert len(simulate(spec).frame_poses) == scene.clip.n_frames


def _reply_text(s: dict | None, program: str) -> str:
    parts = ["The ball rolls and hits the box."]
    if s is not None:
        parts.append("```json\n" + json.dumps(s) + "\n```")
    parts.append("```html\n" + program + "\n```")
    return "\n\n".join(parts)


@pytest.mark.slow
@pytest.mark.browser
def test_run_scores_s_apart_from_a_broken_program(visphy_home, mini_scenes, tmp_path):
    """A broken program with a sound S: the program falls back, the spec track still renders
    and is scored; a reply without S and one with an invalid S are counted as such."""
    scenes = mini_scenes[:3]
    replies = tmp_path / "replies"
    replies.mkdir()
    broken = "<script>throw new Error('no physics today')</script>"
    good = _reply_of(scenes[0].spec)
    good["world"]["gravity_m_s2"] = [g * 1.5 for g in good["world"]["gravity_m_s2"]]
    invalid = _reply_of(scenes[2].spec)
    del invalid["bodies"][0]["shape"]
    (replies / f"{scenes[0].scene_id}.txt").write_text(_reply_text(good, broken))
    (replies / f"{scenes[1].scene_id}.txt").write_text(_reply_text(None, broken))
    (replies / f"{scenes[2].scene_id}.txt").write_text(_reply_text(invalid, broken))
    ids = ",".join(s.scene_id for s in scenes)
    run_cli("model=replay", f"model.source={replies}", f"dataset.scenes=[{ids}]",
            "tracking=none", "run.progress=false", "metrics.names=[psnr,ssim]",
            "metrics.spec_track=true", home=visphy_home)
    run_dir = max((visphy_home / "runs").iterdir())
    rows = {r["scene_id"]: r for r in map(json.loads, (run_dir / "results.jsonl").open())}
    first, second, third = (rows[s.scene_id] for s in scenes)
    assert first["fallback"] and not first["model_success"]
    assert first["spec_track"] == "rendered"
    assert (run_dir / "scenes" / scenes[0].scene_id / "spec_video.mp4").is_file()
    # S with 1.5 g is close to the truth but not equal; the held first frame is further off
    assert first["score_spec.psnr"] is not None and first["score_spec.psnr"] < 60
    assert first["score_spec.psnr"] > first["score_psnr"]
    assert second["spec_track"] == "no_spec" and second["score_spec.psnr"] is None
    assert third["spec_track"] == "invalid_spec" and third["score_spec.psnr"] is None
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["spec_track"] == {"rendered": 1, "no_spec": 1, "invalid_spec": 1}
    spec_psnr = summary["metrics"]["spec.psnr"]
    assert spec_psnr["n_with_fallbacks"] == 1
    assert spec_psnr["mean_with_fallbacks"] == pytest.approx(first["score_spec.psnr"])
