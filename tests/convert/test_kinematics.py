"""Batched FK against MuJoCo's own site pose, for the built-in arm, another arm and odd chains."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

from demo.convert.kinematics import Kinematics
from demo.errors import DemoError
from demo.sim import geometry as rot

ARM7 = Path(__file__).parents[1] / "assets" / "convert_arm7" / "robot.toml"

# Every feature of a chain FK must handle: a base that is not the world and sits below a free joint,
# non-axis-aligned hinge axes, hinge anchors off the body origin, a slide joint, a joint reference
# (qpos0 != 0), rotated bodies, and a rotated site.
ODD_ARM = """
<mujoco>
  <worldbody>
    <body name="side" pos="1 0 0"><geom size="0.05"/></body>
    <body name="cart" pos="0.3 -0.2 0.1" quat="0.9 0.1 -0.3 0.2">
      <freejoint name="float"/>
      <geom size="0.05"/>
      <body name="base" pos="0.1 0.05 0.02" quat="0.7 0 0.7 0.1">
        <geom size="0.05"/>
        <body name="a" pos="0 0 0.2">
          <joint name="q1" axis="0.3 -0.5 0.8" pos="0.01 0.02 -0.03" ref="0.4"/>
          <geom size="0.04"/>
          <body name="b" pos="0.25 0 0" quat="0.5 0.5 -0.5 0.5">
            <joint name="q2" type="slide" axis="1 1 0" ref="-0.05"/>
            <geom size="0.04"/>
            <body name="c" pos="0 0.2 0.05" euler="0.3 0.2 0.1">
              <joint name="q3" axis="0 -1 0" pos="0 0 0.1"/>
              <joint name="q4" axis="1 0 0"/>
              <geom size="0.03"/>
              <site name="tool" pos="0.02 -0.03 0.15" euler="0.5 -0.2 1.0"/>
            </body>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


def _site_in_base(model: mujoco.MjModel, data: mujoco.MjData, site: str, base: str) -> tuple[np.ndarray, np.ndarray]:
    s, b = model.site(site).id, model.body(base).id
    Rb = data.xmat[b].reshape(3, 3)
    return Rb.T @ (data.site_xpos[s] - data.xpos[b]), Rb.T @ data.site_xmat[s].reshape(3, 3)


def test_odd_chain_matches_mujoco_site_pose():
    model = mujoco.MjModel.from_xml_string(ODD_ARM)
    kin = Kinematics(model, ["q1", "q2", "q3", "q4"], "tool", "base")
    rng = np.random.default_rng(0)
    q = rng.uniform(-3, 3, (200, 4))
    pos, R = kin.fk(q)
    data = mujoco.MjData(model)
    for i in range(len(q)):
        data.qpos[:] = model.qpos0
        data.qpos[:7] = [0.1, 0.2, 0.3, 0.6, 0.0, 0.8, 0.0]  # the free joint moves the base: irrelevant in its frame
        data.qpos[kin.qpos_adr] = q[i]
        mujoco.mj_kinematics(model, data)
        p_ref, R_ref = _site_in_base(model, data, "tool", "base")
        assert np.abs(pos[i] - p_ref).max() < 1e-13
        assert np.abs(R[i] - R_ref).max() < 1e-13
    assert max(kin.verify(q)) < 1e-13


def test_builtin_robot_fk_matches_mujoco_and_is_chunked():
    from demo.sim import load_robot

    robot = load_robot(None)
    kin = Kinematics(robot.spec().compile(), robot.arm_joints, robot.ee_site, robot.base_body)
    q = kin.random_q(10_000, np.random.default_rng(1))  # more than one 4096-frame block
    pos, R = kin.fk(q)
    ref_pos, ref_R = kin.fk_mujoco(q[::7])
    assert np.abs(pos[::7] - ref_pos).max() < 1e-13
    assert np.abs(R[::7] - ref_R).max() < 1e-13
    assert np.abs(R @ np.swapaxes(R, 1, 2) - np.eye(3)).max() < 1e-13


def test_another_robot_fk_matches_the_scene_site_pose():
    """The second robot (yawed, offset base) inside a task scene: FK == MuJoCo's site, base frame."""
    from demo.sim import load_robot, make_env

    robot = load_robot(ARM7)
    kin = Kinematics(robot.spec().compile(), robot.arm_joints, robot.ee_site, robot.base_body)
    env = make_env("reach", robot=robot)
    try:
        rng = np.random.default_rng(2)
        q = kin.random_q(50, rng)
        pos, R = kin.fk(q)
        adr = [env.model.jnt_qposadr[env.model.joint(j).id] for j in robot.arm_joints]
        for i in range(len(q)):
            env.data.qpos[adr] = q[i]
            mujoco.mj_kinematics(env.model, env.data)
            p_env, quat_env = env.ee_pose()
            assert np.abs(pos[i] - p_env).max() < 1e-12
            assert rot.angle_between(R[i], rot.quat_to_mat(quat_env)) < 1e-7  # env's quaternion path
    finally:
        env.close()


def test_chain_errors_name_the_problem():
    model = mujoco.MjModel.from_xml_string(ODD_ARM)
    with pytest.raises(DemoError, match="joint 'q4' moves the ee site but is not one of the arm joints"):
        Kinematics(model, ["q1", "q2", "q3"], "tool", "base")
    with pytest.raises(DemoError, match="ee site 'nope'"):
        Kinematics(model, ["q1"], "nope", "base")
    with pytest.raises(DemoError, match="base body 'nowhere' is not in the model"):
        Kinematics(model, ["q1"], "tool", "nowhere")
    with pytest.raises(DemoError, match="not attached below base body 'side'"):
        Kinematics(model, ["q1", "q2", "q3", "q4"], "tool", "side")
    ball = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><body name="b"><joint name="s" type="ball"/><geom size="0.1"/>'
        '<site name="t" pos="0 0 0.2"/></body></worldbody></mujoco>')
    with pytest.raises(DemoError, match="joint 's' on the ee chain must be a hinge or slide joint"):
        Kinematics(ball, ["s"], "t", "world")
