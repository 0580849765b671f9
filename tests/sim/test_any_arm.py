"""Arm models a TOML must run as they come: here, continuous (unlimited) joints, common on 7-DOF cobots."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from demo.sim import make_env
from demo.sim.robot import load_robot

ASSETS = Path(__file__).resolve().parents[2] / "sim" / "assets"


def continuous_joint_robot(tmp_path: Path) -> Path:
    """The built-in arm with joint4 and joint6 unlimited (MuJoCo keeps an unlimited joint's range at [0, 0])."""
    xml = (ASSETS / "panda.xml").read_text()
    for joint in ("joint4", "joint6"):
        start = xml.index(f'<joint name="{joint}"')
        end = xml.index("/>", start)
        xml = xml[:start] + f'<joint name="{joint}" limited="false" range="0 0"' + xml[end:]  # as a model without a range
    (tmp_path / "cobot.xml").write_text(xml)
    toml = (ASSETS / "panda.toml").read_text().replace('name = "panda_prim"', 'name = "cobot"')
    (tmp_path / "cobot.toml").write_text(toml.replace('mjcf = "panda.xml"', 'mjcf = "cobot.xml"'))
    return tmp_path / "cobot.toml"


def test_unlimited_joints_are_not_pinned_at_zero(tmp_path: Path) -> None:
    robot = load_robot(continuous_joint_robot(tmp_path))
    env, builtin = make_env("pick", robot=robot), make_env("pick")
    try:
        ids = [env.model.joint(j).id for j in ("joint4", "joint6")]
        assert not env.model.jnt_limited[ids].any()  # the model really has continuous joints
        obs, reference = env.reset(3), builtin.reset(3)
        # Reset holds the home pose (joint4 -1.57 rad, joint6 1.57 rad), as on the built-in arm.
        np.testing.assert_allclose(obs["obs.joint_pos"], reference["obs.joint_pos"], atol=1e-6)
        assert abs(obs["obs.joint_pos"][3]) > 1.0
        expert = env.expert()
        for _ in range(env.horizon):  # the expert's IK reaches its targets: the task is done as on the built-in arm
            _, _, success, ended, _ = env.step(expert.act(env))
            if success or ended:
                break
        assert success
    finally:
        env.close()
        builtin.close()
