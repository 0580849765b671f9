"""Robot configs: what `demo` needs to know about an MJCF arm with a gripper.

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
    max_joint_velocity = 2.0                  # rad/s, for the experts' IK (scalar or one per joint)
    wrist_camera = { pos = [0.05, 0, -0.05], target = [0, 0, 0.12], fovy = 80 }   # the `wrist` camera

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

from demo.errors import DemoError, one_line
from demo.sim.actuation import add_pd_layer, is_motor, is_position_servo, kind_of
from demo.sim.geometry import lookat_quat

ASSETS = Path(__file__).resolve().parent / "assets"
BUILTIN_CONFIG = ASSETS / "panda.toml"

_REQUIRED = ("mjcf", "arm_joints", "gripper_range", "ee_site", "base_body")
# Keys of which exactly one is required, with what to write when both are missing.
_ONE_OF = (
    (("gripper_actuator", "gripper_actuators"), 'gripper_actuator = "NAME" (or gripper_actuators = ["LEFT", "RIGHT"])'),
    (("home_key", "home"), 'home_key = "KEYFRAME" (or home = [one angle per arm joint, rad])'),
)
_HINGE_SLIDE = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
_OPTIONAL = ("name", "ee_site_body", "ee_site_pos", "ee_site_quat", "gravcomp", "max_joint_velocity", "wrist_camera",
             "gripper_actuator", "gripper_actuators", "home_key", "home", "base_pos", "base_quat", "pd_kp", "pd_kd",
             "gripper_mjcf", "gripper_mount")


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


def robot_spec(robot: RobotConfig) -> mujoco.MjSpec:
    """The robot MJCF as a spec: the configured EE site added, motor actuators made PD servos."""
    spec = _file_spec(robot)
    model = _compile(robot, spec)
    motors = [a for a in _driving_actuators(model, robot) if is_motor(model, a)]
    if motors:
        add_pd_layer(spec, model, home_qpos_vector(model, robot), motors, robot.pd_kp, robot.pd_kd, robot.config_path)
    return spec


def _file_spec(robot: RobotConfig) -> mujoco.MjSpec:
    """The MJCF as written, plus the configured EE site."""
    try:
        spec = mujoco.MjSpec.from_file(str(robot.mjcf_path))
    except Exception as exc:  # mujoco raises ValueError with the parser's (multi-line) message
        raise DemoError(robot.mjcf_path, f"MJCF does not load: {mujoco_message(exc)}{_named_by(robot)}") from None
    if robot.gripper_mjcf is not None:
        _attach_gripper(robot, spec)
    if robot.ee_site_body:
        body = spec.body(robot.ee_site_body)
        if body is None:
            raise DemoError(robot.config_path, f"ee_site_body '{robot.ee_site_body}' is not a body in {robot.mjcf_path.name}; "
                                               "name a body of the hand (the EE site is added to it)")
        body.add_site(name=robot.ee_site, pos=list(robot.ee_site_pos), quat=list(robot.ee_site_quat), size=[0.006, 0, 0])
    return spec


def _attach_gripper(robot: RobotConfig, spec: mujoco.MjSpec) -> None:
    """Attach ``gripper_mjcf`` (compiled on its own terms, names kept) to the arm body ``gripper_mount``."""
    try:
        gripper = mujoco.MjSpec.from_file(str(robot.gripper_mjcf))
    except Exception as exc:
        raise DemoError(robot.gripper_mjcf, f"gripper MJCF does not load: {mujoco_message(exc)}{_named_by(robot)}") from None
    mount = spec.body(str(robot.gripper_mount))
    if mount is None:
        raise DemoError(robot.config_path, f"gripper_mount '{robot.gripper_mount}' is not a body in {robot.mjcf_path.name}; "
                                           "name the arm's flange body")
    for key in list(gripper.keys):
        gripper.delete(key)
    for name in (n for n in dir(spec.option) if not n.startswith("_")):  # the arm's options win, silently
        setattr(gripper.option, name, getattr(spec.option, name))
    spec.attach(gripper, prefix="", frame=mount.add_frame())


def _compile(robot: RobotConfig, spec: mujoco.MjSpec) -> mujoco.MjModel:
    try:
        return spec.compile()
    except Exception as exc:
        raise DemoError(robot.mjcf_path, f"MJCF does not compile: {mujoco_message(exc)}{_named_by(robot)}") from None


def _driving_actuators(model: mujoco.MjModel, robot: RobotConfig) -> list[int]:
    """The actuators `demo` commands: each arm joint's, then the gripper's (names not found are skipped)."""
    out = []
    for name in robot.arm_joints:
        j = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        a = _joint_actuator(model, j) if j >= 0 else None
        if a is not None:
            out.append(a)
    for name, _ in robot.grippers:
        a = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, name)
        if a >= 0 and a not in out:
            out.append(a)
    return out


def _joint_actuator(model: mujoco.MjModel, joint_id: int) -> int | None:
    """The first actuator whose transmission is the joint itself."""
    for a in range(model.nu):
        if int(model.actuator_trntype[a]) == int(mujoco.mjtTrn.mjTRN_JOINT) and model.actuator_trnid[a, 0] == joint_id:
            return a
    return None


def home_qpos_vector(model: mujoco.MjModel, robot: RobotConfig) -> np.ndarray:
    """The robot model's qpos at home: its keyframe ``home_key``, else ``qpos0`` with ``home`` on the arm."""
    if robot.home_key is not None:
        key = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, robot.home_key)
        return model.key_qpos[key].copy() if key >= 0 else model.qpos0.copy()
    q = model.qpos0.copy()
    for name, value in zip(robot.arm_joints, robot.home):
        j = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        if j >= 0:
            q[model.jnt_qposadr[j]] = value
    return q


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
        ee_site_body=raw.get("ee_site_body"),
        ee_site_pos=_floats(where, "ee_site_pos", raw.get("ee_site_pos", [0, 0, 0]), 3),  # type: ignore[arg-type]
        ee_site_quat=_floats(where, "ee_site_quat", raw.get("ee_site_quat", [1, 0, 0, 0]), 4),  # type: ignore[arg-type]
        gravcomp=bool(raw.get("gravcomp", True)),
        max_joint_velocity=vmax,
        wrist_camera=_wrist_camera(where, raw.get("wrist_camera")),
    )
    return _validated(robot)


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
    if robot.ee_site_body:
        keys["ee_site_body"] = robot.ee_site_body
    if robot.wrist_camera != DEFAULT_WRIST_CAMERA:
        cam = robot.wrist_camera
        keys["wrist_camera"] = cam if isinstance(cam, str) else {"pos": list(cam.pos), "quat": list(cam.quat), "fovy": cam.fovy}
    return keys


def _validated(robot: RobotConfig) -> RobotConfig:
    """Compile the robot alone, check every name and actuator, and read its home configuration.

    Each error names the config key (or the MJCF element) at fault and what to write instead.
    """
    where = robot.config_path
    file_model = _compile(robot, _file_spec(robot))
    fname = robot.mjcf_path.name

    def need(kind: mujoco.mjtObj, name: str, what: str, key: str) -> int:
        i = mujoco.mj_name2id(file_model, kind, name)
        if i < 0:
            raise DemoError(where, f"{what} '{name}' not found in {fname}; fix '{key}' ({_names_hint(file_model, kind)})")
        return i

    for name in robot.arm_joints:
        jid = need(mujoco.mjtObj.mjOBJ_JOINT, name, "arm joint", "arm_joints")
        if int(file_model.jnt_type[jid]) not in _HINGE_SLIDE:
            raise DemoError(where, f"arm joint '{name}' must be a hinge or slide joint; fix 'arm_joints'")
    for name, _ in robot.grippers:
        need(mujoco.mjtObj.mjOBJ_ACTUATOR, name, "gripper actuator", "gripper_actuators" if robot.gripper_actuators else "gripper_actuator")
    site = need(mujoco.mjtObj.mjOBJ_SITE, robot.ee_site, "ee site", "ee_site")
    need(mujoco.mjtObj.mjOBJ_BODY, robot.base_body, "base body", "base_body")
    key = -1
    if robot.home_key is not None:
        key = mujoco.mj_name2id(file_model, mujoco.mjtObj.mjOBJ_KEY, robot.home_key)
        if key < 0:
            raise DemoError(where, f"home keyframe '{robot.home_key}' not found in {fname}; fix 'home_key' "
                                   f"({_names_hint(file_model, mujoco.mjtObj.mjOBJ_KEY)}), or write home = [one angle per arm joint]")
    if isinstance(robot.wrist_camera, str):
        need(mujoco.mjtObj.mjOBJ_CAMERA, robot.wrist_camera, "wrist_camera", "wrist_camera")
    if robot.wrist_camera != "wrist" and mujoco.mj_name2id(file_model, mujoco.mjtObj.mjOBJ_CAMERA, "wrist") >= 0:
        raise DemoError(where, f"{fname} has a camera named 'wrist' that wrist_camera does not name: "
                               "set wrist_camera = \"wrist\" to render it as the wrist camera, or rename it")

    model = _compile(robot, robot_spec(robot))  # with the PD layer, if the robot has motors
    for name in robot.arm_joints:
        arm_actuator_for(model, model.joint(name).id, name, where)
    ee_body = int(model.site_bodyid[site])
    for name, (open_, closed) in robot.grippers:
        act = model.actuator(name).id
        position_gain(model, act, name, where)
        _check_gripper(model, act, name, (open_, closed), ee_body, robot)

    q = home_qpos_vector(model, robot)
    home = {model.joint(j).name: float(q[model.jnt_qposadr[j]]) for j in range(model.njnt) if int(model.jnt_type[j]) in _HINGE_SLIDE}
    first = model.actuator(robot.gripper_actuator).id
    open_, closed = robot.gripper_range
    ctrl = float(model.key_ctrl[key, first]) if key >= 0 and model.nu else open_
    grip = float(np.clip((ctrl - open_) / (closed - open_), 0.0, 1.0)) + 0.0
    object.__setattr__(robot, "home_qpos", home)
    object.__setattr__(robot, "home_gripper", grip)
    return robot


def _names_hint(model: mujoco.MjModel, kind: mujoco.mjtObj) -> str:
    """'it has: a, b, c' for error messages (the first few names of that kind in the model)."""
    count = {mujoco.mjtObj.mjOBJ_JOINT: model.njnt, mujoco.mjtObj.mjOBJ_ACTUATOR: model.nu, mujoco.mjtObj.mjOBJ_SITE: model.nsite,
             mujoco.mjtObj.mjOBJ_BODY: model.nbody, mujoco.mjtObj.mjOBJ_KEY: model.nkey, mujoco.mjtObj.mjOBJ_CAMERA: model.ncam}[kind]
    names = [n for n in (mujoco.mj_id2name(model, kind, i) for i in range(count)) if n]
    if not names:
        return "it has none"
    return "it has: " + ", ".join(names[:12]) + (", ..." if len(names) > 12 else "")


def _check_gripper(model: mujoco.MjModel, act: int, name: str, rng: tuple[float, float], ee_body: int, robot: RobotConfig) -> None:
    """A gripper actuator must move a finger (a joint below the EE site's body) and its range must be
    commandable (open and closed inside the actuator's ctrl range)."""
    where = robot.config_path
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    start, n = int(data.moment_rowadr[act]), int(data.moment_rownnz[act])
    dofs = [int(d) for d, v in zip(data.moment_colind[start:start + n], data.actuator_moment[start:start + n]) if v != 0]
    bodies = {int(model.dof_bodyid[d]) for d in dofs}
    if not any(is_descendant(model, b, ee_body) for b in bodies):
        moved = ", ".join(sorted(model.body(b).name for b in bodies)) or "nothing"
        raise DemoError(where, f"gripper actuator '{name}' cannot close the gripper: it moves {moved}, no finger below "
                               f"the EE site's body '{model.body(ee_body).name}'; name the finger actuator in 'gripper_actuator'")
    if model.actuator_ctrllimited[act]:
        lo, hi = (float(v) for v in model.actuator_ctrlrange[act])
        for label, value in zip(("open", "closed"), rng):
            if not lo - 1e-9 <= value <= hi + 1e-9:
                raise DemoError(where, f"gripper_range {label} value {value:g} lies outside actuator '{name}' ctrlrange "
                                       f"[{lo:g}, {hi:g}], so the gripper cannot {'open' if label == 'open' else 'close'}; "
                                       f"write gripper_range = [open, closed] within it")


def is_descendant(model: mujoco.MjModel, body: int, ancestor: int) -> bool:
    """Whether ``body`` lies strictly below ``ancestor`` in the kinematic tree."""
    while body > 0:
        body = int(model.body_parentid[body])
        if body == ancestor:
            return True
    return False


def position_gain(model: mujoco.MjModel, act: int, name: str, where: Path | None) -> tuple[float, float]:
    """(scale, offset) with equilibrium actuator length = scale * ctrl + offset (position servo)."""
    if not is_position_servo(model, act):
        raise DemoError(where, f"actuator '{name}' is a {kind_of(model, act)}, not a position actuator (gain kp, bias -kp) "
                               "or a motor; give it a <position> or <motor> actuator in the MJCF")
    gain = float(model.actuator_gainprm[act, 0])
    b0, b1 = float(model.actuator_biasprm[act, 0]), float(model.actuator_biasprm[act, 1])
    return gain / -b1, b0 / -b1


def arm_actuator_for(model: mujoco.MjModel, joint_id: int, joint_name: str, where: Path | None) -> int:
    """The position actuator that drives ``joint_id`` directly (transmission = the joint)."""
    a = _joint_actuator(model, joint_id)
    if a is None:
        raise DemoError(where, f"arm joint '{joint_name}' has no position actuator driving it (an actuator with "
                               f"joint=\"{joint_name}\"); fix 'arm_joints' or give it a <position> or <motor> actuator")
    position_gain(model, a, model.actuator(a).name or f"#{a}", where)
    return a
