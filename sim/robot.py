"""Robot configs: what `demo` needs to know about an MJCF arm with a gripper, read from TOML keys.

This module parses and checks the keys (:func:`load_robot`, :func:`robot_from_keys`) into a
:class:`RobotConfig`; building the robot's MjSpec/model from it and checking the model's names and
actuators is :mod:`demo.sim.robot_model`, whose public names are importable from here too.

A robot config is a small TOML file (paths relative to it)::

    name = "panda_prim"
    mjcf = "panda.xml"                        # or "pkg://PACKAGE/path/in/package.xml": a file of an installed package
    arm_joints = ["joint1", ..., "joint7"]     # the joints the action drives, in action order
    gripper_actuator = "gripper"              # a position-like actuator (tendon or joint)
    gripper_range = [0.04, 0.0]               # its ctrl at [open, closed]
    ee_site = "tcp"                           # end-effector site (z: approach axis, y: finger axis)
    base_body = "link0"                       # the robot base body (placed at base_pos/base_quat in the scene)
    home_key = "home"                         # keyframe with the home configuration (or `home`, below)
    # optional:
    home = [0, 0, 0, -1.57, 0, 1.57, -0.785]  # home arm configuration (rad), for MJCFs without a keyframe
    gripper_mjcf = "hand.xml"                 # a gripper in its own MJCF (arm files without one) ...
    gripper_mount = "flange"                  #   ... attached to this arm body
    gripper_prefix = "hand/"                  #   ... its names prefixed (default: the file's stem and "/", so
                                              #   names never clash; "" keeps them); names here may omit it
    gripper_actuators = ["left", "right"]     # instead of gripper_actuator: one actuator per finger
                                              #   (gripper_range then [open, closed] for all, or one pair each)
    base_pos = [0, 0, 0]                      # the base body's position in the scene frame (m; table top z = 0)
    base_quat = [1, 0, 0, 0]                  # ... and orientation (wxyz)
    pd_kp = 400.0                             # PD gains for motor actuators (scalar or one per motor;
    pd_kd = 20.0                              #   default from the inertia at home, see demo.sim.actuation)
    ee_site_body = "hand"                     # create `ee_site` on this body (for MJCFs without one)
    ee_site_pos = [0, 0, 0.1034]              #   ... at this pose in the body frame (m)
    ee_site_quat = [1, 0, 0, 0]               #   ... (wxyz)
    gravcomp = true                           # compensate gravity on the robot's bodies (default)
    add_actuators = true                      # a PD position servo on every arm joint without an actuator
                                              #   (models published without actuators; gains: pd_kp, pd_kd)
    max_joint_velocity = 2.0                  # rad/s, for the experts' IK (scalar or one per joint)
    wrist_camera = { pos = [0.05, 0, -0.05], target = [0, 0, 0.12], fovy = 80 }   # the `wrist` camera
    arm_prefix = "vx300s_left/"               # a file with several arms (a bimanual scene): the one whose top-level
                                              #   body is named so or starts with it; names here may omit it
    keep_bodies = ["table"]                   #   ... the file's other top-level bodies kept (default: none)

Leader-follower capture (``demo collect --source leader``, :mod:`demo.collect.leader`) reads a leader
arm's joint readings; the ``[leader]`` table (at the end of the file, as TOML tables go) says how they
map onto this arm, per arm joint ``follower = sign * reading + offset`` (rad, or m for a slide)::

    [leader]
    joints = ["waist", "shoulder", ...]       # the leader file's column for each arm joint (default: arm_joints)
    sign = [1, -1, 1, 1, 1, 1]                # +1 or -1 per joint (default: all +1)
    offset = [0, 0.05, 0, 0, 0, 0]            # rad added after the sign (default: all 0)
    gripper = [0.2, 0.9]                      # the leader's gripper reading at open and at closed (default [0, 1])

A file with several arms (gym-aloha's bimanual scenes: two ViperX arms, a table, a cube) runs one of
them: ``arm_prefix`` keeps the top-level bodies of that arm, every other top-level body (the other
arms, the file's table and objects) is left out unless ``keep_bodies`` names it, and so are the
world's own lights, cameras, geoms and sites (the task scene brings its own) and every actuator of
what was left out. Keyframes keep the values of the joints and actuators that remain.

``wrist_camera`` places the ``wrist`` camera (``demo collect --camera wrist@WxH``) on the EE site's
body, in the **EE site frame** (m): ``pos`` its position, then either ``target`` (a point it looks
at, with the site's +x up in the image) or ``quat`` (wxyz, MuJoCo camera convention: it looks along
its -z, +y up), and ``fovy`` (vertical field of view, degrees). Keys left out take the defaults
above (beside the hand, above the TCP, looking past the fingertips; ``quat`` ~ [0.1008, 0.6999,
0.6999, 0.1008]). ``wrist_camera = "NAME"`` instead renders the MJCF's own camera ``NAME`` as
``wrist``.

Each arm joint must be a hinge or slide joint driven directly by a position-like actuator (``ctrl``
= joint target, e.g. MJCF ``<position>`` or Menagerie's ``<general>`` with ``biasprm="0 -kp -kv"``)
or by a ``<motor>``, which becomes a PD position servo (:mod:`demo.sim.actuation`). The gripper is
one actuator (on a finger joint, a tendon, or one joint of an equality-coupled pair) or one per
finger (``gripper_actuators``), position-like or motor. The finger bodies must be descendants of
the EE site's body (the experts detect a grasp by contacts of two such bodies with the object).
The robot is compiled on its own and attached into the task scene (:mod:`demo.sim.scene`), so its
``<compiler>`` options, defaults and keyframes never touch task objects, and its mesh and texture
files are found relative to its MJCF (``meshdir``/``texturedir`` as MuJoCo reads them).
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

import importlib.util
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from demo.errors import DemoError
from demo.sim.geometry import lookat_quat
from demo.sim.robot_model import (
    arm_actuator_for,
    home_qpos_vector,
    is_descendant,
    mujoco_message,
    position_gain,
    robot_spec,
    validated,
)

# The model-side names (robot_spec ... arm_actuator_for) are defined in demo.sim.robot_model and
# re-exported: callers import them from here.
__all__ = [
    "ASSETS", "BUILTIN_CONFIG", "DEFAULT_WRIST_CAMERA", "LeaderCalibration", "PACKAGE_SCHEME", "RobotConfig", "WristCamera",
    "config_keys", "default_gripper_prefix", "load_robot", "mjcf_location", "robot_from_keys",
    "arm_actuator_for", "home_qpos_vector", "is_descendant", "mujoco_message", "position_gain", "robot_spec",
]

ASSETS = Path(__file__).resolve().parent / "assets"
BUILTIN_CONFIG = ASSETS / "panda.toml"

_REQUIRED = ("mjcf", "arm_joints", "gripper_range", "ee_site", "base_body")
# Keys of which exactly one is required, with what to write when both are missing.
_ONE_OF = (
    (("gripper_actuator", "gripper_actuators"), 'gripper_actuator = "NAME" (or gripper_actuators = ["LEFT", "RIGHT"])'),
    (("home_key", "home"), 'home_key = "KEYFRAME" (or home = [one angle per arm joint, rad])'),
)
_OPTIONAL = ("name", "ee_site_body", "ee_site_pos", "ee_site_quat", "gravcomp", "max_joint_velocity", "wrist_camera",
             "gripper_actuator", "gripper_actuators", "home_key", "home", "base_pos", "base_quat", "pd_kp", "pd_kd",
             "gripper_mjcf", "gripper_mount", "gripper_prefix", "add_actuators", "arm_prefix", "keep_bodies", "leader")


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
class LeaderCalibration:
    """How a leader arm's readings map onto this arm (``[leader]``; module docstring): per arm joint
    ``follower = sign * reading + offset`` (rad, or m), the gripper's reading linear between ``gripper``'s open
    and closed values (closedness 0 .. 1, clipped)."""

    joints: tuple[str, ...]  # the leader file's column of each arm joint, in arm_joints order
    sign: tuple[float, ...]
    offset: tuple[float, ...]
    gripper: tuple[float, float] = (0.0, 1.0)  # the reading at open, at closed

    def follower(self, readings: np.ndarray) -> np.ndarray:
        """Leader joint readings ``[..., n_arm]`` -> this arm's joint positions."""
        return np.asarray(self.sign) * readings + np.asarray(self.offset)

    def readings(self, joints: np.ndarray) -> np.ndarray:
        """This arm's joint positions -> the leader readings that map onto them (the inverse of :meth:`follower`)."""
        return (joints - np.asarray(self.offset)) / np.asarray(self.sign)

    def closedness(self, reading: np.ndarray | float) -> np.ndarray:
        open_, closed = self.gripper
        return np.clip((np.asarray(reading, dtype=np.float64) - open_) / (closed - open_), 0.0, 1.0)

    def gripper_reading(self, closedness: np.ndarray | float) -> np.ndarray:
        open_, closed = self.gripper
        return open_ + np.asarray(closedness, dtype=np.float64) * (closed - open_)

    def to_json(self) -> dict[str, Any]:
        return {"joints": list(self.joints), "sign": list(self.sign), "offset": list(self.offset),
                "gripper": list(self.gripper)}


@dataclass(frozen=True)
class RobotConfig:
    """A validated robot config. ``home_qpos`` maps every robot hinge/slide joint to its home value."""

    name: str
    mjcf_path: Path
    arm_joints: tuple[str, ...]
    gripper_actuator: str  # the first (or only) gripper actuator
    gripper_range: tuple[float, float]  # its ctrl at (open, closed)
    ee_site: str
    base_body: str
    home_key: str | None  # None: the home configuration is ``home``
    config_path: Path | None = None  # the TOML file, or the store/run folder the robot's files were restored from
    home: tuple[float, ...] = ()  # arm joint angles at home (rad), where the MJCF has no home keyframe
    gripper_actuators: tuple[str, ...] = ()  # every gripper actuator (default: gripper_actuator alone)
    gripper_ranges: tuple[tuple[float, float], ...] = ()  # (open, closed) ctrl per gripper actuator
    base_pos: tuple[float, float, float] = (0.0, 0.0, 0.0)  # base body in the scene frame (m)
    base_quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)  # (wxyz)
    pd_kp: tuple[float, ...] = ()  # PD gains of motor actuators (empty: from the inertia at home)
    pd_kd: tuple[float, ...] = ()
    gripper_mjcf: Path | None = None  # a separate gripper MJCF, attached to the arm at gripper_mount
    gripper_mount: str | None = None  # the arm body the gripper's root is attached to (its frame)
    gripper_prefix: str = ""  # prepended to every name of the gripper file when it is attached
    arm_prefix: str = ""  # a file with several arms: the one whose top-level bodies' names start with it
    keep_bodies: tuple[str, ...] = ()  # ... and the file's other top-level bodies kept
    leader: LeaderCalibration | None = None  # leader-follower capture's calibration ([leader]); None: identity
    add_actuators: bool = False  # a PD servo on every arm joint no actuator drives
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

    @property
    def grippers(self) -> tuple[tuple[str, tuple[float, float]], ...]:
        """(actuator name, (open, closed) ctrl) for every gripper actuator."""
        if not self.gripper_actuators:
            return ((self.gripper_actuator, self.gripper_range),)
        return tuple(zip(self.gripper_actuators, self.gripper_ranges))

    def spec(self) -> mujoco.MjSpec:
        """A fresh MjSpec of the robot MJCF, with the configured EE site added if asked."""
        return robot_spec(self)


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


def _flag(where: Path, key: str, value: Any) -> bool:
    if not isinstance(value, bool):
        raise DemoError(where, f"'{key}' must be true or false, got {value!r}")
    return value


def load_robot(path: str | Path | RobotConfig | None = None) -> RobotConfig:
    """Read and validate a robot config (``None``: the built-in arm). Bad names raise DemoError."""
    if isinstance(path, RobotConfig):
        return path
    cfg_path = BUILTIN_CONFIG if path is None else Path(path).expanduser()
    raw = read_robot_toml(cfg_path)
    if "arms" in raw:
        raise DemoError(cfg_path, "lists several arms ([[arms]], demo.sim.arms): demo's tasks take one arm (give one of "
                                  "its arm configs); demo robot check checks each")
    return robot_from_keys(raw, cfg_path.parent, cfg_path.resolve(), default_name=cfg_path.stem)


def read_robot_toml(path: Path) -> dict[str, Any]:
    """A robot config file's keys; a missing file or bad TOML fails in one line naming it."""
    if not path.is_file():
        raise DemoError(path, "robot config not found (expected a .toml file)")
    try:
        return tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise DemoError(path, f"not a valid TOML robot config: {exc}") from None


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
    for keys, write in _ONE_OF:
        given = [k for k in keys if k in raw]
        if not given:
            raise DemoError(where, f"robot config lacks {keys[0]}: write {write}")
        if len(given) > 1:
            raise DemoError(where, f"robot config has both {' and '.join(keys)}: keep one")
    unknown = sorted(set(raw) - set(_REQUIRED) - set(_OPTIONAL))
    if unknown:
        raise DemoError(where, f"unknown robot config key(s): {', '.join(unknown)}")
    mjcf = mjcf_location(str(raw["mjcf"]), base, where)
    arm = raw["arm_joints"]
    if not isinstance(arm, list) or not arm or not all(isinstance(j, str) for j in arm):
        raise DemoError(where, "'arm_joints' must be a non-empty list of joint names")
    gripper_actuators, gripper_ranges = _grippers(where, raw)
    vmax = _floats(where, "max_joint_velocity", raw.get("max_joint_velocity", 2.0))
    if len(vmax) == 1:
        vmax = vmax * len(arm)
    if len(vmax) != len(arm) or min(vmax) <= 0:
        raise DemoError(where, f"'max_joint_velocity' needs 1 or {len(arm)} positive numbers")
    if not isinstance(raw.get("ee_site_body", ""), str):
        raise DemoError(where, "'ee_site_body' must be a body name")
    home = _floats(where, "home", raw["home"], len(arm)) if "home" in raw else ()
    base_quat = _floats(where, "base_quat", raw.get("base_quat", [1, 0, 0, 0]), 4)
    if np.linalg.norm(base_quat) < 1e-6:
        raise DemoError(where, f"'base_quat' must be a non-zero quaternion (wxyz), got {raw['base_quat']!r}")
    if "gripper_prefix" in raw and ("gripper_mjcf" not in raw or not isinstance(raw["gripper_prefix"], str)):
        raise DemoError(where, "'gripper_prefix' is a string prefixed to the names of gripper_mjcf's file (write both)")
    if not isinstance(raw.get("arm_prefix", "x"), str) or raw.get("arm_prefix", "x") == "":
        raise DemoError(where, "'arm_prefix' names the arm of a file with several (the start of its top-level body's name)")
    keep = raw.get("keep_bodies", [])
    if not isinstance(keep, list) or not all(isinstance(b, str) and b for b in keep) or (keep and "arm_prefix" not in raw):
        raise DemoError(where, "'keep_bodies' is a list of the file's top-level bodies kept beside the arm of 'arm_prefix' (write both)")
    if ("gripper_mjcf" in raw) != ("gripper_mount" in raw):
        raise DemoError(where, "'gripper_mjcf' and 'gripper_mount' go together: write both (the gripper file and the arm body it mounts on)")
    gripper_mjcf = mjcf_location(str(raw["gripper_mjcf"]), base, where) if "gripper_mjcf" in raw else None
    pd = {k: _floats(where, k, raw[k]) if k in raw else () for k in ("pd_kp", "pd_kd")}
    if any(v <= 0 for v in pd["pd_kp"]) or any(v < 0 for v in pd["pd_kd"]):
        raise DemoError(where, "'pd_kp' must be > 0 and 'pd_kd' >= 0 (N m/rad and N m s/rad for a hinge)")
    robot = RobotConfig(
        name=str(raw.get("name", default_name)),
        mjcf_path=mjcf,
        arm_joints=tuple(arm),
        gripper_actuator=gripper_actuators[0],
        gripper_range=gripper_ranges[0],
        ee_site=str(raw["ee_site"]),
        base_body=str(raw["base_body"]),
        home_key=str(raw["home_key"]) if "home_key" in raw else None,
        config_path=where,
        home=home,
        gripper_actuators=gripper_actuators if "gripper_actuators" in raw else (),
        gripper_ranges=gripper_ranges if "gripper_actuators" in raw else (),
        base_pos=_floats(where, "base_pos", raw.get("base_pos", [0, 0, 0]), 3),  # type: ignore[arg-type]
        base_quat=base_quat,  # type: ignore[arg-type]
        pd_kp=pd["pd_kp"],
        pd_kd=pd["pd_kd"],
        gripper_mjcf=gripper_mjcf,
        gripper_mount=str(raw["gripper_mount"]) if "gripper_mount" in raw else None,
        gripper_prefix=str(raw.get("gripper_prefix", default_gripper_prefix(gripper_mjcf))),
        arm_prefix=str(raw.get("arm_prefix", "")),
        keep_bodies=tuple(keep),
        leader=_leader(where, raw["leader"], tuple(arm)) if "leader" in raw else None,
        add_actuators=_flag(where, "add_actuators", raw.get("add_actuators", False)),
        ee_site_body=raw.get("ee_site_body"),
        ee_site_pos=_floats(where, "ee_site_pos", raw.get("ee_site_pos", [0, 0, 0]), 3),  # type: ignore[arg-type]
        ee_site_quat=_floats(where, "ee_site_quat", raw.get("ee_site_quat", [1, 0, 0, 0]), 4),  # type: ignore[arg-type]
        gravcomp=bool(raw.get("gravcomp", True)),
        max_joint_velocity=vmax,
        wrist_camera=_wrist_camera(where, raw.get("wrist_camera")),
    )
    return validated(robot)


def default_gripper_prefix(gripper_mjcf: Path | None) -> str:
    """The prefix a gripper file's names get by default: its file's stem and "/" (``robotiq_2f85/``), so that
    names the arm's file also uses (sites, textures) never clash."""
    return f"{gripper_mjcf.stem}/" if gripper_mjcf is not None else ""


PACKAGE_SCHEME = "pkg://"


def mjcf_location(mjcf: str, base: Path, where: Path) -> Path:
    """The MJCF file a config's ``mjcf`` names: a path relative to ``base``, or
    ``pkg://PACKAGE/PATH``, a file inside an installed Python package (found without importing it)."""
    if mjcf.startswith(PACKAGE_SCHEME):
        package, _, inner = mjcf[len(PACKAGE_SCHEME):].partition("/")
        try:
            found = importlib.util.find_spec(package) if package.isidentifier() else None
        except (ImportError, ValueError):
            found = None
        if found is None or not found.submodule_search_locations:
            raise DemoError(where, f"mjcf {mjcf}: Python package '{package}' is not installed in this environment; "
                                   "install it (pip install ...) or point mjcf at the MJCF file")
        root = Path(list(found.submodule_search_locations)[0]).resolve()
        path = (root / inner).resolve()
        if not inner or not path.is_relative_to(root):
            raise DemoError(where, f"mjcf {mjcf}: write pkg://{package}/PATH with PATH inside the package")
    else:
        path = (base / mjcf).resolve()
    if not path.is_file():
        raise DemoError(where, f"mjcf file {path} does not exist")
    return path


def _grippers(where: Path, raw: dict[str, Any]) -> tuple[tuple[str, ...], tuple[tuple[float, float], ...]]:
    """The gripper actuator names and each one's (open, closed) ctrl, from either form of the keys."""
    names = raw.get("gripper_actuators", [raw.get("gripper_actuator")])
    if not isinstance(names, list) or not names or not all(isinstance(n, str) and n for n in names):
        raise DemoError(where, "'gripper_actuators' must be a non-empty list of actuator names")
    value = raw["gripper_range"]
    if isinstance(value, list) and value and all(isinstance(v, list) for v in value):
        if len(value) != len(names):
            raise DemoError(where, f"'gripper_range' has {len(value)} [open, closed] pairs for {len(names)} gripper actuators")
        ranges = tuple(_floats(where, "gripper_range", v, 2) for v in value)
    else:
        ranges = (_floats(where, "gripper_range", value, 2),) * len(names)
    if any(r[0] == r[1] for r in ranges):
        raise DemoError(where, "'gripper_range' open and closed values must differ")
    return tuple(names), tuple((r[0], r[1]) for r in ranges)


def _leader(where: Path, value: Any, arm: tuple[str, ...]) -> LeaderCalibration:
    """The ``[leader]`` table (module docstring)."""
    if not isinstance(value, dict):
        raise DemoError(where, "'leader' is a table: [leader] with joints, sign, offset, gripper")
    unknown = sorted(set(value) - {"joints", "sign", "offset", "gripper"})
    if unknown:
        raise DemoError(where, f"unknown key(s) in [leader]: {', '.join(unknown)} (it has joints, sign, offset, gripper)")
    joints = value.get("joints", list(arm))
    if (not isinstance(joints, list) or len(joints) != len(arm) or not all(isinstance(j, str) and j for j in joints)
            or len(set(joints)) != len(joints)):
        raise DemoError(where, f"[leader] joints must name {len(arm)} distinct columns, one per arm joint")
    if set(joints) & {"t", "gripper", "episode_seed"}:
        raise DemoError(where, "[leader] joints may not be named t, gripper or episode_seed (the file's other columns)")
    sign = _floats(where, "[leader] sign", value.get("sign", [1.0] * len(arm)), len(arm))
    if any(v not in (1.0, -1.0) for v in sign):
        raise DemoError(where, f"[leader] sign must be +1 or -1 per joint, got {list(sign)}")
    offset = _floats(where, "[leader] offset", value.get("offset", [0.0] * len(arm)), len(arm))
    gripper = _floats(where, "[leader] gripper", value.get("gripper", [0.0, 1.0]), 2)
    if gripper[0] == gripper[1]:
        raise DemoError(where, "[leader] gripper's open and closed readings must differ")
    return LeaderCalibration(tuple(joints), sign, offset, (gripper[0], gripper[1]))


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


def config_keys(robot: RobotConfig, mjcf: str, gripper_mjcf: str | None = None) -> dict[str, Any]:
    """The robot's config as TOML keys (what :func:`robot_from_keys` reads), ``mjcf`` (and
    ``gripper_mjcf``, for a robot with a separate gripper file) as given."""
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
    # Keys added later are written only when set, so records of robots without them stay as they were.
    if robot.gripper_actuators:
        del keys["gripper_actuator"]
        keys["gripper_actuators"] = list(robot.gripper_actuators)
        keys["gripper_range"] = [list(r) for r in robot.gripper_ranges]
    if robot.home_key is None:
        del keys["home_key"]
        keys["home"] = list(robot.home)
    if robot.base_pos != (0.0, 0.0, 0.0):
        keys["base_pos"] = list(robot.base_pos)
    if robot.base_quat != (1.0, 0.0, 0.0, 0.0):
        keys["base_quat"] = list(robot.base_quat)
    for key in ("pd_kp", "pd_kd"):
        if getattr(robot, key):
            keys[key] = list(getattr(robot, key))
    if robot.gripper_mjcf is not None:
        keys["gripper_mjcf"] = gripper_mjcf
        keys["gripper_mount"] = robot.gripper_mount
        if robot.gripper_prefix != default_gripper_prefix(robot.gripper_mjcf):
            keys["gripper_prefix"] = robot.gripper_prefix
    if robot.arm_prefix:
        keys["arm_prefix"] = robot.arm_prefix
    if robot.keep_bodies:
        keys["keep_bodies"] = list(robot.keep_bodies)
    if robot.leader is not None:
        keys["leader"] = robot.leader.to_json()
    if robot.add_actuators:
        keys["add_actuators"] = True
    if robot.ee_site_body:
        keys["ee_site_body"] = robot.ee_site_body
    if robot.wrist_camera != DEFAULT_WRIST_CAMERA:
        cam = robot.wrist_camera
        keys["wrist_camera"] = cam if isinstance(cam, str) else {"pos": list(cam.pos), "quat": list(cam.quat), "fovy": cam.fovy}
    return keys
