"""Arm models a TOML must run as they come: continuous (unlimited) joints, common on 7-DOF cobots; gripper files
sharing names with the arm's; gripper files without an angle unit; unnamed actuators; arms without actuators;
one arm of a file with several (a bimanual scene)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from demo.sim import make_env
from demo.sim.robot import config_keys, load_robot
from demo.sim.rollout import run_expert

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


GRIPPER = """<mujoco model="extra_gripper">{compiler}
  <worldbody>
    <body name="claw">
      <geom type="box" size="0.01 0.01 0.01" mass="0.05"/>
      <site name="tcp" size="0.005"/>
      <camera name="cam" pos="0 0 -0.05"/>
      <body name="jaw"><joint name="jaw_hinge" type="hinge" range="0 0.8"/><geom type="box" size="0.005 0.005 0.02" mass="0.01"/></body>
    </body>
  </worldbody>
</mujoco>
"""


def with_gripper_file(tmp_path: Path, extra: str, compiler: str = "") -> Path:
    """The built-in arm with a second gripper file attached at its flange; the file names a site ``tcp`` as
    the arm's own does."""
    (tmp_path / "claw.xml").write_text(GRIPPER.format(compiler=compiler))
    toml = (ASSETS / "panda.toml").read_text().replace('mjcf = "panda.xml"', f'mjcf = "{ASSETS / "panda.xml"}"')
    (tmp_path / "arm.toml").write_text(toml + 'gripper_mjcf = "claw.xml"\ngripper_mount = "link7"\n' + extra)
    return tmp_path / "arm.toml"


def test_a_gripper_file_gets_its_stem_as_prefix_so_names_never_clash(tmp_path: Path, one_line_error) -> None:
    """The gripper file names a site 'tcp' as the arm's does: by default its names carry 'claw/' (its file's
    stem); a TOML may write them without it; gripper_prefix = "" keeps them, and then they clash, in one line."""
    robot = load_robot(with_gripper_file(tmp_path, 'wrist_camera = "cam"\n'))  # the gripper's camera, no prefix
    assert robot.gripper_prefix == "claw/" and robot.wrist_camera == "claw/cam"
    env = make_env("reach", robot=robot)
    try:
        assert env.model.site("claw/tcp").id >= 0 and env.model.site("tcp").id >= 0  # both names, told apart
        assert env.model.body(env.model.camera("wrist").bodyid[0]).name == "claw/claw"  # renders as the wrist camera
    finally:
        env.close()
    config = with_gripper_file(tmp_path, 'gripper_prefix = ""\n')
    one_line_error(["robot", "check", str(config)], str(config), "claw.xml cannot be attached", "repeated name",
                   "gripper_prefix")
    assert "gripper_prefix" not in config_keys(robot, "panda.xml", "claw.xml")  # the default is not written into a store's record
    config = with_gripper_file(tmp_path, 'wrist_camera = "kam"\n')  # a name neither file has: both files named
    one_line_error(["robot", "check", str(config)], str(config), "wrist_camera 'kam' not found in panda.xml (with claw.xml "
                   "attached, its names prefixed 'claw/')")


def test_a_gripper_file_without_an_angle_unit_is_read_in_the_arms(tmp_path: Path) -> None:
    """Files written to be included in a radian arm declare no unit; MJCF's default (degrees) would shrink
    their ranges 57-fold. One that declares degrees keeps them."""
    for compiler, high in (("", 0.8), ('\n  <compiler angle="degree"/>', np.deg2rad(0.8))):
        robot = load_robot(with_gripper_file(tmp_path, 'gripper_prefix = "claw/"\n', compiler))
        env = make_env("reach", robot=robot)
        try:
            np.testing.assert_allclose(env.model.jnt_range[env.model.joint("claw/jaw_hinge").id], [0.0, high])
        finally:
            env.close()


def test_unnamed_actuators_are_named_after_what_they_drive(tmp_path: Path) -> None:
    """gym-aloha's scenes leave their actuators unnamed: a TOML names them by their joint or tendon."""
    xml = (ASSETS / "panda.xml").read_text()
    start = xml.index("<actuator>")
    body = xml[start:xml.index("</actuator>")]
    unnamed = body
    for name in ("actuator1", "actuator2", "actuator3", "actuator4", "actuator5", "actuator6", "actuator7", "gripper"):
        unnamed = unnamed.replace(f'name="{name}" ', "").replace(f' name="{name}"', "")
    assert 'name="' not in unnamed.split(">", 1)[1], "every actuator is unnamed now"
    (tmp_path / "unnamed.xml").write_text(xml.replace(body, unnamed))
    tendon = unnamed.split('tendon="', 1)[1].split('"', 1)[0]  # the gripper drives the fingers' tendon
    toml = (ASSETS / "panda.toml").read_text().replace('mjcf = "panda.xml"', 'mjcf = "unnamed.xml"')
    (tmp_path / "unnamed.toml").write_text(toml.replace('gripper_actuator = "gripper"', f'gripper_actuator = "{tendon}"'))
    robot = load_robot(tmp_path / "unnamed.toml")
    env = make_env("reach", robot=robot)
    try:
        assert env.model.actuator("joint1").id >= 0 and env.model.actuator(tendon).id >= 0
        assert run_expert(env, 0).success
    finally:
        env.close()


def test_robot_check_points_the_base_towards_the_targets_it_misses(tmp_path: Path) -> None:
    """The hint is computed from where the missed targets lie: behind the table, forward; past it, back."""
    from demo.errors import DemoError
    from demo.sim.robot_check import check_robot

    for base_x, way in ((-0.7, "forward (+x)"), (0.9, "back (-x)")):
        toml = (ASSETS / "panda.toml").read_text().replace('mjcf = "panda.xml"', f'mjcf = "{ASSETS / "panda.xml"}"')
        (tmp_path / "moved.toml").write_text(toml + f"base_pos = [{base_x}, 0.0, 0.0]\n")
        with pytest.raises(DemoError) as err:
            check_robot(tmp_path / "moved.toml", episodes=1, targets=3)
        message = str(err.value)
        assert f"move the base {way}" in message, message
        suggested = float(message.split("base_pos = [")[1].split(",")[0])
        assert abs(suggested) < abs(base_x)  # back towards the table


def test_an_arm_published_without_actuators_runs_with_add_actuators(tmp_path: Path, one_line_error) -> None:
    """Some packages add their arm's actuators in Python: the model has none; add_actuators = true adds PD servos."""
    xml = (ASSETS / "panda.xml").read_text()
    for i in range(1, 8):
        start = xml.index(f'<position class="panda" name="actuator{i}"')
        xml = xml[:start] + xml[xml.index("/>", start) + 2:]
    xml = xml.replace('ctrl="0 0 0 -1.57079 0 1.57079 -0.7853 0.04"', 'ctrl="0.04"')  # the keyframe: the gripper's only
    (tmp_path / "bare.xml").write_text(xml)
    toml = (ASSETS / "panda.toml").read_text().replace('mjcf = "panda.xml"', 'mjcf = "bare.xml"')
    (tmp_path / "bare.toml").write_text(toml)
    one_line_error(["robot", "check", str(tmp_path / "bare.toml")], "has no position actuator", "add_actuators = true")
    (tmp_path / "bare.toml").write_text(toml + "add_actuators = true\n")
    env = make_env("reach", robot=load_robot(tmp_path / "bare.toml"))
    try:
        assert env.model.actuator("joint1_servo").id >= 0
        assert run_expert(env, 0).success and run_expert(env, 1).success
    finally:
        env.close()
