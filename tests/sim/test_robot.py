"""Robot configs: the built-in arm, clear errors for bad names, and a second MJCF robot."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from demo.errors import DemoError
from demo.sim import load_robot, make_env
from demo.sim.robot import ASSETS, BUILTIN_CONFIG
from demo.sim.rollout import run_expert

BUILTIN_TOML = BUILTIN_CONFIG.read_text()


def write_config(tmp_path: Path, text: str, name: str = "robot.toml") -> Path:
    p = tmp_path / name
    p.write_text(text.replace('mjcf = "panda.xml"', f'mjcf = "{ASSETS / "panda.xml"}"'))
    return p


def test_builtin_robot_loads():
    r = load_robot(None)
    assert r.name == "panda_prim" and r.n_arm == 7
    assert r.arm_joints[0] == "joint1" and r.ee_site == "tcp" and r.base_body == "link0"
    assert r.mjcf_path.is_file() and r.config_path == BUILTIN_CONFIG.resolve()
    assert r.home_qpos["joint4"] == pytest.approx(-1.57079)
    assert r.home_gripper == 0.0  # home keyframe has the gripper open
    assert load_robot(r) is r


@pytest.mark.parametrize(
    "old,new,bad",
    [
        ('"joint3"', '"joint_3"', "arm joint 'joint_3'"),
        ('ee_site = "tcp"', 'ee_site = "tool"', "ee site 'tool'"),
        ('gripper_actuator = "gripper"', 'gripper_actuator = "grip"', "gripper actuator 'grip'"),
        ('base_body = "link0"', 'base_body = "base"', "base body 'base'"),
        ('home_key = "home"', 'home_key = "ready"', "home keyframe 'ready'"),
    ],
)
def test_wrong_name_names_config_and_name(tmp_path, old, new, bad):
    cfg = write_config(tmp_path, BUILTIN_TOML.replace(old, new))
    with pytest.raises(DemoError) as e:
        load_robot(cfg)
    assert e.value.where == str(cfg.resolve()) or e.value.where == str(cfg)
    assert bad in e.value.problem


def test_bad_config_files(tmp_path):
    with pytest.raises(DemoError, match="not found"):
        load_robot(tmp_path / "missing.toml")
    with pytest.raises(DemoError, match="lacks ee_site"):
        load_robot(write_config(tmp_path, re.sub(r"ee_site = .*\n", "", BUILTIN_TOML)))
    with pytest.raises(DemoError, match="not a valid TOML"):
        load_robot(write_config(tmp_path, "name = [", "broken.toml"))
    with pytest.raises(DemoError, match="unknown robot config key"):
        load_robot(write_config(tmp_path, BUILTIN_TOML + "colour = 'red'\n", "extra.toml"))
    with pytest.raises(DemoError, match="no position actuator"):
        # finger_joint2 exists but nothing drives it directly
        load_robot(write_config(tmp_path, BUILTIN_TOML.replace('"joint7"]', '"finger_joint2"]'), "f.toml"))


def renamed_robot(tmp_path: Path, yaw: float = 0.6, offset=(0.1, -0.2, 0.05)) -> Path:
    """A copy of the built-in arm with other names, a moved and turned base, and no EE site."""
    xml = (ASSETS / "panda.xml").read_text()
    xml = re.sub(r'"joint(\d)"', r'"arm_j\1"', xml)
    xml = re.sub(r'"actuator(\d)"', r'"servo\1"', xml)
    xml = xml.replace('name="gripper"', 'name="hand_servo"').replace('key name="home"', 'key name="ready"')
    xml = re.sub(r'<site name="tcp"[^>]*/>', "", xml)
    q = f"{math.cos(yaw / 2)} 0 0 {math.sin(yaw / 2)}"
    xml = xml.replace('<body name="link0" childclass="panda">', f'<body name="base" childclass="panda" pos="{offset[0]} {offset[1]} {offset[2]}" quat="{q}">')
    (tmp_path / "other.xml").write_text(xml)
    cfg = tmp_path / "other.toml"
    cfg.write_text(
        'name = "other"\nmjcf = "other.xml"\n'
        'arm_joints = ["arm_j1", "arm_j2", "arm_j3", "arm_j4", "arm_j5", "arm_j6", "arm_j7"]\n'
        'gripper_actuator = "hand_servo"\ngripper_range = [0.04, 0.0]\n'
        'ee_site = "grasp_point"\nee_site_body = "hand"\nee_site_pos = [0, 0, 0.1034]\n'
        'base_body = "base"\nhome_key = "ready"\n'
    )
    return cfg


def test_second_robot_runs_reach_in_its_base_frame(tmp_path):
    robot = load_robot(renamed_robot(tmp_path))
    assert robot.ee_site == "grasp_point" and robot.arm_joints[0] == "arm_j1"
    other = make_env("reach", robot=robot)
    builtin = make_env("reach")
    # Same kinematics, so in the base frame everything matches although the base moved and turned.
    a, b = other.reset(5), builtin.reset(5)
    for key in ("obs.joint_pos", "obs.ee_pos", "obs.ee_quat", "obs.goal_pos", "obs.goal_quat"):
        np.testing.assert_allclose(a[key], b[key], atol=1e-4, err_msg=key)
    assert other.action_spec.names[0] == "arm_j1.target"
    for seed in (0, 1):
        r = run_expert(other, seed)
        assert r.success, f"reach with the second robot failed on seed {seed}"
