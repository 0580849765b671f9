"""reach: the expert reaches random target poses, also after the target moves mid-episode."""

from __future__ import annotations

import numpy as np
import pytest

from demo.sim import make_env
from demo.sim.geometry import quat_angle
from demo.sim.rollout import run_expert


@pytest.fixture(scope="module")
def env():
    e = make_env("reach")
    yield e
    e.close()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_expert_reaches(env, seed):
    r = run_expert(env, seed)
    assert r.success and r.first_success_step is not None
    goal = env.observe()
    assert np.linalg.norm(goal["obs.ee_pos"] - goal["obs.goal_pos"]) < 0.01
    assert quat_angle(goal["obs.ee_quat"].astype(float), goal["obs.goal_quat"].astype(float)) < 0.1


def test_targets_vary_and_stay_reachable(env):
    goals = np.array([env.reset(s)["obs.goal_pos"] for s in range(20)])
    assert goals.std(axis=0).min() > 0.02
    assert (goals[:, 2] > 0.05).all()  # above the table


def test_recovers_when_the_target_jumps(env):
    moved = {}

    def jump(e, t):
        if t == 8:
            e.set_mocap_pose(e.task.mocap, np.array([0.45, -0.2, 0.15]), e.task.goal(e)[1])
            moved["yes"] = True

    r = run_expert(env, 4, perturb=jump, hold_success_s=0)  # ends at the first success
    assert moved and r.success and r.length == r.first_success_step > 9
    assert np.linalg.norm(env.ee_pose()[0] - np.array([0.45, -0.2, 0.15])) < 0.01


def test_arc_style_lifts_the_path(env):
    env.reset(3)
    ee, _ = env.ee_pose()
    env.set_mocap_pose(env.task.mocap, ee + np.array([0.0, -0.3, 0.0]), env.task.goal(env)[1])  # level with the EE
    heights = {}
    for arc in (0.0, 0.12):
        ex = env.expert(np.random.default_rng(0), arc=arc)
        ex.act(env)
        heights[arc] = ex.ee_target[2]
    assert heights[0.0] == pytest.approx(ee[2], abs=1e-3)
    assert heights[0.12] > ee[2] + 0.005
    assert run_expert(env, 3, arc=0.12).success
