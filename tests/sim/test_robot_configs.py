"""Any arm from a TOML alone: attach isolation, base pose, home without a keyframe, mesh paths, the
PD layer for motor arms, gripper kinds, bad configs in one line, `demo robot check`, a third-party arm."""

from __future__ import annotations

import importlib.util
import json
import re
from pathlib import Path

import mujoco
import numpy as np
import pytest

from demo.cli.main import main
from demo.errors import DemoError
from demo.sim import load_robot, make_env
from demo.sim.actuation import PD_OMEGA, actuator_inertia
from demo.sim.arms import lists_arms
from demo.sim.robot import ASSETS, BUILTIN_CONFIG
from demo.sim.robot_check import check_robot
from demo.sim.rollout import run_expert

PANDA_XML = (ASSETS / "panda.xml").read_text()
ROBOTS = ASSETS / "robots"
ARM = [f"joint{i}" for i in range(1, 8)]


def panda_variant(tmp_path: Path, xml: str, extra: str = "", drop: tuple[str, ...] = (), name: str = "arm") -> Path:
    """A config for a variant of the built-in arm's MJCF (``xml``), ``extra`` TOML lines, keys in ``drop`` left out."""
    (tmp_path / f"{name}.xml").write_text(xml)
    keys = {
        "mjcf": f'"{name}.xml"', "arm_joints": json.dumps(ARM), "gripper_actuator": '"gripper"',
        "gripper_range": "[0.04, 0.0]", "ee_site": '"tcp"', "base_body": '"link0"', "home_key": '"home"',
    }
    text = "".join(f"{k} = {v}\n" for k, v in keys.items() if k not in drop) + extra
    cfg = tmp_path / f"{name}.toml"
    cfg.write_text(text)
    return cfg


# ---------------------------------------------------------------- attach isolation, base, home, meshes
HOSTILE = '<compiler angle="radian" autolimits="true" inertiagrouprange="4 5" inertiafromgeom="true" boundmass="0.5" boundinertia="0.1"/>'


def test_robot_compiler_options_never_reach_task_objects(tmp_path):
    # The robot file's inertiagrouprange="4 5" once made our cube massless ("mass and inertia of
    # moving bodies must be larger than mjMINVAL Element name 'cube'"); boundmass would have made it 0.5 kg.
    hostile = panda_variant(tmp_path, PANDA_XML.replace('<compiler angle="radian" autolimits="true"/>', HOSTILE))
    builtin, other = make_env("pick"), make_env("pick", robot=hostile)
    for env in (builtin, other):
        cube = env.model.body("cube").id
        assert env.model.body_mass[cube] == pytest.approx(0.08)
    np.testing.assert_array_equal(other.model.body_inertia[other.model.body("cube").id],
                                  builtin.model.body_inertia[builtin.model.body("cube").id])
    # ... while they still apply to the robot's own bodies (compiled on its own terms: radians kept).
    alone = mujoco.MjSpec.from_file(str(tmp_path / "arm.xml")).compile()
    link = other.model.body("link3").id
    assert other.model.body_mass[link] == pytest.approx(alone.body_mass[alone.body("link3").id])
    np.testing.assert_allclose(other.model.jnt_range[other.model.joint("joint4").id], [-3.0718, -0.0698])
    assert other.model.nkey == 0  # the robot's keyframes are dropped


def test_base_pose_and_home_without_keyframe(tmp_path):
    xml = re.sub(r"<keyframe>.*</keyframe>", "", PANDA_XML, flags=re.S)
    home = [0, 0, 0, -1.57079, 0, 1.57079, -0.7853]
    cfg = panda_variant(tmp_path, xml, f"home = {home}\nbase_pos = [-0.1, 0.05, 0.2]\n", drop=("home_key",))
    robot = load_robot(cfg)
    assert robot.home_key is None and robot.home_qpos["joint4"] == pytest.approx(-1.57079)
    moved, builtin = make_env("reach", robot=robot), make_env("reach")
    # The scene frame stays the table's: the arm's home EE moves by exactly base_pos.
    np.testing.assert_allclose(moved.home_ee_pos - builtin.home_ee_pos, [-0.1, 0.05, 0.2], atol=1e-9)
    assert moved.model.geom("robot_riser").size[1] == pytest.approx(0.1)  # a 20 cm riser under the base
    assert run_expert(moved, 3).success


def test_base_quat_turns_the_arm(tmp_path):
    cfg = panda_variant(tmp_path, PANDA_XML, "base_quat = [0.7071068, 0, 0, 0.7071068]\nbase_pos = [0.3, -0.3, 0]\n")
    env = make_env("reach", robot=cfg)
    x, y = (env.home_ee_pos - np.array([0.3, -0.3, 0]))[:2]
    bx, by = make_env("reach").home_ee_pos[:2]
    np.testing.assert_allclose([x, y], [-by, bx], atol=1e-6)  # turned 90 deg about z


def test_meshes_resolve_relative_to_the_robot_file(tmp_path, monkeypatch):
    (tmp_path / "robot" / "parts").mkdir(parents=True)
    verts = " ".join(f"{x} {y} {z}" for x in (-0.03, 0.03) for y in (-0.03, 0.03) for z in (0, 0.03))
    xml = PANDA_XML.replace('<compiler angle="radian" autolimits="true"/>',
                            '<compiler angle="radian" autolimits="true" meshdir="parts"/>'
                            '<asset><mesh name="puck" file="puck.msh"/></asset>')
    xml = xml.replace('<geom type="cylinder" fromto="0 0 0 0 0 0.03" size="0.11" rgba="0.3 0.3 0.32 1"/>',
                      '<geom type="mesh" mesh="puck"/>')
    _write_msh(tmp_path / "robot" / "parts" / "puck.msh", np.array(verts.split(), dtype=np.float32))
    cfg = panda_variant(tmp_path / "robot", xml)
    monkeypatch.chdir(tmp_path)  # elsewhere: paths must not depend on the working directory
    env = make_env("pick", robot=cfg)
    assert env.model.nmesh == 1 and env.model.mesh_vertnum[0] == 8


def _write_msh(path: Path, vertices: np.ndarray) -> None:
    """MuJoCo's binary mesh format: four int32 counts (vertices, normals, texcoords, faces), then data."""
    path.write_bytes(np.array([len(vertices) // 3, 0, 0, 0], dtype=np.int32).tobytes() + vertices.tobytes())


# ---------------------------------------------------------------- actuation and gripper kinds
def motor_panda(tmp_path: Path, extra: str = "") -> Path:
    """The built-in arm with torque motors (its force limits as ctrl ranges) instead of position servos."""
    xml = re.sub(r'<position class="panda" name="(actuator\d)" joint="(joint\d)"[^/]*/>',
                 r'<motor name="\1" joint="\2" ctrlrange="-87 87"/>', PANDA_XML)
    assert xml.count("<motor") == 7
    return panda_variant(tmp_path, xml, extra, name="motor_arm")


def test_motor_arm_gets_a_pd_layer_with_inertia_gains(tmp_path):
    robot = load_robot(motor_panda(tmp_path))
    env = make_env("reach", robot=robot)
    m = env.model
    a = m.actuator("actuator4").id
    data = mujoco.MjData(m)
    for j, v in robot.home_qpos.items():
        data.qpos[m.jnt_qposadr[m.joint(j).id]] = v
    mujoco.mj_forward(m, data)
    inertia = actuator_inertia(m, data, a)
    assert m.actuator_gainprm[a, 0] == pytest.approx(inertia * PD_OMEGA**2, rel=1e-6)
    assert m.actuator_biasprm[a, 2] == pytest.approx(-2 * inertia * PD_OMEGA, rel=1e-6)
    np.testing.assert_allclose(m.actuator_forcerange[a], [-87, 87])  # the motor's torque limit is kept
    np.testing.assert_allclose(m.actuator_ctrlrange[a], [-3.0718, -0.0698])  # ctrl is now a joint target
    assert all(run_expert(env, s).success for s in (0, 1))


def test_pd_gains_from_the_config(tmp_path):
    env = make_env("reach", robot=motor_panda(tmp_path, "pd_kp = 900.0\npd_kd = [60, 60, 60, 60, 20, 20, 20]\n"))
    a = env.model.actuator("actuator6").id
    assert env.model.actuator_gainprm[a, 0] == 900.0 and env.model.actuator_biasprm[a, 2] == -20.0


def test_two_finger_actuators(tmp_path):
    xml = PANDA_XML.replace(
        '<position class="panda" name="gripper" tendon="split" kp="1500" dampratio="1" ctrlrange="0 0.04" forcerange="-70 70"/>',
        '<position name="left" joint="finger_joint1" kp="1500" dampratio="1" ctrlrange="0 0.04" forcerange="-70 70"/>'
        '<position name="right" joint="finger_joint2" kp="1500" dampratio="1" ctrlrange="0 0.04" forcerange="-70 70"/>')
    xml = re.sub(r"<equality>.*</equality>", "", xml, flags=re.S).replace(' ctrl="0 0 0 -1.57079 0 1.57079 -0.7853 0.04"', "")
    cfg = panda_variant(tmp_path, xml, 'gripper_actuators = ["left", "right"]\n', drop=("gripper_actuator",))
    env = make_env("pick", robot=cfg)
    assert env.action_spec.dim == 8  # still one gripper command
    assert run_expert(env, 0).success


# ---------------------------------------------------------------- bad configs: one line, the file, the fix
BAD = [
    ("drop:gripper_actuator", "", "lacks gripper_actuator: write gripper_actuator = "),
    ("drop:home_key", "", "lacks home_key: write home_key = "),
    ('"joint3"->"joint_3"', "", "arm joint 'joint_3' not found in arm.xml; fix 'arm_joints' (it has: joint1"),
    ('<position class="panda" name="actuator5" joint="joint5" kp="2000" forcerange="-12 12"/>'
     '-><velocity name="actuator5" joint="joint5" kv="20"/>', "",
     "actuator 'actuator5' is a velocity servo, not a position actuator"),
    ('gripper_actuator = "gripper"->gripper_actuator = "actuator7"', "",
     "gripper actuator 'actuator7' cannot close the gripper: it moves link7"),
    ("gripper_range = [0.04, 0.0]->gripper_range = [0.04, -0.03]", "", "gripper_range closed value -0.03 lies outside"),
]


@pytest.mark.parametrize("change,extra,expected", BAD, ids=["missing-gripper", "missing-home", "no-joint", "velocity",
                                                           "gripper-on-arm", "gripper-range"])
def test_bad_config_is_one_line_naming_the_file_and_fix(tmp_path, one_line_error, change, extra, expected):
    drop, edits = (), []
    if change.startswith("drop:"):
        drop = (change[5:],)
    else:
        edits.append(change.split("->"))
    cfg = panda_variant(tmp_path, PANDA_XML, extra, drop=drop)
    text = cfg.read_text()
    for old, new in edits:
        if old in text:  # a config key, else the MJCF
            text = text.replace(old, new)
        else:
            assert old in PANDA_XML
            (tmp_path / "arm.xml").write_text(PANDA_XML.replace(old, new))
    cfg.write_text(text)
    with pytest.raises(DemoError) as e:
        load_robot(cfg)
    assert e.value.where == str(cfg.resolve()) and expected in e.value.problem, e.value.problem
    line = one_line_error(["robot", "check", str(cfg), "--episodes", "1"])
    assert line.startswith(f"error: {cfg.resolve()}: ") and expected in line


def test_base_pose_out_of_reach_names_base_pos(tmp_path, one_line_error):
    cfg = panda_variant(tmp_path, PANDA_XML, "base_pos = [-0.9, 0, 0]\n")
    line = one_line_error(["robot", "check", str(cfg), "--episodes", "1", "--targets", "2"])
    assert f"{cfg.resolve()}: the arm reaches" in line and "move the base forward (+x): base_pos = [" in line


def test_package_that_is_not_installed(tmp_path):
    cfg = panda_variant(tmp_path, PANDA_XML)
    cfg.write_text(cfg.read_text().replace('mjcf = "arm.xml"', 'mjcf = "pkg://no_such_robot_pkg/arm.xml"'))
    with pytest.raises(DemoError, match="Python package 'no_such_robot_pkg' is not installed"):
        load_robot(cfg)


# ---------------------------------------------------------------- demo robot check
def test_robot_check_on_the_builtin_arm(tmp_path, capsys):
    png = tmp_path / "home.png"
    capsys.readouterr()
    assert main(["robot", "check", str(BUILTIN_CONFIG), "--episodes", "2", "--targets", "2", "--png", str(png),
                 "--json", "-"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["dof"] == 7 and report["ok"] and report["joints"][3]["upper"] == pytest.approx(-0.0698)
    assert set(report["ik"]) == {"reach", "pick", "push", "avoid", "stack", "place"}
    assert all(r["rate"] == 1.0 for r in report["ik"].values()) and report["gripper_closes"] > 0.9
    assert report["experts"]["pick"] == {"successes": 2, "episodes": 2, "rate": 1.0}
    from PIL import Image

    assert Image.open(png).size == (640, 480)


# ---------------------------------------------------------------- a third-party arm, when installed
@pytest.mark.skipif(importlib.util.find_spec("trossen_arm_sim") is None,
                    reason="trossen-arm-sim is not installed (pip install --no-deps trossen-arm-sim==0.2.3 runs this arm)")
def test_third_party_six_dof_arm_from_a_toml_alone():
    report = check_robot(ROBOTS / "trossen_wxai.toml", episodes=2, targets=2)
    assert report.dof == 6 and report.ok
    assert report.experts["pick"]["successes"] == 2 and report.experts["reach"]["successes"] == 2


def _package_of(toml: Path) -> str | None:
    """The Python package a shipped config's MJCF lives in (``pkg://PACKAGE/...``), or None."""
    import tomllib

    keys = tomllib.loads(toml.read_text())
    mjcf = str(keys["mjcf"])
    return mjcf.removeprefix("pkg://").split("/", 1)[0] if mjcf.startswith("pkg://") else None


@pytest.mark.slow
@pytest.mark.parametrize("toml", [
    pytest.param(t, id=t.stem, marks=pytest.mark.skipif(
        _package_of(t) is not None and importlib.util.find_spec(_package_of(t)) is None,
        reason=f"{_package_of(t)} is not installed (docs/robots.md: pip install --no-deps ...)"))
    for t in sorted(ROBOTS.glob("*.toml")) if not lists_arms(t)])
def test_every_shipped_robot_config_passes_the_check(toml: Path) -> None:
    """The worked examples in sim/assets/robots, each arm of gym-aloha's bimanual scene among them (their pair,
    aloha_vx300s.toml, is tests/sim/test_arms.py's)."""
    report = check_robot(toml, episodes=2, targets=2)
    assert report.ok and report.experts["pick"]["successes"] == 2
