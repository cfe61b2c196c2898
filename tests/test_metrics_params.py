"""Parameter-recovery metrics (plugins/metrics/params.py) and the static program analysis
(plugins/metrics/program_params.py): exact errors from S, extraction from programs, hostile
input, and the dataset's mean ground-truth values beside the paper's."""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from visphy_core.api.metrics import LOWER, SCENE, MetricInput
from visphy_plugins.metrics import params as P
from visphy_plugins.metrics.program_params import analyse_program, eval_number, match_name

NAMES = ("param_gravity_err", "param_restitution_err", "param_friction_err",
         "param_mass_ratio_err", "param_speed_err")

# ------------------------------------------------------------------------------ fixtures
@pytest.fixture(scope="module")
def specs_dir(mini_root, tmp_path_factory) -> Path:
    """Every scene's spec of the generated benchmark, one ``<id>.json`` each as a full build
    writes ``specs/``. The session's build renders only the `mini` split, but its catalogue
    holds every scene's spec (simulated, not rendered); a rendered scene's spec file is the
    catalogue's plus the path of its trajectory, which this checks on the rendered ones."""
    catalogue = json.loads((mini_root / "catalogue.json").read_text())
    out = tmp_path_factory.mktemp("specs")
    rendered = 0
    for scene in catalogue["scenes"]:
        spec, sid = scene["spec"], scene["spec"]["scene_id"]
        spec["ground_truth"]["trajectory"] = f"trajectories/{sid}.npz"
        built = mini_root / "specs" / f"{sid}.json"
        if built.is_file():
            assert json.loads(built.read_text()) == spec, sid
            rendered += 1
        (out / f"{sid}.json").write_text(json.dumps(spec, indent=1) + "\n")
    assert rendered == len(catalogue["splits"]["mini"]) > 0
    return out


PPM, T = 6.0, 5.0  # PHYRE scale; 2D clips: 60 steps of 1/60 s per frame at 5 fps


def gt_2d() -> dict:
    return {
        "schema": "visphy-scene/1", "scene_id": "task99999_000", "dim": "2d",
        "world": {"engine": "box2d", "units": {"px_per_m": PPM, "canvas_px": [512, 512]},
                  "gravity_m_s2": [0.0, -9.8], "dt_s": 1 / 60, "steps_per_frame": 60,
                  "video_fps": 5, "n_frames": 17},
        "bodies": [
            {"id": "red_ball", "category": "circle", "dynamic": True,
             "color_rgb": [243, 79, 70], "shape": {"type": "circle", "radius_px": 12.0},
             "pose": {"x_px": 100.0, "y_px": 300.0, "angle_rad": 0.0},
             "velocity": {"vx_px_s": 60.0, "vy_px_s": 80.0, "omega_rad_s": 0.0},
             "material": {"density_kg_m2": 0.25, "friction": 0.5, "restitution": 0.2}},
            {"id": "blue_box", "category": "rectangle", "dynamic": True,
             "color_rgb": [33, 150, 243], "shape": {"type": "box", "length_px": 24.0,
                                                     "thickness_px": 24.0},
             "pose": {"x_px": 300.0, "y_px": 12.0, "angle_rad": 0.0},
             "velocity": {"vx_px_s": 0.0, "vy_px_s": 0.0, "omega_rad_s": 0.0},
             "material": {"density_kg_m2": 0.5, "friction": 0.5, "restitution": 0.2}},
            {"id": "black_bar", "category": "line", "dynamic": False,
             "color_rgb": [0, 0, 0], "shape": {"type": "box", "length_px": 200.0,
                                               "thickness_px": 10.0},
             "pose": {"x_px": 200.0, "y_px": 150.0, "angle_rad": 0.0}}],
        "contacts": {"default": {"friction": 0.5, "restitution": 0.2},
                     "pairs": [{"a": "red_ball", "b": "black_bar", "friction": 0.5,
                                "restitution": 0.4}]},
        "ground_truth": {"trajectory": None, "events": [], "identifiable": {
            "gravity": True, "initial_velocity": ["red_ball"],
            "restitution": [["red_ball", "black_bar"], ["red_ball", "wall_bottom"]],
            "friction": [["blue_box", "wall_bottom"]],
            "mass_ratio": [["red_ball", "blue_box"]]}},
    }


def gt_3d() -> dict:
    return {
        "schema": "visphy-scene/1", "scene_id": "99_tmpl_00", "dim": "3d",
        "world": {"engine": "cannon-es", "gravity_m_s2": [0.0, -9.82, 0.0], "dt_s": 1 / 60,
                  "steps_per_frame": 4, "video_fps": 15, "n_frames": 75},
        "bodies": [
            {"id": "red_ball", "category": "circle", "dynamic": True,
             "color_rgb": [243, 79, 70], "shape": {"type": "sphere", "radius_m": 0.2},
             "pose": {"position_m": [0.0, 0.2, 0.0], "quat": [0, 0, 0, 1]},
             "velocity": {"linear_m_s": [3.0, 0.0, 0.0], "angular_rad_s": [0, 0, 0]},
             "material": {"mass_kg": 1.5, "friction": 0.4, "restitution": 0.2}},
            {"id": "green_box", "category": "rectangle", "dynamic": True,
             "color_rgb": [107, 206, 187], "shape": {"type": "box", "size_m": [0.3, 0.3, 0.3]},
             "pose": {"position_m": [1.0, 0.15, 0.0], "quat": [0, 0, 0, 1]},
             "velocity": {"linear_m_s": [0.0, 0.0, 0.0], "angular_rad_s": [0, 0, 0]},
             "material": {"mass_kg": 0.5, "friction": 0.1, "restitution": 0.3}},
            {"id": "black_ramp", "category": "triangle", "dynamic": False,
             "color_rgb": [0, 0, 0], "shape": {"type": "wedge", "length_m": 1, "height_m": 0.5,
                                               "width_m": 0.5},
             "pose": {"position_m": [-1.0, 0.2, 0.0], "quat": [0, 0, 0, 1]},
             "material": {"friction": 0.4, "restitution": 0.1}}],
        "contacts": {"default": {"friction": 0.4, "restitution": 0.1},
                     "pairs": [{"a": "red_ball", "b": "green_box", "friction": 0.1,
                                "restitution": 0.2},
                               {"a": "green_box", "b": "floor", "friction": 0.05,
                                "restitution": 0.15}]},
        "ground_truth": {"trajectory": None, "events": [], "identifiable": {
            "gravity": True, "initial_velocity": ["red_ball"],
            "restitution": [["red_ball", "green_box"], ["green_box", "floor"]],
            "friction": [["green_box", "floor"]],
            "mass_ratio": [["red_ball", "green_box"]]}},
    }


GT_SPEED_2D = 100.0 / PPM  # ‖(60, 80)‖ px/s
GT_SPEED_3D = 3.0


def run_metrics(gt: dict, spec=None, program=None, language=None) -> tuple[dict, dict]:
    """The five metric values and the breakdown, through the metric classes."""
    inp = MetricInput(scene=SimpleNamespace(spec=gt), reference=np.zeros((1, 2, 2, 3), np.uint8),
                      generated=np.zeros((1, 2, 2, 3), np.uint8), spec=spec, program=program,
                      language=language)
    values = {cls.name: cls().compute(inp) for cls in P.METRICS}
    return values, inp.extra[P.EXTRA_KEY]


def nan(x) -> bool:
    return isinstance(x, float) and math.isnan(x)


# ------------------------------------------------------------------------------ contract
def test_registration_and_contract():
    got = []
    P.visphy_register_metrics(got.append)
    assert [m.name for m in got] == list(NAMES)
    for m in got:
        assert (m.family, m.kind, m.direction, m.needs) == ("physics", SCENE, LOWER,
                                                            ("spec", "program"))
        assert m.unavailable_reason() is None
        assert m.describe()["range"][0] == 0.0


# ------------------------------------------------------------------------------ S = ground truth
@pytest.mark.parametrize("make", [gt_2d, gt_3d])
def test_oracle_spec_gives_zero_errors(make):
    gt = make()
    values, rec = run_metrics(gt, spec=copy.deepcopy(gt))
    assert values == {n: 0.0 for n in NAMES}
    for p in P.PARAMS:
        assert rec[p]["status"] == "scored" and rec[p]["source"] == "spec"
    json.dumps(rec)  # the breakdown is JSON-serialisable (the lead writes it to the run dir)


@pytest.mark.parametrize("make", [gt_2d, gt_3d])
def test_unrevealed_parameters_are_nan(make):
    gt = make()
    gt["ground_truth"]["identifiable"] = {"gravity": False, "initial_velocity": [],
                                          "restitution": [], "friction": [], "mass_ratio": []}
    values, rec = run_metrics(gt, spec=copy.deepcopy(gt))
    assert all(nan(v) for v in values.values())
    assert all(rec[p]["status"] == "not_revealed" and rec[p]["err"] is None for p in P.PARAMS)


def test_oracle_on_every_dataset_spec(specs_dir):
    files = sorted(specs_dir.glob("*.json"))
    assert files
    for f in files:
        gt = json.loads(f.read_text())
        rec = P.parameter_recovery(gt, gt, None, None)
        for p in P.PARAMS:
            assert rec[p]["status"] in ("scored", "not_revealed"), (f.name, p, rec[p])
            assert rec[p]["err"] in (None, 0.0), (f.name, p)


# ------------------------------------------------------------------------------ perturbed S
def test_perturbed_spec_errors_equal_the_perturbation_2d():
    gt = gt_2d()
    s = copy.deepcopy(gt)
    s["world"]["gravity_m_s2"] = [0.0, -12.0]
    s["contacts"]["pairs"][0]["restitution"] += 0.2       # red_ball|black_bar 0.4 -> 0.6
    s["contacts"]["default"]["friction"] = 0.8            # every unlisted pair: +0.3
    s["bodies"][0]["velocity"] = {"vx_px_s": 90.0, "vy_px_s": 120.0, "omega_rad_s": 0.0}
    s["bodies"][0]["material"]["density_kg_m2"] *= 2      # mass ratio x2
    values, rec = run_metrics(gt, spec=s)
    assert values["param_gravity_err"] == pytest.approx(12.0 - 9.8)
    errs = [it["err"] for it in rec["restitution"]["items"]]
    assert errs == pytest.approx([0.2, 0.0])               # wall_bottom pair keeps the default
    assert values["param_restitution_err"] == pytest.approx(0.1)
    assert values["param_friction_err"] == pytest.approx(0.3)
    assert values["param_speed_err"] == pytest.approx(0.5 * GT_SPEED_2D)
    assert rec["speed"]["items"][0]["err_px_s"] == pytest.approx(50.0)
    assert values["param_mass_ratio_err"] == pytest.approx(math.log(2))


def test_perturbed_spec_errors_equal_the_perturbation_3d():
    gt = gt_3d()
    s = copy.deepcopy(gt)
    s["world"]["gravity_m_s2"] = [0.0, -12.0, 0.0]
    for p in s["contacts"]["pairs"]:
        p["restitution"] += 0.2
    s["bodies"][0]["velocity"]["linear_m_s"] = [4.5, 0.0, 0.0]
    values, rec = run_metrics(gt, spec=s)
    assert values["param_gravity_err"] == pytest.approx(12.0 - 9.82)
    assert values["param_restitution_err"] == pytest.approx(0.2)
    assert values["param_friction_err"] == 0.0
    assert values["param_speed_err"] == pytest.approx(0.5 * GT_SPEED_3D)
    assert values["param_mass_ratio_err"] == 0.0
    assert rec["gravity"]["model"] == pytest.approx(12.0)
    assert rec["gravity"]["gt"] == pytest.approx(9.82)


def test_model_px_per_m_is_used_for_2d_speed():
    gt = gt_2d()
    s = copy.deepcopy(gt)
    s["world"]["units"]["px_per_m"] = 12.0  # the model believes in 12 px/m: half the speed
    _, rec = run_metrics(gt, spec=s)
    item = rec["speed"]["items"][0]
    assert item["model"] == pytest.approx(100.0 / 12.0)
    assert item["err_px_s"] == 0.0
    # the mass ratio does not depend on the scale
    assert rec["mass_ratio"]["err"] == pytest.approx(0.0)


def test_bodies_matched_by_colour_and_floor_synonyms():
    gt = gt_3d()
    s = copy.deepcopy(gt)
    s["bodies"][0]["id"], s["bodies"][1]["id"] = "ball", "cube"
    s["bodies"][0]["color_rgb"] = [240, 80, 72]  # close enough
    s["contacts"]["pairs"] = [{"a": "ball", "b": "cube", "friction": 0.1, "restitution": 0.5},
                              {"a": "ground", "b": "cube", "friction": 0.05,
                               "restitution": 0.15}]
    values, rec = run_metrics(gt, spec=s)
    assert rec["_meta"]["spec_body_match"] == {"red_ball": "ball", "green_box": "cube",
                                               "black_ramp": "black_ramp"}
    assert [it["err"] for it in rec["restitution"]["items"]] == pytest.approx([0.3, 0.0])
    assert values["param_speed_err"] == 0.0 and values["param_mass_ratio_err"] == 0.0


def test_bodies_matched_by_a_paler_or_tinted_colour_but_not_another_hue():
    """S bodies renamed and drawn in the colours models write (the red ball paler and
    orange-pink (247, 151, 142), the green box 50% paler) still match by colour; a body whose
    colour is another hue (magenta for the red ball) does not, whatever its position."""
    gt = gt_3d()
    s = copy.deepcopy(gt)
    s["bodies"][0]["id"], s["bodies"][1]["id"] = "ball", "cube"
    s["bodies"][0]["color_rgb"] = [247, 151, 142]
    s["bodies"][1]["color_rgb"] = [181, 231, 221]
    _, rec = run_metrics(gt, spec=s)
    assert rec["_meta"]["spec_body_match"] == {"red_ball": "ball", "green_box": "cube",
                                               "black_ramp": "black_ramp"}
    s["bodies"][0]["color_rgb"] = [255, 0, 255]
    _, rec = run_metrics(gt, spec=s)
    assert rec["_meta"]["spec_body_match"] == {"green_box": "cube", "black_ramp": "black_ramp"}


def test_two_bodies_of_one_colour_are_told_apart_by_position():
    gt = gt_3d()
    gt["bodies"][1]["color_rgb"] = list(gt["bodies"][0]["color_rgb"])  # two red bodies...
    gt["bodies"][1]["category"] = gt["bodies"][0]["category"]  # ...of one category
    s = copy.deepcopy(gt)
    s["bodies"][0]["id"], s["bodies"][1]["id"] = "b", "a"
    s["bodies"] = [s["bodies"][1], s["bodies"][0], s["bodies"][2]]  # listed the other way
    _, rec = run_metrics(gt, spec=s)
    assert rec["_meta"]["spec_body_match"] == {"red_ball": "b", "green_box": "a",
                                               "black_ramp": "black_ramp"}


def test_spec_without_contacts_uses_the_gt_engine_mixing_rule():
    gt = gt_2d()  # Box2D: friction sqrt(a b), restitution max(a, b)
    s = copy.deepcopy(gt)
    del s["contacts"]
    s["bodies"][0]["material"].update(friction=0.4, restitution=0.3)
    s["bodies"][1]["material"].update(friction=0.9, restitution=0.7)
    s["bodies"][2]["material"] = {"density_kg_m2": 1.0, "friction": 0.1, "restitution": 0.5}
    _, rec = run_metrics(gt, spec=s)
    r = {tuple(it["pair"]): it for it in rec["restitution"]["items"]}
    assert r[("red_ball", "black_bar")]["model"] == pytest.approx(0.5)      # max(0.3, 0.5)
    assert r[("red_ball", "wall_bottom")]["model"] == pytest.approx(0.3)    # walls: one side
    assert rec["friction"]["items"][0]["model"] == pytest.approx(0.9)       # one side

    gt3 = gt_3d()  # cannon-es: product
    s3 = copy.deepcopy(gt3)
    del s3["contacts"]
    _, rec3 = run_metrics(gt3, spec=s3)
    r3 = {tuple(it["pair"]): it for it in rec3["restitution"]["items"]}
    assert r3[("red_ball", "green_box")]["model"] == pytest.approx(0.2 * 0.3)
    assert r3[("red_ball", "green_box")]["source"] == "spec: product of materials"


# ------------------------------------------------------------------------------ programs only
CANNON_HTML = """<!DOCTYPE html><html><body><script type="module">
import * as CANNON from 'cannon-es';
// restitution: 0.99 in a comment must not count
const world = new CANNON.World({ gravity: new CANNON.Vec3(0, -9.81, 0) });
const ballMat = new CANNON.Material('ball');
const boxMat = new CANNON.Material('box');
const floorMat = new CANNON.Material('floor');
world.addContactMaterial(new CANNON.ContactMaterial(ballMat, boxMat,
  { friction: 0.1, restitution: 0.35 }));
world.addContactMaterial(new CANNON.ContactMaterial(boxMat, floorMat,
  { friction: 0.08, restitution: 0.15 }));
const red_ball = new CANNON.Body({ mass: 2.0, material: ballMat, shape: new CANNON.Sphere(0.2) });
red_ball.position.set(0, 0.2, 0);
red_ball.velocity.set(2.4, 0, 3.2);
world.addBody(red_ball);
const greenBox = new CANNON.Body({ mass: 0.5, material: boxMat,
  shape: new CANNON.Box(new CANNON.Vec3(0.15, 0.15, 0.15)) });
world.addBody(greenBox);
const floorBody = new CANNON.Body({ mass: 0, material: floorMat, shape: new CANNON.Plane() });
world.addBody(floorBody);
function tick() { world.step(1 / 60); requestAnimationFrame(tick); }
setupRecording(document.querySelector('canvas'), 5000);
</script></body></html>"""


def test_cannon_program_extraction_3d():
    gt = gt_3d()
    values, rec = run_metrics(gt, spec=None, program=CANNON_HTML, language="html")
    assert rec["gravity"]["model"] == pytest.approx(9.81)
    assert values["param_gravity_err"] == pytest.approx(0.01)
    r = {tuple(it["pair"]): it["model"] for it in rec["restitution"]["items"]}
    assert r == pytest.approx({("red_ball", "green_box"): 0.35, ("green_box", "floor"): 0.15})
    assert values["param_restitution_err"] == pytest.approx(0.075)
    assert rec["friction"]["items"][0]["model"] == pytest.approx(0.08)
    assert values["param_friction_err"] == pytest.approx(0.03)
    assert rec["speed"]["items"][0]["model"] == pytest.approx(4.0)
    assert values["param_speed_err"] == pytest.approx(1.0)
    assert values["param_mass_ratio_err"] == pytest.approx(abs(math.log(4.0) - math.log(3.0)))
    assert all(rec[p]["source"] == "program" for p in P.PARAMS)
    assert rec["_meta"]["program_engine"] == "cannon"


def test_cannon_gravity_set_and_spec_preferred_over_program():
    prog = CANNON_HTML.replace(
        "const world = new CANNON.World({ gravity: new CANNON.Vec3(0, -9.81, 0) });",
        "const world = new CANNON.World();\nworld.gravity.set(0, -9.6, 0);")
    a = analyse_program(prog, "html")
    assert a["gravity"]["value"] == pytest.approx(9.6) and a["length_unit"] == "m"
    # S present with gravity: S wins; S without contacts/material: the program fills in
    gt = gt_3d()
    s = {"world": {"gravity_m_s2": [0, -10.0, 0]}, "bodies": []}
    _, rec = run_metrics(gt, spec=s, program=prog, language="html")
    assert rec["gravity"]["source"] == "spec" and rec["gravity"]["model"] == 10.0
    assert rec["restitution"]["source"] == "program"


P5_SI = """<script>
const g = 9.8;            // m/s^2
const PX_PER_M = 40;
let x = 2, y = 5, vx = 3, vy = 4;
const RESTITUTION = 0.35;
function draw() { const dt = deltaTime / 1000; vy -= g * dt; y += vy * dt;
  if (y < 0.3) { y = 0.3; vy = -vy * RESTITUTION; }
  circle(x * PX_PER_M, height - y * PX_PER_M, 24); }
</script>"""

P5_PX = """<script>
const g = 1470, r = 12;   // px/s^2 on the clip's clock
let pos, vel;
function setup() {
  createCanvas(512, 512); pos = createVector(100, 300); vel = createVector(90, 120); }
function draw() { const dt = deltaTime / 1000; vel.y += g * dt; pos.add(p5.Vector.mult(vel, dt));
  if (pos.y > 500) { vel.y *= -0.2; } }
</script>"""


def test_p5_integrator_si_and_pixels():
    gt = gt_2d()
    values, rec = run_metrics(gt, program=P5_SI, language="html")
    assert rec["gravity"]["model"] == pytest.approx(9.8)
    assert values["param_gravity_err"] == pytest.approx(0.0)
    assert rec["speed"]["items"][0]["model"] == pytest.approx(5.0)        # vx, vy in m/s
    assert [it["model"] for it in rec["restitution"]["items"]] == pytest.approx([0.35, 0.35])
    assert nan(values["param_mass_ratio_err"])                           # nothing stated
    assert rec["mass_ratio"]["status"] == "not_determinable"
    # pixels: converted with the ground truth's px_per_m and the clip's time scale
    values, rec = run_metrics(gt, program=P5_PX, language="html")
    assert rec["gravity"]["model"] == pytest.approx(1470 / (PPM * T * T))
    assert rec["speed"]["items"][0]["model"] == pytest.approx(150 / (PPM * T))
    # the program's own scale wins over the ground truth's
    own = P5_PX.replace("const g = 1470", "const PIXELS_PER_METER = 50;\nconst g = 490")
    _, rec = run_metrics(gt, program=own, language="html")
    assert rec["gravity"]["model"] == pytest.approx(9.8)
    # a per-frame integrator (g = 0.25 px/frame^2) is not interpretable
    values, rec = run_metrics(gt, program="<script>let g = 0.25; let vy = 0;</script>",
                              language="html")
    assert nan(values["param_gravity_err"]) and rec["gravity"]["status"] == "not_determinable"
    # a pixel program on a 3D scene has no scale to convert with
    values, _ = run_metrics(gt_3d(), program=P5_PX, language="html")
    assert nan(values["param_gravity_err"])


P5_MATTER = """<script src="https://cdn.jsdelivr.net/npm/matter-js@0.20.0/build/matter.js">
</script>
<script>
let engine, red_ball, blue_box;
function setup() {
  createCanvas(512, 512);
  engine = Matter.Engine.create();
  engine.gravity.y = 1;
  red_ball = Matter.Bodies.circle(100, 200, 12,
    { restitution: 0.5, friction: 0.1, density: 0.002 });
  blue_box = Matter.Bodies.rectangle(300, 500, 24, 24, { restitution: 0.1, friction: 0.3 });
  Matter.Body.setVelocity(red_ball, { x: 2, y: 0 });
  Matter.Composite.add(engine.world, [red_ball, blue_box]);
}
function draw() { Matter.Engine.update(engine, 1000 / 60); }
</script>"""


def test_matter_program_extraction():
    gt = gt_2d()
    values, rec = run_metrics(gt, program=P5_MATTER, language="html")
    assert rec["_meta"]["program_engine"] == "matter"
    assert rec["gravity"]["model"] == pytest.approx(1000.0 / (PPM * T * T))
    assert rec["speed"]["items"][0]["model"] == pytest.approx(120.0 / (PPM * T))
    assert [it["model"] for it in rec["restitution"]["items"]] == pytest.approx([0.5, 0.5])
    assert rec["friction"]["items"][0]["model"] == pytest.approx(0.3)
    m_red, m_blue = 0.002 * math.pi * 144, 0.001 * 576   # matter's default density 0.001
    gt_ratio = math.log((0.25 * math.pi * 144) / (0.5 * 576))
    assert values["param_mass_ratio_err"] == pytest.approx(abs(math.log(m_red / m_blue)
                                                               - gt_ratio))


MANIM_PY = '''from manim import *

GRAVITY = 9.81  # m/s^2
restitution = 0.6
FRICTION = 0.45


class GeneratedScene(Scene):
    def construct(self):
        ball = Circle(radius=0.3, color="#f34f46", fill_opacity=1).shift(UP * 2)
        self.add(ball)
        y, vy, dt = 2.0, 0.0, 1 / 30
        for _ in range(90):
            vy -= GRAVITY * dt
            y += vy * dt
            if y < -3:
                y, vy = -3, -vy * restitution
            ball.move_to([0, y, 0])
            self.wait(dt)
'''


def test_manim_python_extraction():
    gt = gt_2d()
    values, rec = run_metrics(gt, program=MANIM_PY, language="python")
    assert values["param_gravity_err"] == pytest.approx(0.01)
    r = [it["model"] for it in rec["restitution"]["items"]]
    assert r == pytest.approx([0.6, 0.6])
    assert values["param_restitution_err"] == pytest.approx((0.2 + 0.4) / 2)
    assert rec["friction"]["items"][0]["model"] == pytest.approx(0.45)
    # `y, vy, dt = 2.0, 0.0, 1 / 30`: the ball starts at rest (the clip says it moves)
    assert rec["speed"]["items"][0]["model"] == 0.0
    assert values["param_speed_err"] == pytest.approx(GT_SPEED_2D)


BLENDER_PY = '''import bpy

scene = bpy.context.scene
bpy.ops.rigidbody.world_add()
scene.gravity = (0.0, 0.0, -9.81)
bpy.ops.mesh.primitive_uv_sphere_add(radius=0.2, location=(0, 0, 1))
obj = bpy.context.active_object
obj.name = "red_ball"
bpy.ops.rigidbody.object_add()
obj.rigid_body.mass = 3.0
obj.rigid_body.friction = 0.5
obj.rigid_body.restitution = 0.4
bpy.ops.mesh.primitive_cube_add(size=0.3, location=(1, 0, 0.15))
obj = bpy.context.active_object
obj.name = "green_box"
bpy.ops.rigidbody.object_add()
rb = obj.rigid_body
rb.mass = 1.0
rb.friction = 0.2
rb.restitution = 0.5
bpy.ops.mesh.primitive_plane_add(size=20)
ground = bpy.context.active_object
bpy.ops.rigidbody.object_add()
ground.rigid_body.type = 'PASSIVE'
ground.rigid_body.friction = 0.25
ground.rigid_body.restitution = 0.6
mat = bpy.data.materials.new("red")  # colour "#ff0000" in a string is not a comment
mat.diffuse_color = (1, 0, 0, 1)
'''


def test_blender_python_extraction():
    gt = gt_3d()
    values, rec = run_metrics(gt, program=BLENDER_PY, language="python")
    assert rec["_meta"]["program_engine"] == "bpy"
    assert values["param_gravity_err"] == pytest.approx(0.01)
    assert values["param_mass_ratio_err"] == pytest.approx(abs(math.log(3.0) - math.log(3.0)))
    r = {tuple(it["pair"]): it["model"] for it in rec["restitution"]["items"]}
    assert r == pytest.approx({("red_ball", "green_box"): 0.2, ("green_box", "floor"): 0.3})
    assert rec["friction"]["items"][0]["model"] == pytest.approx(0.05)  # Bullet: product
    assert rec["friction"]["items"][0]["source"] == "program: product of body values"
    # 2D Blender in pixels (the engine asks for 1 unit = 1 px): gravity via the scale
    px = BLENDER_PY.replace("(0.0, 0.0, -9.81)", "(0.0, -1470.0, 0.0)")
    _, rec2 = run_metrics(gt_2d(), program=px, language="python")
    assert rec2["gravity"]["model"] == pytest.approx(9.8)


@pytest.mark.parametrize("program", [
    None, "", 42, b"\x00\xff", ["gravity.set(0, -9.8, 0)"], "\x00" * 1000,
    "gravity.set(0, -1e400, 0); const g = 9.8e308 * 10;",
    "world.gravity.set(" + "(" * 5000 + "1" + ")" * 5000 + ", 0, 0)",
    "const g = 10 ** 10 ** 10; restitution = 'abc'; friction = -0.5;",
    "const ball = new CANNON.Body({ mass: NaN, material: m }); ball.velocity.set(Infinity, 0, 0);",
    "Matter.Body.setVelocity(red_ball, { x: 1e300, y: 1e300 }); engine.gravity.y = 1e300;",
    "{" * 20000, "g = (" * 3000, "a" * 200_000 + "= 9.8",
    "restitution = 2e9\nfriction = 5e8\nred_ball_mass = 0\nblue_box_mass = -1",
    "import bpy\nbpy.context.scene.gravity = ('a', None, [])\nobj.rigid_body.mass = 1/0",
])
def test_garbage_programs_are_nan_never_an_exception(program):
    for make in (gt_2d, gt_3d):
        values, rec = run_metrics(make(), program=program, language="html")
        values2, _ = run_metrics(make(), program=program, language="python")
        assert all(nan(v) for v in values.values()), (program if isinstance(program, str)
                                                      else type(program), values)
        assert all(nan(v) for v in values2.values())
        json.dumps(rec)


@pytest.mark.parametrize("spec", [
    "not a dict", [], {"world": None, "bodies": "x"},
    {"world": {"gravity_m_s2": "abc", "units": {"px_per_m": -3}}, "bodies": [1, None, "a"]},
    {"world": {"gravity_m_s2": [float("nan"), 1]}, "bodies": [{"id": ["x"]}]},
    {"world": {"gravity_m_s2": [1e300, 1e300]}, "contacts": {"default": "x", "pairs": [1, {}]}},
    {"world": {"gravity_m_s2": [True, False]},
     "contacts": {"default": {"friction": -1, "restitution": float("inf")},
                  "pairs": [{"a": "red_ball", "b": "black_bar", "friction": "0.3",
                             "restitution": None}]},
     "bodies": [{"id": "red_ball", "dynamic": True, "color_rgb": "red",
                 "velocity": {"vx_px_s": float("inf"), "vy_px_s": 0, "linear_m_s": [1e99] * 3},
                 "material": {"density_kg_m2": 0, "mass_kg": -2, "friction": 1e30,
                              "restitution": -0.1}, "shape": {"type": "compound",
                                                              "parts_px": [[[0, 0]] * 100]}},
                {"id": "blue_box", "dynamic": True, "material": {"density_kg_m2": 1e300},
                 "shape": {"type": "box", "length_px": 1e300, "thickness_px": 1e300}}]},
])
def test_hostile_spec_is_nan_never_an_exception(spec):
    for make in (gt_2d, gt_3d):
        values, rec = run_metrics(make(), spec=spec)
        assert all(nan(v) for v in values.values()), (spec, values)
        json.dumps(rec)


def test_broken_ground_truth_is_nan():
    class Broken:
        @property
        def spec(self):
            raise ValueError("malformed JSON")

    inp = MetricInput(scene=Broken(), reference=np.zeros((1, 2, 2, 3), np.uint8),
                      generated=np.zeros((1, 2, 2, 3), np.uint8), spec={"world": {}})
    assert all(nan(cls().compute(inp)) for cls in P.METRICS)
    assert P.parameter_recovery({"dim": "2d", "ground_truth": "x", "bodies": 3},
                                gt_2d())["gravity"]["status"] == "not_revealed"


def test_breakdown_is_computed_once_and_reused():
    gt = gt_2d()
    inp = MetricInput(scene=SimpleNamespace(spec=gt), reference=np.zeros((1, 2, 2, 3), np.uint8),
                      generated=np.zeros((1, 2, 2, 3), np.uint8), spec=copy.deepcopy(gt))
    P.GravityError().compute(inp)
    rec = inp.extra[P.EXTRA_KEY]
    P.SpeedError().compute(inp)
    assert inp.extra[P.EXTRA_KEY] is rec
    assert set(rec) == set(P.PARAMS) | {"_meta"}
    assert rec["gravity"] | {} == rec["gravity"]
    assert {"model", "gt", "source", "err", "status", "unit", "items"} <= set(rec["gravity"])


# ------------------------------------------------------------------------------ helpers
def test_eval_number_is_safe():
    assert eval_number("-9.8 * 60") == pytest.approx(-588.0)
    assert eval_number("Math.PI / 2") == pytest.approx(math.pi / 2)
    assert eval_number("g * 2", {"g": 3.0}) == 6.0
    for bad in ("__import__('os')", "1e400", "10 ** 10 ** 10", "1/0", "x", "[1]", "True",
                "(lambda: 1)()", "9" * 500, None):
        assert eval_number(bad) is None


def test_match_name():
    ents = {"red_ball": ("red", "ball"), "green_box": ("green", "box"),
            "green_box_2": ("green", "box", "2"), "floor": ("floor",)}
    assert match_name("redBallBody", ents) == "red_ball"
    assert match_name("ballMesh", ents) == "red_ball"
    assert match_name("sphere", ents) == "red_ball"
    assert match_name("ground", ents) == "floor"
    assert match_name("box", ents) == "green_box"
    assert match_name("greenBox2", ents) == "green_box_2"
    assert match_name("purple_thing", ents) is None
    assert match_name(None, ents) is None


# ------------------------------------------------------------------------------ the GT table
def test_gt_parameter_table_synthetic():
    table = P.gt_parameter_table([gt_2d(), gt_3d(), "no/such/file.json", 17])
    assert table["all"]["n_scenes"] == 2
    assert table["all"]["gravity"]["mean"] == pytest.approx((9.8 + 9.82) / 2)
    assert table["2d"]["restitution"]["mean"] == pytest.approx((0.4 + 0.2) / 2)
    assert table["3d"]["friction"]["mean"] == pytest.approx(0.05)
    m2d = [0.25 * math.pi * 144 / PPM ** 2, 0.5 * 576 / PPM ** 2]
    assert table["2d"]["mass"]["mean"] == pytest.approx(sum(m2d) / 2)
    assert table["3d"]["mass"]["mean"] == pytest.approx(1.0)
    assert table["all"]["speed"]["mean"] == pytest.approx((GT_SPEED_2D + GT_SPEED_3D) / 2)
    assert table["paper"] == {"gravity": 9.82, "restitution": 0.15, "friction": 0.40,
                              "mass": 1.25, "speed": 2.59}
    md = P.format_gt_table(table)
    assert md.count("\n") == 6 and "| gravity |" in md


def test_gt_parameter_table_dataset(specs_dir):
    table = P.gt_parameter_table(sorted(specs_dir.glob("*.json")))
    print("\n" + P.format_gt_table(table))
    assert table["all"]["n_scenes"] == len(list(specs_dir.glob("*.json")))
    for p in P.PAPER_GT_MEANS:
        e = table["all"][p]
        assert e["n"] > 0 and e["mean"] is not None and math.isfinite(e["mean"])
    assert 3.0 < table["all"]["gravity"]["mean"] < 20.0
    assert 0.0 <= table["all"]["restitution"]["mean"] <= 1.0


def test_pair_of_a_body_missing_from_spec_falls_back_to_the_program():
    gt = gt_2d()
    s = copy.deepcopy(gt)
    s["bodies"] = [b for b in s["bodies"] if b["id"] != "black_bar"]
    s["bodies"][0]["color_rgb"] = [10, 200, 10]  # still matched by id
    prog = "<script>const ball_bar_restitution = 1; const restitution = 0.45;</script>"
    _, rec = run_metrics(gt, spec=s, program=prog, language="html")
    r = {tuple(it["pair"]): it for it in rec["restitution"]["items"]}
    assert r[("red_ball", "black_bar")]["source"].startswith("program")
    assert r[("red_ball", "black_bar")]["model"] == pytest.approx(0.45)
    assert r[("red_ball", "wall_bottom")]["source"] == "spec: contacts.default"
    assert rec["restitution"]["source"] == "mixed"
