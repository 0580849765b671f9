"""The expert contract shared by every task: state feedback only, styles, deterministic choices."""

from __future__ import annotations

import numpy as np
import pytest

from demo.sim import make_env


@pytest.mark.parametrize("task,opts", [("reach", {}), ("push", {}), ("avoid", {}), ("stack", {"blocks": 2})])
def test_fresh_expert_answers_like_the_acting_one(task, opts):
    """No hidden phase: asked at any visited state, a new expert gives the acting expert's action."""
    env = make_env(task, **opts)
    env.reset(3)
    acting = env.expert(np.random.default_rng(5), vary=True)
    for t in range(min(env.horizon, 90)):
        if t % 9 == 0:
            fresh = env.expert(np.random.default_rng(5), vary=True)
            np.testing.assert_allclose(fresh.act(env), acting.act(env), atol=1e-12, err_msg=f"step {t}")
        env.step(acting.act(env))


def test_styles_are_drawn_once_and_overridable():
    env = make_env("pick")
    env.reset(0)
    a = env.expert(np.random.default_rng(1), vary=True)
    b = env.expert(np.random.default_rng(2), vary=True)
    assert a.p.approach_height != b.p.approach_height
    assert env.expert().p == env.expert().p  # the default expert is consistent
    c = env.expert(np.random.default_rng(1), vary=True, approach_height=0.07)
    assert c.p.approach_height == 0.07 and c.p.grasp_yaw == a.p.grasp_yaw
    assert env.expert(speed=2.0).p.speed == 2.0


def test_ee_target_is_the_commanded_waypoint():
    env = make_env("reach")
    env.reset(1)
    ex = env.expert()
    start = env.ee_pose()[0]
    ex.act(env)
    assert ex.ee_target.shape == (7,)
    step = np.linalg.norm(ex.ee_target[:3] - start)
    assert 0 < step <= ex.p.max_speed / env.fps + 1e-9  # one control step at the expert's speed
    assert abs(np.linalg.norm(ex.ee_target[3:]) - 1) < 1e-9


def test_aim_offset_shifts_where_the_expert_goes():
    env = make_env("reach")
    env.reset(2)
    goal, _ = env.task.goal(env)
    ex = env.expert()
    ex.aim_offset = np.array([0.0, 0.03, 0.0])
    for _ in range(60):
        env.step(ex.act(env))
    np.testing.assert_allclose(env.ee_pose()[0], goal + ex.aim_offset, atol=0.004)
