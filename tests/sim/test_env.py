"""The environment API: features, determinism, state round trips, stepping, errors."""

from __future__ import annotations

import numpy as np
import pytest

from demo.errors import DemoError
from demo.sim import TASK_NAMES, make_env


@pytest.fixture(scope="module")
def pick():
    env = make_env("pick")
    yield env
    env.close()


def test_task_names():
    assert TASK_NAMES == ("reach", "pick", "push", "avoid", "stack", "place")


@pytest.mark.parametrize("task,opts", [("reach", {}), ("pick", {}), ("push", {}), ("avoid", {}), ("stack", {"blocks": 3})])
def test_features_describe_frames(task, opts):
    env = make_env(task, **opts)
    assert env.task_name == task and env.fps == 20.0 and env.n_substeps == 25
    assert env.model.opt.timestep == pytest.approx(0.002)
    env.reset(1)
    frame = env.frame()
    assert set(frame) == set(env.features)
    for key, spec in env.features.items():
        assert frame[key].shape == spec.shape, key
        assert frame[key].dtype == spec.np_dtype, key
    assert set(env.observe()) == {k for k in env.features if k.startswith("obs.")}
    assert env.action_spec.name == "joint_pos" and env.action_spec.dim == 8
    assert env.task_options == {**type(env.task).defaults, **opts}
    env.close()


def test_reset_is_deterministic_per_seed(pick):
    a = pick.reset(3)
    sa = pick.get_state()
    b = pick.reset(3)
    np.testing.assert_array_equal(sa, pick.get_state())
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])
    c = pick.reset(4)
    assert not np.allclose(a["obs.object_pos"], c["obs.object_pos"])
    assert not np.allclose(a["obs.joint_pos"], c["obs.joint_pos"])


def test_state_round_trip_replays_exactly(pick):
    pick.reset(2)
    expert = pick.expert()
    for _ in range(10):
        pick.step(expert.act(pick))
    state = pick.get_state()
    actions = []
    for _ in range(15):
        a = expert.act(pick)
        actions.append(a)
        pick.step(a)
    end = pick.frame()
    pick.set_state(state)
    assert pick.steps == 10
    for a in actions:
        pick.step(a)
    again = pick.frame()
    for k in end:
        np.testing.assert_array_equal(end[k], again[k], err_msg=k)


def test_step_contract(pick):
    pick.reset(0)
    hold = np.concatenate([pick.observe()["obs.joint_pos"], [0.0]])
    for t in range(pick.horizon):
        obs, reward, terminated, truncated, info = pick.step(hold)
        assert reward == 0.0 and terminated is False and info == {"success": False}
        assert truncated == (t == pick.horizon - 1)
    # holding the home pose, the arm stays put (gravity compensated, stiff servos)
    np.testing.assert_allclose(obs["obs.joint_pos"], hold[:-1], atol=2e-3)
    assert obs["obs.gripper"][0] == pytest.approx(0.0, abs=0.02)
    # step's observations are the state's: a frame built from them is the frame of that state
    given, looked_up = pick.frame(obs), pick.frame()
    assert given.keys() == looked_up.keys() and all(np.array_equal(given[k], looked_up[k]) for k in given)
    with pytest.raises(DemoError, match="expected shape"):
        pick.step(np.zeros(3))


def test_ee_pose_and_quaternion_sign(pick):
    obs = pick.reset(0)
    pos, quat = pick.ee_pose()
    np.testing.assert_allclose(obs["obs.ee_pos"], pos, atol=1e-6)
    assert obs["obs.ee_quat"][0] >= 0 and abs(np.linalg.norm(quat) - 1) < 1e-9
    # the gripper points down at home: EE z axis along -z of the base
    w, x, y, z = quat
    assert 1 - 2 * (x * x + y * y) == pytest.approx(-1.0, abs=0.01)


def test_errors():
    with pytest.raises(DemoError, match="unknown task"):
        make_env("fly")
    with pytest.raises(DemoError, match="unknown task option"):
        make_env("pick", blocks=3)
    with pytest.raises(DemoError, match="blocks must be within"):
        make_env("stack", blocks=0)
    env = make_env("reach")
    with pytest.raises(DemoError, match="unknown style option"):
        env.expert(np.random.default_rng(0), velocity=2.0)
    with pytest.raises(DemoError, match="speed must be > 0"):
        env.expert(np.random.default_rng(0), speed=0.0)
    with pytest.raises(DemoError, match="unknown camera"):
        make_env("reach", cameras=[("ceiling", 64, 64)])


def test_camera_images():
    env = make_env("pick", cameras=[("front", 64, 48), "wrist"])  # (name, width, height)
    try:
        assert env.features["obs.image_front"].shape == (48, 64, 3)
        assert env.features["obs.image_wrist"].shape == (128, 128, 3)
        obs = env.reset(0)
        img = obs["obs.image_front"]
        assert img.dtype == np.uint8 and img.shape == (48, 64, 3) and img.std() > 5
        assert obs["obs.image_wrist"].shape == (128, 128, 3)
        assert env.model.vis.quality.shadowsize == 0 and env.model.vis.quality.offsamples == 0
    finally:
        env.close()


def test_per_step_fast_paths_give_the_array_formulas(pick):
    """Gripper closedness and command as floats, finger contacts by a loop: the array formulas' numbers."""
    from demo.sim.rollout import run_expert

    env = pick
    counts = []

    def check(env, t):
        length = env.data.actuator_length[env.grip_act]
        each = (length - env._grip_len_open) / (env._grip_len_closed - env._grip_len_open)
        assert env.gripper_closedness() == float(each[0])
        c = t / 40.0
        expected_ctrl = env._grip_open + min(1.0, c) * (env._grip_closed - env._grip_open)
        assert np.array([env._gripper_ctrl(c)]).tobytes() == expected_ctrl.tobytes()
        # finger_contacts: the vectorised count it replaced
        geom = env.data.contact.geom
        body = env.model.geom_bodyid[geom]
        mask = env.task.mask
        hit1 = env._finger_mask[body[:, 0]] & mask[geom[:, 1]]
        hit2 = env._finger_mask[body[:, 1]] & mask[geom[:, 0]]
        expected = len(set(body[hit1, 0].tolist()) | set(body[hit2, 1].tolist()))
        assert env.finger_contacts(mask) == expected
        counts.append(expected)

    assert run_expert(env, 0, perturb=check).success
    assert max(counts) == 2  # the check saw the grasp
