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
    assert r.success and r.final_success
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
    assert knocked and r.success and r.first_success > knocked["t"]


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
