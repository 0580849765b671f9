"""push: the contact-rich pushing expert succeeds and recovers when the block is moved."""

from __future__ import annotations

import math

import numpy as np
import pytest

from demo.sim import make_env
from demo.sim.rollout import run_expert
from demo.sim.task import place_free_body


@pytest.fixture(scope="module")
def env():
    e = make_env("push")
    yield e
    e.close()


def block_goal_distance(env) -> float:
    obs = env.observe()
    b, g = obs["obs.object_pos"][0], obs["obs.goal_pos"]
    return math.hypot(b[0] - g[0], b[1] - g[1])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_expert_pushes_into_the_goal(env, seed):
    obs = env.reset(seed)
    assert 0.1 <= math.hypot(*(obs["obs.object_pos"][0, :2] - obs["obs.goal_pos"][:2])) <= 0.2 + 1e-6
    r = run_expert(env, seed, hold_success_s=None)  # to the horizon: the block stays in
    assert r.success and r.length == env.horizon
    assert block_goal_distance(env) < 0.03
    assert env.observe()["obs.gripper"][0] > 0.8  # pushed with closed fingers, never grasped


def test_block_stays_in_the_goal_until_the_horizon(env):
    r = run_expert(env, 3, hold_success_s=None)
    assert r.success and r.length == env.horizon


def test_recovers_when_the_block_is_moved(env):
    moved = {}

    def nudge(e, t):
        if not moved and block_goal_distance(e) < 0.07:  # mid-push, close to the goal
            b = e.observe()["obs.object_pos"][0]
            place_free_body(e, e.task.joint, np.array([b[0] - 0.06, b[1] + 0.08, e.task.half]), 0.7)
            moved["t"] = t

    r = run_expert(env, 4, perturb=nudge)
    assert moved and r.success and r.first_success_step > moved["t"] + 1  # first held after a later step


def test_varied_styles_succeed(env):
    assert run_expert(env, 5, rng=np.random.default_rng(5), vary=True).success
