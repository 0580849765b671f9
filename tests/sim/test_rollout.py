"""The one episode loop: when episodes end, what they record, how failures are reported."""

from __future__ import annotations

import numpy as np
import pytest

from demo.sim import make_env
from demo.sim.avoid import OBSTACLE_HALF
from demo.sim.rollout import StepCommand, rollout, run_expert


@pytest.fixture(scope="module")
def reach():
    e = make_env("reach")
    yield e
    e.close()


def test_an_episode_ends_once_success_has_held(reach):
    hold = int(round(0.5 * reach.fps))
    held = run_expert(reach, 1)
    assert held.success and held.failure is None
    assert held.length == held.first_success_step + hold < reach.horizon
    first = run_expert(reach, 1, hold_success_s=0)
    assert first.length == first.first_success_step == held.first_success_step
    to_horizon = run_expert(reach, 1, hold_success_s=None)
    assert to_horizon.length == reach.horizon and to_horizon.first_success_step == held.first_success_step
    assert run_expert(reach, 1, max_steps=5).length == 5


def test_a_recorded_frame_is_the_state_before_its_command(reach):
    ep = run_expert(reach, 2, record=True)
    T = ep.length
    assert all(len(v) == T for v in ep.data.values())
    assert {"action", "info.executed_action", "info.ee_target", "sim.state", "obs.joint_pos"} <= set(ep.data)
    reach.reset(2)
    np.testing.assert_array_equal(ep.data["sim.state"][0], reach.frame()["sim.state"])
    # Replaying the recorded commands from frame t's state reaches frame t + 1's state.
    reach.set_state(ep.data["sim.state"][T // 2])
    reach.step(ep.data["info.executed_action"][T // 2])
    np.testing.assert_allclose(reach.frame()["sim.state"], ep.data["sim.state"][T // 2 + 1], atol=1e-9)
    assert np.abs(np.linalg.norm(ep.data["info.ee_target"][:, 3:], axis=1) - 1).max() < 1e-5


def test_a_failure_is_reported_and_does_not_end_the_episode():
    env = make_env("avoid")
    env.reset(4)
    hold = np.append(env.data.qpos[env.arm_qadr], 0.0).astype(np.float32)

    def touch_then_hold(env, frame, t) -> StepCommand:
        if t == 0:  # bring the obstacle to the hand: the contact is latched
            ee = env.ee_pose()[0]
            env.set_mocap_pose(env.task.obstacle_mocap, np.array([ee[0] + 0.09, ee[1], OBSTACLE_HALF[2]]))
        return StepCommand(executed=hold, label=hold)

    ep = rollout(env, 4, touch_then_hold, reset=False, record=False)
    env.close()
    assert ep.failure == "collision" and not ep.success and ep.data == {}
    assert ep.length == env.horizon
