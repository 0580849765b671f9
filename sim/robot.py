"""Robot configs: what `demo` needs to know about an MJCF arm with a gripper.

A robot config is a small TOML file (paths relative to it)::

    name = "panda_prim"
    mjcf = "panda.xml"
    arm_joints = ["joint1", ..., "joint7"]     # the joints the action drives, in action order
    gripper_actuator = "gripper"              # a position-like actuator (tendon or joint)
    gripper_range = [0.04, 0.0]               # its ctrl at [open, closed]
    ee_site = "tcp"                           # end-effector site (z: approach axis, y: finger axis)
    base_body = "link0"                       # the robot base frame every pose is expressed in
    home_key = "home"                         # keyframe with the home configuration
    # optional:
    ee_site_body = "hand"                     # create `ee_site` on this body (for MJCFs without one)
    ee_site_pos = [0, 0, 0.1034]              #   ... at this pose in the body frame (m)
    ee_site_quat = [1, 0, 0, 0]               #   ... (wxyz)
    gravcomp = true                           # compensate gravity on the robot's bodies (default)
    max_joint_velocity = 2.0                  # rad/s, for the experts' IK (scalar or one per joint)
    wrist_camera = { pos = [0.05, 0, -0.05], target = [0, 0, 0.12], fovy = 80 }   # the `wrist` camera

``wrist_camera`` places the ``wrist`` camera (``demo collect --camera wrist@WxH``) on the EE site's
body, in the **EE site frame** (m): ``pos`` its position, then either ``target`` (a point it looks
at, with the site's +x up in the image) or ``quat`` (wxyz, MuJoCo camera convention: it looks along
its -z, +y up), and ``fovy`` (vertical field of view, degrees). Keys left out take the defaults
above (beside the hand, above the TCP, looking past the fingertips; ``quat`` ~ [0.1008, 0.6999,
0.6999, 0.1008]). ``wrist_camera = "NAME"`` instead renders the MJCF's own camera ``NAME`` as
``wrist``.

Each arm joint must be a hinge or slide joint driven by a position-like actuator (``ctrl`` = joint
target, e.g. MJCF ``<position>`` or Menagerie's ``<general>`` with ``biasprm="0 -kp -kv"``). The
finger bodies must be descendants of the EE site's body (the experts detect a grasp by contacts
of two such bodies with the object).
The built-in robot (``load_robot(None)``) is ``sim/assets/panda.toml``. A store records any other
robot by content: these keys, the MJCF and its asset files (see :mod:`demo.sim.robot_record`).
A MuJoCo Menagerie Panda checkout works with (its MJCF has no TCP site, so the config adds one)::

    name = "menagerie_panda"
    mjcf = "/path/to/mujoco_menagerie/franka_emika_panda/panda.xml"
    arm_joints = ["joint1", "joint2", "joint3", "joint4", "joint5", "joint6", "joint7"]
    gripper_actuator = "actuator8"
    gripper_range = [255, 0]
    ee_site = "tcp"
    ee_site_body = "hand"
    ee_site_pos = [0, 0, 0.1034]
    base_body = "link0"
    home_key = "home"
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from demo.errors import DemoError, one_line
from demo.sim.geometry import lookat_quat

ASSETS = Path(__file__).resolve().parent / "assets"
BUILTIN_CONFIG = ASSETS / "panda.toml"

_REQUIRED = ("mjcf", "arm_joints", "gripper_actuator", "gripper_range", "ee_site", "base_body", "home_key")
_HINGE_SLIDE = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
_OPTIONAL = ("name", "ee_site_body", "ee_site_pos", "ee_site_quat", "gravcomp", "max_joint_velocity", "wrist_camera")


@dataclass(frozen=True)
class WristCamera:
    """Where the ``wrist`` camera sits, in the EE site frame: ``pos`` (m), ``quat`` (wxyz, looking
    along its -z with +y up, MuJoCo's camera convention) and ``fovy`` (vertical field of view, deg)."""

    pos: tuple[float, float, float]
    quat: tuple[float, float, float, float]
    fovy: float


_WRIST_POS, _WRIST_TARGET, _WRIST_FOVY = (0.05, 0.0, -0.05), (0.0, 0.0, 0.12), 80.0
_WRIST_UP = np.array([1.0, 0.0, 0.0])  # the site's +x is "up" in the wrist image


def _looking_at(pos: tuple[float, ...], target: tuple[float, ...]) -> tuple[float, float, float, float]:
    return tuple(float(v) for v in lookat_quat(np.array(pos), np.array(target), up=_WRIST_UP))  # type: ignore[return-value]


DEFAULT_WRIST_CAMERA = WristCamera(_WRIST_POS, _looking_at(_WRIST_POS, _WRIST_TARGET), _WRIST_FOVY)


@dataclass(frozen=True)
class RobotConfig:
    """A validated robot config. ``home_qpos`` maps every robot hinge/slide joint to its home value."""

    name: str
    mjcf_path: Path
    arm_joints: tuple[str, ...]
    gripper_actuator: str
    gripper_range: tuple[float, float]
    ee_site: str
    base_body: str
    home_key: str
    config_path: Path | None = None  # the TOML file, or the store/run folder the robot's files were restored from
    ee_site_body: str | None = None
    ee_site_pos: tuple[float, float, float] = (0.0, 0.0, 0.0)
    ee_site_quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    gravcomp: bool = True
    max_joint_velocity: tuple[float, ...] = ()
    wrist_camera: WristCamera | str = DEFAULT_WRIST_CAMERA  # or the name of a camera in the MJCF
    home_qpos: dict[str, float] = field(default_factory=dict, compare=False)
    home_gripper: float = 0.0  # normalised closedness at home (0 open .. 1 closed)

    @property
    def n_arm(self) -> int:
        return len(self.arm_joints)

    def spec(self) -> mujoco.MjSpec:
        """A fresh MjSpec of the robot MJCF, with the configured EE site added if asked."""
        return robot_spec(self)


def robot_spec(robot: RobotConfig) -> mujoco.MjSpec:
    try:
        spec = mujoco.MjSpec.from_file(str(robot.mjcf_path))
    except Exception as exc:  # mujoco raises ValueError with the parser's (multi-line) message
        raise DemoError(robot.mjcf_path, f"MJCF does not load: {mujoco_message(exc)}{_named_by(robot)}") from None
    if robot.ee_site_body:
        body = spec.body(robot.ee_site_body)
        if body is None:
            raise DemoError(robot.config_path, f"ee_site_body '{robot.ee_site_body}' is not a body in {robot.mjcf_path}")
        body.add_site(name=robot.ee_site, pos=list(robot.ee_site_pos), quat=list(robot.ee_site_quat), size=[0.006, 0, 0])
    return spec


def mujoco_message(exc: BaseException) -> str:
    """MuJoCo's parser/compiler message on one line, without its ``Error:`` prefixes."""
    return one_line(str(exc).replace("Error: ", "")) or type(exc).__name__


def _named_by(robot: RobotConfig) -> str:
    return f" (named by {robot.config_path})" if robot.config_path and robot.config_path != robot.mjcf_path else ""


def _floats(where: Path, key: str, value: Any, n: int | None = None) -> tuple[float, ...]:
    try:
        out = tuple(float(v) for v in (value if isinstance(value, (list, tuple)) else [value]))
    except (TypeError, ValueError):
        raise DemoError(where, f"'{key}' must be a number or a list of numbers, got {value!r}") from None
    if n is not None and len(out) != n:
        raise DemoError(where, f"'{key}' must have {n} numbers, got {len(out)}")
    if not all(math.isfinite(v) for v in out):  # NaN would reach the simulator as a control
        raise DemoError(where, f"'{key}' must be finite numbers, got {value!r}")
    return out


def load_robot(path: str | Path | RobotConfig | None = None) -> RobotConfig:
    """Read and validate a robot config (``None``: the built-in arm). Bad names raise DemoError."""
    if isinstance(path, RobotConfig):
        return path
    cfg_path = BUILTIN_CONFIG if path is None else Path(path).expanduser()
    if not cfg_path.is_file():
        raise DemoError(cfg_path, "robot config not found (expected a .toml file)")
    try:
        raw = tomllib.loads(cfg_path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise DemoError(cfg_path, f"not a valid TOML robot config: {exc}") from None
    return robot_from_keys(raw, cfg_path.parent, cfg_path.resolve(), default_name=cfg_path.stem)


def robot_from_keys(raw: dict[str, Any], base: Path, where: Path, default_name: str = "robot") -> RobotConfig:
    """Validate a robot config's keys (a parsed TOML file, or a store's record of one).

    ``base``: the folder ``mjcf`` is relative to. ``where``: what errors name, kept as
    ``config_path`` (the TOML file, or the store/run folder holding the robot's files).
    """
    if not isinstance(raw, dict):
        raise DemoError(where, "robot config must be a table of keys")
    missing = [k for k in _REQUIRED if k not in raw]
    if missing:
        raise DemoError(where, f"robot config lacks {', '.join(missing)}")
    unknown = sorted(set(raw) - set(_REQUIRED) - set(_OPTIONAL))
    if unknown:
        raise DemoError(where, f"unknown robot config key(s): {', '.join(unknown)}")
    mjcf = (base / str(raw["mjcf"])).resolve()
    if not mjcf.is_file():
        raise DemoError(where, f"mjcf file {mjcf} does not exist")
    arm = raw["arm_joints"]
    if not isinstance(arm, list) or not arm or not all(isinstance(j, str) for j in arm):
        raise DemoError(where, "'arm_joints' must be a non-empty list of joint names")
    grip = _floats(where, "gripper_range", raw["gripper_range"], 2)
    if grip[0] == grip[1]:
        raise DemoError(where, "'gripper_range' open and closed values must differ")
    vmax = _floats(where, "max_joint_velocity", raw.get("max_joint_velocity", 2.0))
    if len(vmax) == 1:
        vmax = vmax * len(arm)
    if len(vmax) != len(arm) or min(vmax) <= 0:
        raise DemoError(where, f"'max_joint_velocity' needs 1 or {len(arm)} positive numbers")
    if not isinstance(raw.get("ee_site_body", ""), str):
        raise DemoError(where, "'ee_site_body' must be a body name")
    robot = RobotConfig(
        name=str(raw.get("name", default_name)),
        mjcf_path=mjcf,
        arm_joints=tuple(arm),
        gripper_actuator=str(raw["gripper_actuator"]),
        gripper_range=(grip[0], grip[1]),
        ee_site=str(raw["ee_site"]),
        base_body=str(raw["base_body"]),
        home_key=str(raw["home_key"]),
        config_path=where,
        ee_site_body=raw.get("ee_site_body"),
        ee_site_pos=_floats(where, "ee_site_pos", raw.get("ee_site_pos", [0, 0, 0]), 3),  # type: ignore[arg-type]
        ee_site_quat=_floats(where, "ee_site_quat", raw.get("ee_site_quat", [1, 0, 0, 0]), 4),  # type: ignore[arg-type]
        gravcomp=bool(raw.get("gravcomp", True)),
        max_joint_velocity=vmax,
        wrist_camera=_wrist_camera(where, raw.get("wrist_camera")),
    )
    return _validated(robot)


def _wrist_camera(where: Path, value: Any) -> WristCamera | str:
    """The ``wrist_camera`` key: a camera name in the MJCF, or a table of pos/target|quat/fovy."""
    if value is None:
        return DEFAULT_WRIST_CAMERA
    if isinstance(value, str):
        if not value:
            raise DemoError(where, "'wrist_camera' must name a camera in the MJCF, or be a table of pos, target|quat, fovy")
        return value
    if not isinstance(value, dict):
        raise DemoError(where, f"'wrist_camera' must be a camera name or a table of pos, target|quat, fovy, got {value!r}")
    unknown = sorted(set(value) - {"pos", "target", "quat", "fovy"})
    if unknown:
        raise DemoError(where, f"unknown 'wrist_camera' key(s): {', '.join(unknown)} (known: pos, target, quat, fovy)")
    if "target" in value and "quat" in value:
        raise DemoError(where, "'wrist_camera' takes target or quat, not both")
    pos = _floats(where, "wrist_camera.pos", value.get("pos", _WRIST_POS), 3)
    if "quat" in value:
        quat = _floats(where, "wrist_camera.quat", value["quat"], 4)
        if np.linalg.norm(quat) < 1e-6:  # kept as given otherwise: MuJoCo normalises it, as in MJCF
            raise DemoError(where, f"'wrist_camera.quat' must be a non-zero quaternion (wxyz), got {value['quat']!r}")
    else:
        target = _floats(where, "wrist_camera.target", value.get("target", _WRIST_TARGET), 3)
        if np.linalg.norm(np.subtract(target, pos)) < 1e-6:
            raise DemoError(where, "'wrist_camera.target' must differ from its pos")
        quat = _looking_at(pos, target)
    (fovy,) = _floats(where, "wrist_camera.fovy", value.get("fovy", _WRIST_FOVY), 1)
    if not 0.0 < fovy < 180.0:
        raise DemoError(where, f"'wrist_camera.fovy' must be in (0, 180) degrees, got {fovy:g}")
    return WristCamera(pos, quat, fovy)  # type: ignore[arg-type]


def config_keys(robot: RobotConfig, mjcf: str) -> dict[str, Any]:
    """The robot's config as TOML keys (what :func:`robot_from_keys` reads), ``mjcf`` as given."""
    keys: dict[str, Any] = {
        "name": robot.name,
        "mjcf": mjcf,
        "arm_joints": list(robot.arm_joints),
        "gripper_actuator": robot.gripper_actuator,
        "gripper_range": list(robot.gripper_range),
        "ee_site": robot.ee_site,
        "base_body": robot.base_body,
        "home_key": robot.home_key,
        "ee_site_pos": list(robot.ee_site_pos),
        "ee_site_quat": list(robot.ee_site_quat),
        "gravcomp": robot.gravcomp,
        "max_joint_velocity": list(robot.max_joint_velocity),
    }
    if robot.ee_site_body:
        keys["ee_site_body"] = robot.ee_site_body
    if robot.wrist_camera != DEFAULT_WRIST_CAMERA:  # records of robots without the key stay as they were
        cam = robot.wrist_camera
        keys["wrist_camera"] = cam if isinstance(cam, str) else {"pos": list(cam.pos), "quat": list(cam.quat), "fovy": cam.fovy}
    return keys


def _validated(robot: RobotConfig) -> RobotConfig:
    """Compile the robot alone, check every name, and read its home configuration."""
    where = robot.config_path
    try:
        model = robot_spec(robot).compile()
    except DemoError:
        raise
    except Exception as exc:
        raise DemoError(robot.mjcf_path, f"MJCF does not compile: {mujoco_message(exc)}{_named_by(robot)}") from None

    def need(kind: mujoco.mjtObj, name: str, what: str) -> int:
        i = mujoco.mj_name2id(model, kind, name)
        if i < 0:
            raise DemoError(where, f"{what} '{name}' not found in {robot.mjcf_path.name}")
        return i

    joint_ids = [need(mujoco.mjtObj.mjOBJ_JOINT, j, "arm joint") for j in robot.arm_joints]
    for name, jid in zip(robot.arm_joints, joint_ids):
        if int(model.jnt_type[jid]) not in _HINGE_SLIDE:
            raise DemoError(where, f"arm joint '{name}' must be a hinge or slide joint")
        arm_actuator_for(model, jid, name, where)
    act = need(mujoco.mjtObj.mjOBJ_ACTUATOR, robot.gripper_actuator, "gripper actuator")
    position_gain(model, act, robot.gripper_actuator, where)
    need(mujoco.mjtObj.mjOBJ_SITE, robot.ee_site, "ee site")
    need(mujoco.mjtObj.mjOBJ_BODY, robot.base_body, "base body")
    key = need(mujoco.mjtObj.mjOBJ_KEY, robot.home_key, "home keyframe")
    if isinstance(robot.wrist_camera, str):
        need(mujoco.mjtObj.mjOBJ_CAMERA, robot.wrist_camera, "wrist_camera")
    if robot.wrist_camera != "wrist" and mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, "wrist") >= 0:
        raise DemoError(where, f"{robot.mjcf_path.name} has a camera named 'wrist' that wrist_camera does not name: "
                               "set wrist_camera = \"wrist\" to render it as the wrist camera, or rename it")

    home: dict[str, float] = {}
    for j in range(model.njnt):
        if int(model.jnt_type[j]) in _HINGE_SLIDE:
            home[model.joint(j).name] = float(model.key_qpos[key, model.jnt_qposadr[j]])
    open_, closed = robot.gripper_range
    ctrl = float(model.key_ctrl[key, act]) if model.nu else open_
    grip = float(np.clip((ctrl - open_) / (closed - open_), 0.0, 1.0)) + 0.0
    object.__setattr__(robot, "home_qpos", home)
    object.__setattr__(robot, "home_gripper", grip)
    return robot


def position_gain(model: mujoco.MjModel, act: int, name: str, where: Path | None) -> tuple[float, float]:
    """(scale, offset) with equilibrium actuator length = scale * ctrl + offset (position servo)."""
    gain = float(model.actuator_gainprm[act, 0])
    b0, b1 = float(model.actuator_biasprm[act, 0]), float(model.actuator_biasprm[act, 1])
    if int(model.actuator_gaintype[act]) != int(mujoco.mjtGain.mjGAIN_FIXED) or b1 >= 0 or gain <= 0:
        raise DemoError(where, f"actuator '{name}' is not a position actuator (need gain kp and bias -kp)")
    return gain / -b1, b0 / -b1


def arm_actuator_for(model: mujoco.MjModel, joint_id: int, joint_name: str, where: Path | None) -> int:
    """The position actuator that drives ``joint_id`` directly (transmission = the joint)."""
    for a in range(model.nu):
        if int(model.actuator_trntype[a]) == int(mujoco.mjtTrn.mjTRN_JOINT) and model.actuator_trnid[a, 0] == joint_id:
            position_gain(model, a, model.actuator(a).name or f"#{a}", where)
            return a
    raise DemoError(where, f"arm joint '{joint_name}' has no position actuator driving it")
