"""stack: a long-horizon task whose horizon grows with the number of blocks; the expert recovers."""

from __future__ import annotations

import numpy as np
import pytest

from demo.sim import make_env
from demo.sim.grasp import in_hand
from demo.sim.rollout import run_expert
from demo.sim.task import place_free_body


def test_horizon_grows_linearly_with_blocks():
    h = [make_env("stack", blocks=n).horizon for n in (1, 2, 3)]
    assert h[1] - h[0] == h[2] - h[1] > 0


@pytest.mark.parametrize("blocks,seed", [(1, 0), (2, 0), (2, 1)])
def test_expert_stacks(blocks, seed):
    env = make_env("stack", blocks=blocks)
    r = run_expert(env, seed)
    assert r.success
    obs = env.observe()
    pad = obs["obs.goal_pos"]
    for i, p in enumerate(obs["obs.object_pos"]):
        assert np.hypot(*(p[:2] - pad[:2])) < 0.02 and abs(p[2] - (i + 0.5) * 0.04) < 0.01
    assert obs["obs.gripper"][0] < 0.5  # released


def test_reset_spreads_cubes_apart():
    env = make_env("stack", blocks=4)
    for seed in range(5):
        obs = env.reset(seed)
        pts = np.vstack([obs["obs.object_pos"][:, :2], obs["obs.goal_pos"][None, :2]])
        d = np.linalg.norm(pts[:, None] - pts[None], axis=-1) + np.eye(len(pts))
        assert d.min() >= 0.09 - 1e-9


def test_recovers_when_the_stack_is_knocked_over():
    env = make_env("stack", blocks=2)
    task = env.task
    knocked = {}

    def knock(e, t):
        boxes = task.boxes(e)
        if not knocked and task.levels_done(e, boxes, task.goal(e)) >= 1 and e.gripper_closedness() < 0.1:
            place_free_body(e, task.joints[0], np.array([0.40, -0.22, task.size / 2]), 0.3)
            knocked["t"] = t

    r = run_expert(env, 2, perturb=knock, max_steps=2 * env.horizon)
    assert knocked and r.success and r.first_success_step > knocked["t"] + 1  # first held after a later step


def test_parks_a_cube_held_out_of_order():
    """Holding cube 1 while cube 0 is not in place: the expert puts cube 1 aside first."""
    env = make_env("stack", blocks=2)
    task = env.task
    moved = {}

    def swap(e, t):
        boxes = task.boxes(e)
        if not moved and in_hand(e, boxes[1])[1] and boxes[1].pos[2] > 0.05:
            place_free_body(e, task.joints[0], np.array([0.62, -0.2, task.size / 2]), 0.0)
            moved["t"] = t

    r = run_expert(env, 3, perturb=swap, max_steps=3 * env.horizon)
    assert moved and r.success


def test_near_field_observations() -> None:
    """object_in_ee / object_to_place: offsets saturated at NEAR; object_yaw4: the relative yaw mod 90 deg."""
    from demo.sim.geometry import quat_to_mat, yaw_of
    from demo.sim.stack import NEAR

    env = make_env("stack", blocks=2)
    task = env.task
    obs = env.reset(3)
    ee_pos, ee_quat = env.ee_pose()
    pad = obs["obs.goal_pos"]
    for i, p in enumerate(obs["obs.object_pos"].astype(float)):
        rel = quat_to_mat(ee_quat).T @ (p - ee_pos)
        np.testing.assert_allclose(obs["obs.object_in_ee"][i], NEAR * np.tanh(rel / NEAR), atol=1e-5)
        assert np.abs(obs["obs.object_to_place"][i]).max() <= NEAR
        assert abs(np.hypot(*obs["obs.object_yaw4"][i]) - 1) < 1e-5
    # A cube at its place reads zero there; turning it by 90 deg changes nothing a gripper can tell.
    place_free_body(env, task.joints[0], np.array([pad[0], pad[1], task.size / 2]), 0.4)
    env.data.qvel[:] = 0
    import mujoco

    mujoco.mj_forward(env.model, env.data)
    env._obs_cache = None
    a = env.observe()
    assert np.abs(a["obs.object_to_place"][0]).max() < 1e-3
    place_free_body(env, task.joints[0], np.array([pad[0], pad[1], task.size / 2]), 0.4 + np.pi / 2)
    mujoco.mj_forward(env.model, env.data)
    env._obs_cache = None
    b = env.observe()
    np.testing.assert_allclose(a["obs.object_yaw4"][0], b["obs.object_yaw4"][0], atol=1e-4)
    d = 4 * (0.4 - yaw_of(ee_quat))
    np.testing.assert_allclose(a["obs.object_yaw4"][0], [np.sin(d), np.cos(d)], atol=1e-3)


def test_funnel_target_is_continuous_and_converges() -> None:
    from demo.sim.grasp import FUNNEL_FAR, funnel_target

    goal = np.array([0.5, 0.0, 0.02])
    top = 0.12
    # On the axis it aims at the goal; far off the axis and low, straight up; far and clear, over at the top.
    np.testing.assert_allclose(funnel_target(np.array([0.5, 0.0, 0.08]), goal, top, 1.0, 3.0), goal)
    low_far = funnel_target(np.array([0.5 + 2 * FUNNEL_FAR, 0.0, 0.03]), goal, top, 0.0, 3.0)
    np.testing.assert_allclose(low_far, [0.5 + 2 * FUNNEL_FAR, 0.0, top])
    np.testing.assert_allclose(funnel_target(np.array([0.7, 0.1, 0.3]), goal, top, 1.0, 3.0), [0.5, 0.0, top])
    # No jumps: nearby states, nearby targets (what makes the expert imitable).
    rng = np.random.default_rng(0)
    for _ in range(200):
        p = goal + rng.uniform([-0.08, -0.08, 0.0], [0.08, 0.08, 0.12])
        lift = float(rng.uniform())
        a = funnel_target(p, goal, top, lift, 3.0, 0.1)
        b = funnel_target(p + rng.normal(0, 1e-4, 3), goal, top, min(1.0, lift + 1e-4), 3.0, 0.1)
        assert np.abs(a - b).max() < 5e-3


def test_stepwise_expert_still_available() -> None:
    """funnel = 0 restores the original over-then-down approach, which also stacks."""
    env = make_env("stack", blocks=1)
    r = run_expert(env, 0, funnel=0.0)
    assert r.success
