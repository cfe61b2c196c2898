"""Box2D ground truth (`visphy_plugins.physics.box2d`): PHYRE timing and gravity, frame/step
bookkeeping, determinism, explicit per-pair contact materials, contact events."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
from mini_templates import ball, box, scene

from visphy_plugins.physics.box2d import simulate_2d, trajectory_digest


def _drop(y: float = 490.0, n_frames: int = 4, **ball_kw) -> dict:
    spec = scene(99, 0, "single ball", [ball("red_ball", "red", 10, 256, y, **ball_kw)])
    spec["world"]["n_frames"] = n_frames
    return spec


def test_free_fall_second_differences_are_58_8_px_per_frame2():
    rollout = simulate_2d(_drop())  # 3 s of flight: falls 265 px, still in the air
    y = rollout.frame_poses[:, 0, 1]
    second = y[2:] - 2 * y[1:-1] + y[:-2]
    assert np.allclose(second, -58.8, atol=0.05), second
    assert np.allclose(np.diff(rollout.frame_poses[:, 0, 0]), 0.0, atol=1e-3)


def test_horizontal_velocity_is_px_per_second():
    rollout = simulate_2d(_drop(velocity=(30.0, 0.0, 0.0)))
    assert np.allclose(np.diff(rollout.frame_poses[:, 0, 0]), 30.0, atol=0.01)


def test_frames_are_60k_plus_1_steps_and_step_poses_include_t0():
    spec = scene(99, 0, "", [ball("red_ball", "red", 10, 256, 300)])
    rollout = simulate_2d(spec)
    assert rollout.frame_steps.tolist() == [60 * k + 1 for k in range(17)]
    assert np.allclose(rollout.frame_times_s, rollout.frame_steps / 60.0)
    assert rollout.step_poses.shape == (60 * 16 + 2, 1, 3)
    assert rollout.frame_poses.shape == (17, 1, 3)
    assert np.array_equal(rollout.frame_poses, rollout.step_poses[rollout.frame_steps])
    assert np.allclose(rollout.step_poses[0, 0], [256, 300, 0], atol=1e-4)
    # after one step the ball has fallen g*dt^2 (semi-implicit Euler), not zero
    assert rollout.step_poses[1, 0, 1] - 300 == pytest.approx(-9.8 * 6 / 3600, abs=1e-4)


def test_rest_on_floor_at_bottom_edge():
    rollout = simulate_2d(_drop(y=200.0, n_frames=17))
    assert rollout.frame_poses[-1, 0, 1] == pytest.approx(10.0, abs=0.1)  # radius above y = 0
    begin = [e for e in rollout.events if e["b"] == "wall_bottom"][0]
    t = math.sqrt(2 * (190 / 6) / 9.8)
    assert begin["t_s"] == pytest.approx(t, abs=2 / 60)
    assert begin["normal_speed_m_s"] == pytest.approx(9.8 * t, rel=0.03)


def test_determinism_and_sensitivity():
    spec = _drop(n_frames=17)
    a, b = simulate_2d(spec), simulate_2d(copy.deepcopy(spec))
    assert trajectory_digest(a) == trajectory_digest(b)
    assert np.array_equal(a.step_poses, b.step_poses) and a.events == b.events
    moved = copy.deepcopy(spec)
    moved["bodies"][0]["pose"]["y_px"] += 0.5
    assert trajectory_digest(simulate_2d(moved)) != trajectory_digest(a)


def _bounce(restitution_pair: float | None, ball_restitution: float = 0.2) -> float:
    """Highest y after the first floor contact for a ball dropped from 300 px."""
    spec = _drop(y=300.0, n_frames=17)
    spec["bodies"][0]["material"]["restitution"] = ball_restitution
    spec["bodies"][0]["material"]["friction"] = 0.9
    if restitution_pair is not None:
        spec["contacts"]["pairs"] = [{"a": "red_ball", "b": "wall_bottom", "friction": 0.5,
                                      "restitution": restitution_pair}]
    rollout = simulate_2d(spec)
    first = next(e["step"] for e in rollout.events if e["b"] == "wall_bottom")
    return float(rollout.step_poses[first + 5:, 0, 1].max())


def test_contact_materials_come_from_spec_contacts_not_box2d_mixing():
    # Box2D would mix max(e1, e2) = 0.9; the spec's default contact (0.2) must win.
    assert _bounce(None, ball_restitution=0.9) == pytest.approx(_bounce(None, 0.2), abs=1e-9)
    # an explicit pair overrides the default: a lively bounce, up to ~e^2 of the drop height
    high = _bounce(0.9)
    assert high > 200 > _bounce(None) + 100


def test_sliding_box_obeys_pair_friction():
    def slide(mu: float) -> float:
        crate = box("green_box", "green", 40, 40, 100, 20.5, dynamic=True)
        crate["velocity"] = {"vx_px_s": 60.0, "vy_px_s": 0.0, "omega_rad_s": 0.0}
        spec = scene(99, 0, "", [ball("red_ball", "red", 10, 480, 300), crate])
        spec["contacts"]["pairs"] = [{"a": "green_box", "b": "wall_bottom", "friction": mu,
                                      "restitution": 0.0}]
        return float(simulate_2d(spec).frame_poses[-1, 1, 0] - 100)

    # v0 = 10 m/s, deceleration mu*g: distance v0^2 / (2 mu g) metres
    assert slide(0.5) == pytest.approx(6 * 100 / (2 * 0.5 * 9.8), rel=0.05)
    assert slide(0.25) == pytest.approx(6 * 100 / (2 * 0.25 * 9.8), rel=0.05)
