"""pick: the grasp-and-lift expert succeeds, decides from the state alone, and recovers."""

from __future__ import annotations

import numpy as np
import pytest

from demo.sim import make_env
from demo.sim.rollout import run_expert
from demo.sim.task import place_free_body


@pytest.fixture(scope="module")
def env():
    e = make_env("pick")
    yield e
    e.close()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_expert_picks(env, seed):
    r = run_expert(env, seed)
    assert r.success and r.first_success_step is not None and r.length < env.horizon
    assert env.observe()["obs.object_pos"][0, 2] > 0.12


def test_varied_operator_styles_succeed(env):
    for seed in (3, 4):
        assert run_expert(env, seed, rng=np.random.default_rng(seed), vary=True).success
    assert run_expert(env, 5, speed=0.6).success


def test_expert_is_a_function_of_the_state(env):
    """A fresh expert asked mid-episode answers exactly like the one that has been acting."""
    env.reset(6)
    acting = env.expert(np.random.default_rng(9), vary=True)
    for t in range(40):
        if t % 6 == 0:
            fresh = env.expert(np.random.default_rng(9), vary=True)
            np.testing.assert_allclose(fresh.act(env), acting.act(env), atol=1e-12)
        env.step(acting.act(env))


def test_recovers_when_the_cube_is_taken_from_the_hand(env):
    state = {"done": False}

    def snatch(e, t):
        cube = e.observe()["obs.object_pos"][0]
        if not state["done"] and cube[2] > 0.05:  # lifted: put it back on the table elsewhere
            place_free_body(e, e.task.joint, np.array([0.45, -0.15, e.task.half]), 0.4)
            state["done"] = True

    r = run_expert(env, 7, perturb=snatch)
    assert state["done"] and r.success


def test_recovers_from_a_pushed_arm(env):
    def shove(e, t):
        if t == 12:
            q = e.data.qpos[e.arm_qadr] + np.array([0.3, -0.2, 0.2, 0.2, -0.3, 0.2, 0.4])
            e.set_arm(q)

    assert run_expert(env, 8, perturb=shove).success
