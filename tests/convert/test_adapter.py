"""The env action adapter: a policy emitting ee7 (or any representation) runs via IK each step."""

from __future__ import annotations

import numpy as np
import pytest

from demo.convert import representations as reps
from demo.convert.adapter import ActionAdapter, make_adapter
from demo.convert.context import RobotContext
from demo.convert.convert import Converter
from demo.convert.kinematics import Kinematics
from demo.convert.representations import Anchor, Segments
from demo.sim import geometry as rot


@pytest.fixture(scope="module")
def recorded():
    """One expert pick episode run live: the start state, the joint_pos labels, and the env."""
    from demo.sim import make_env

    env = make_env("pick")
    env.reset(3)
    state0 = env.get_state()
    expert = env.expert(rng=np.random.default_rng(3))
    actions = []
    for _ in range(env.horizon):
        a = np.asarray(expert.act(env), dtype=np.float32)
        actions.append(a)
        env.step(a)
        if env.success() and len(actions) > 30:
            break
    assert env.success()
    robot = env.robot
    kin = Kinematics(robot.spec().compile(), robot.arm_joints, robot.ee_site, robot.base_body)
    yield env, state0, np.stack(actions), kin
    env.close()


def _convert(actions: np.ndarray, fmt: reps.ActionFormat, env, state0, kin) -> np.ndarray:
    env.set_state(state0)
    qadr = [env.model.jnt_qposadr[env.model.joint(j).id] for j in env.robot.arm_joints]
    q0 = np.array(env.data.qpos[qadr])[None]
    pos, R = kin.fk(q0)
    src = reps.make_format("joint_pos", joint_names=env.robot.arm_joints)
    ctx = RobotContext(env.robot, kin, None, None, None)
    out, _ = Converter(src, fmt, env.fps, ctx).convert(actions, Anchor(q=q0, pos=pos, rot=R), Segments.single(len(actions)))
    return out.astype(np.float32)


@pytest.mark.parametrize("name,kw", [("ee7", {}), ("ee_abs", {"rotation": "rot6d"}), ("ee_delta", {"delta_frame": "ee"}),
                                     ("joint_vel", {})])
def test_adapter_reproduces_the_commands_and_the_success(recorded, name, kw):
    env, state0, actions, kin = recorded
    fmt = reps.make_format(name, joint_names=env.robot.arm_joints, **kw)
    converted = _convert(actions, fmt, env, state0, kin)
    env.set_state(state0)
    adapter = make_adapter(fmt.spec(), env)
    assert isinstance(adapter, ActionAdapter)
    adapter.reset(env)
    sent = []
    for a in converted:
        cmd = adapter(a)
        sent.append(cmd)
        env.step(cmd)
    sent = np.stack(sent)
    assert env.success()
    p0, R0 = kin.fk(actions[:, :7])
    p1, R1 = kin.fk(sent[:, :7])
    assert np.linalg.norm(p1 - p0, axis=1).max() < 1e-4
    assert rot.angle_between(R1, R0).max() < 1e-3
    assert np.allclose(sent[:, 7], actions[:, 7])
    assert adapter.ik_failures == 0


def test_train_finds_the_adapter(recorded):
    from demo.policies.actions import make_action_adapter

    env = recorded[0]
    assert make_action_adapter(env.action_spec, env) is None  # joint_pos passes through
    adapter = make_action_adapter(reps.make_format("ee7").spec(), env)
    assert isinstance(adapter, ActionAdapter)
    out = adapter(np.zeros(7, dtype=np.float32))  # a zero delta holds the commanded pose
    qadr = [env.model.jnt_qposadr[env.model.joint(j).id] for j in env.robot.arm_joints]
    p0, R0 = adapter.kin.fk(np.array(env.data.qpos[qadr])[None])
    p1, R1 = adapter.kin.fk(out[None, :7])
    assert np.linalg.norm(p1 - p0) < 1e-5 and out.shape == (8,)
