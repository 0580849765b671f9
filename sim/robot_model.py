"""Building a robot's MuJoCo model from its :class:`~demo.sim.robot.RobotConfig`, and checking it.

:func:`robot_spec` loads the MJCF as an MjSpec, attaches a separate gripper MJCF at its mount body,
adds the configured EE site (pose in the body frame: m, quat wxyz) and turns motor actuators into PD
position servos (:mod:`demo.sim.actuation`). :func:`validated` compiles the robot alone and checks
every name, actuator and the gripper against the config, naming the key at fault; it fills the
config's home configuration (``home_qpos``, rad or m per hinge/slide joint; ``home_gripper``, 0 open
.. 1 closed).
"""

from __future__ import annotations

import warnings
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING
from xml.etree import ElementTree

import mujoco
import numpy as np

from demo.errors import DemoError, one_line
from demo.sim.actuation import add_pd_layer, is_motor, is_position_servo, kind_of

if TYPE_CHECKING:  # for annotations only: demo.sim.robot imports this module
    from demo.sim.robot import RobotConfig

_HINGE_SLIDE = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))


def robot_spec(robot: RobotConfig) -> mujoco.MjSpec:
    """The robot MJCF as a spec: the configured EE site added, motor actuators made PD servos."""
    spec = file_spec(robot)
    model = _compile(robot, spec)
    motors = [a for a in _driving_actuators(model, robot) if is_motor(model, a)]
    if motors:
        add_pd_layer(spec, model, home_qpos_vector(model, robot), motors, robot.pd_kp, robot.pd_kd, robot.config_path)
    return spec


def file_spec(robot: RobotConfig) -> mujoco.MjSpec:
    """The MJCF as written, plus what the config adds without compiling it: the gripper file, names for
    unnamed actuators, the arm motors of ``add_actuators`` and the EE site (no PD layer yet)."""
    try:
        spec = mujoco.MjSpec.from_file(str(robot.mjcf_path))
    except Exception as exc:  # mujoco raises ValueError with the parser's (multi-line) message
        raise DemoError(robot.mjcf_path, f"MJCF does not load: {mujoco_message(exc)}{_named_by(robot)}") from None
    _name_actuators(spec)
    if robot.arm_prefix:
        _keep_one_arm(robot, spec)
    if robot.gripper_mjcf is not None:
        _attach_gripper(robot, spec)
        _name_actuators(spec)
    if robot.add_actuators:
        _add_arm_motors(robot, spec)
    if robot.ee_site_body:
        body = _spec_body(spec, robot.ee_site_body, name_prefixes(robot))
        if body is None:
            raise DemoError(robot.config_path, f"ee_site_body '{robot.ee_site_body}' is not a body in {robot.mjcf_path.name}; "
                                               "name a body of the hand (the EE site is added to it)")
        body.add_site(name=robot.ee_site, pos=list(robot.ee_site_pos), quat=list(robot.ee_site_quat), size=[0.006, 0, 0])
    return spec


def _add_arm_motors(robot: RobotConfig, spec: mujoco.MjSpec) -> None:
    """``add_actuators = true``: a torque motor on every arm joint no actuator drives (models published without
    actuators, which their packages add in Python); the PD layer makes each a position servo (``pd_kp``/``pd_kd``,
    default from the inertia at home), as for any motor."""
    driven = {a.target for a in spec.actuators if a.trntype == mujoco.mjtTrn.mjTRN_JOINT}
    for joint in robot.arm_joints:
        if joint not in driven:
            spec.add_actuator(name=f"{joint}_servo", target=joint, trntype=mujoco.mjtTrn.mjTRN_JOINT)


def _name_actuators(spec: mujoco.MjSpec) -> None:
    """Name every unnamed actuator after the joint or tendon it drives (``_2``, ... for a second one), so a
    TOML can name it (published scenes such as gym-aloha's leave theirs unnamed)."""
    taken = {a.name for a in spec.actuators if a.name}
    for actuator in spec.actuators:
        if actuator.name or not actuator.target:
            continue
        name, n = actuator.target, 1
        while name in taken:
            n += 1
            name = f"{actuator.target}_{n}"
        actuator.name = name
        taken.add(name)


def name_prefixes(robot: RobotConfig) -> tuple[str, ...]:
    """The prefixes a config's names may leave out: the chosen arm's (``arm_prefix``) and the gripper file's."""
    return tuple(p for p in (robot.arm_prefix, robot.gripper_prefix if robot.gripper_mjcf is not None else "") if p)


def _spec_body(spec: mujoco.MjSpec, name: str, prefixes: tuple[str, ...]) -> mujoco.MjsBody | None:
    """The body ``name``, written with or without one of ``prefixes``."""
    for full in (name, *(p + name for p in prefixes)):
        body = spec.body(full)
        if body is not None:
            return body
    return None


def with_full_names(robot: RobotConfig, model: mujoco.MjModel) -> RobotConfig:
    """The config with every name it wrote without its file's prefix (:func:`name_prefixes`) completed, as the
    compiled ``model`` spells it (``waist`` -> ``vx300s_left/waist``). Names found neither way are left for
    :func:`validated` to report."""
    prefixes = name_prefixes(robot)
    if not prefixes:
        return robot

    def full(kind: mujoco.mjtObj, name: str) -> str:
        for candidate in (name, *(p + name for p in prefixes)):
            if mujoco.mj_name2id(model, kind, candidate) >= 0:
                return candidate
        return name

    joint, actuator = mujoco.mjtObj.mjOBJ_JOINT, mujoco.mjtObj.mjOBJ_ACTUATOR
    return replace(
        robot,
        arm_joints=tuple(full(joint, j) for j in robot.arm_joints),
        gripper_actuator=full(actuator, robot.gripper_actuator),
        gripper_actuators=tuple(full(actuator, a) for a in robot.gripper_actuators),
        ee_site=full(mujoco.mjtObj.mjOBJ_SITE, robot.ee_site),
        base_body=full(mujoco.mjtObj.mjOBJ_BODY, robot.base_body),
        home_key=None if robot.home_key is None else full(mujoco.mjtObj.mjOBJ_KEY, robot.home_key),
        wrist_camera=full(mujoco.mjtObj.mjOBJ_CAMERA, robot.wrist_camera) if isinstance(robot.wrist_camera, str) else robot.wrist_camera,
    )


def _keep_one_arm(robot: RobotConfig, spec: mujoco.MjSpec) -> None:
    """``arm_prefix``: keep the top-level bodies of one arm (and ``keep_bodies``) of a file with several; the
    world's own lights, cameras, geoms and sites go too (the task scene brings its own), and with them every
    actuator of what was left out. Keyframes are rebuilt with the values of the joints and actuators kept."""
    where, fname = robot.config_path, robot.mjcf_path.name
    tops = list(spec.worldbody.bodies)
    names = [b.name for b in tops]

    def is_arm(name: str) -> bool:
        return name == robot.arm_prefix.rstrip("/") or name.startswith(robot.arm_prefix)

    if not any(is_arm(n) for n in names):
        raise DemoError(where, f"arm_prefix '{robot.arm_prefix}' names no top-level body of {fname} (it has: {', '.join(names)})")
    unknown = [b for b in robot.keep_bodies if b not in names]
    if unknown:
        raise DemoError(where, f"keep_bodies: {', '.join(unknown)} is not a top-level body of {fname} (it has: {', '.join(names)})")
    before = _keyframes(_compile(robot, spec))
    for body in tops:
        if not is_arm(body.name) and body.name not in robot.keep_bodies:
            spec.delete(body)
    world = spec.worldbody
    for element in [*world.lights, *world.cameras, *world.geoms, *world.sites]:
        spec.delete(element)
    for key in list(spec.keys):
        spec.delete(key)
    after = _compile(robot, spec)
    for name, (qpos, ctrl) in before.items():
        q, u = after.qpos0.copy(), np.zeros(after.nu)
        for j in range(after.njnt):
            if after.joint(j).name in qpos:
                adr, values = int(after.jnt_qposadr[j]), qpos[after.joint(j).name]
                q[adr:adr + len(values)] = values
        for a in range(after.nu):
            u[a] = ctrl.get(after.actuator(a).name, 0.0)
        spec.add_key(name=name, qpos=q.tolist(), ctrl=u.tolist())


def _keyframes(model: mujoco.MjModel) -> dict[str, tuple[dict[str, np.ndarray], dict[str, float]]]:
    """Each keyframe's qpos by joint name and ctrl by actuator name (named joints and actuators)."""
    widths = {int(mujoco.mjtJoint.mjJNT_FREE): 7, int(mujoco.mjtJoint.mjJNT_BALL): 4}
    out = {}
    for k in range(model.nkey):
        qpos = {model.joint(j).name: model.key_qpos[k, model.jnt_qposadr[j]:model.jnt_qposadr[j] + widths.get(int(model.jnt_type[j]), 1)].copy()
                for j in range(model.njnt) if model.joint(j).name}
        ctrl = {model.actuator(a).name: float(model.key_ctrl[k, a]) for a in range(model.nu) if model.actuator(a).name}
        out[model.key(k).name] = (qpos, ctrl)
    return out


def _attach_gripper(robot: RobotConfig, spec: mujoco.MjSpec) -> None:
    """Attach ``gripper_mjcf`` to the arm body ``gripper_mount``, its names prefixed with ``gripper_prefix``.

    A gripper file that declares no angle unit (``<compiler angle=...>``) is read in the arm's: such files
    are written to be included in an arm's MJCF (MJCF's own default, degrees, would shrink their hinge
    ranges given in radians 57-fold)."""
    try:
        gripper = mujoco.MjSpec.from_file(str(robot.gripper_mjcf))
    except Exception as exc:
        raise DemoError(robot.gripper_mjcf, f"gripper MJCF does not load: {mujoco_message(exc)}{_named_by(robot)}") from None
    if not _declares_angle_unit(robot.gripper_mjcf):
        gripper.compiler.degree = spec.compiler.degree
    mount = _spec_body(spec, str(robot.gripper_mount), name_prefixes(robot))
    if mount is None:
        raise DemoError(robot.config_path, f"gripper_mount '{robot.gripper_mount}' is not a body in {robot.mjcf_path.name}; "
                                           "name the arm's flange body")
    for key in list(gripper.keys):
        gripper.delete(key)
    for name in (n for n in dir(spec.option) if not n.startswith("_")):  # the arm's options win, silently
        setattr(gripper.option, name, getattr(spec.option, name))
    try:
        with warnings.catch_warnings():  # MjSpec warns of an empty prefix at every attach: names kept is the default here
            warnings.simplefilter("ignore", UserWarning)
            spec.attach(gripper, prefix=robot.gripper_prefix, frame=mount.add_frame())
    except Exception as exc:  # a name both files use (textures, materials: MuJoCo's "repeated name")
        raise DemoError(robot.config_path, f"gripper_mjcf {robot.gripper_mjcf.name} cannot be attached to "
                                           f"{robot.mjcf_path.name}: {mujoco_message(exc)}{_prefix_hint(exc)}") from None


def _prefix_hint(exc: BaseException) -> str:
    """For a name the arm's and the gripper's files both use: how to tell them apart."""
    return (" (both files use it: leave gripper_prefix out, or set one, so the gripper's names carry a prefix)"
            if "repeated name" in str(exc) else "")


def _declares_angle_unit(path: Path) -> bool:
    """Whether an MJCF file sets its angle unit (``<compiler angle="...">``)."""
    try:
        root = ElementTree.parse(path).getroot()
    except (ElementTree.ParseError, OSError):
        return True  # MuJoCo parsed it; leave its unit as MuJoCo read it
    return any("angle" in c.attrib for c in root.iter("compiler"))


def _compile(robot: RobotConfig, spec: mujoco.MjSpec) -> mujoco.MjModel:
    try:
        return spec.compile()
    except Exception as exc:
        if robot.gripper_mjcf is not None and not robot.gripper_prefix and "repeated name" in str(exc):
            raise DemoError(robot.config_path, f"gripper_mjcf {robot.gripper_mjcf.name} cannot be attached to "
                                               f"{robot.mjcf_path.name}: {mujoco_message(exc)}{_prefix_hint(exc)}") from None
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
    q = inside_limits(model, model.qpos0)  # some models' qpos0 lies outside a finger's range (gym-aloha's ViperX)
    for name, value in zip(robot.arm_joints, robot.home):
        j = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        if j >= 0:
            q[model.jnt_qposadr[j]] = value
    return q


def inside_limits(model: mujoco.MjModel, qpos: np.ndarray) -> np.ndarray:
    """``qpos`` with every limited hinge and slide joint clipped into its range. Some models' ``qpos0`` lies outside
    a joint's range (gym-aloha's ViperX: 0 for fingers limited to 21-57 mm), where the limit and the fingers'
    contact with each other hold them still."""
    q = qpos.copy()
    for j in range(model.njnt):
        if model.jnt_limited[j] and int(model.jnt_type[j]) in _HINGE_SLIDE:
            adr = int(model.jnt_qposadr[j])
            q[adr] = np.clip(q[adr], *model.jnt_range[j])
    return q


def mujoco_message(exc: BaseException) -> str:
    """MuJoCo's parser/compiler message on one line, without its ``Error:`` prefixes."""
    return one_line(str(exc).replace("Error: ", "")) or type(exc).__name__


def _named_by(robot: RobotConfig) -> str:
    return f" (named by {robot.config_path})" if robot.config_path and robot.config_path != robot.mjcf_path else ""


def validated(robot: RobotConfig) -> RobotConfig:
    """Compile the robot alone, check every name and actuator, and read its home configuration.

    Each error names the config key (or the MJCF element) at fault and what to write instead.
    """
    where = robot.config_path
    file_model = _compile(robot, file_spec(robot))
    robot = with_full_names(robot, file_model)
    fname = robot.mjcf_path.name
    if robot.gripper_mjcf is not None:  # a name may belong to either file: say both
        fname += f" (with {robot.gripper_mjcf.name} attached, its names prefixed '{robot.gripper_prefix}')"

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


def joint_limits(model: mujoco.MjModel, joint_ids: list[int] | np.ndarray) -> np.ndarray:
    """[n, 2] ranges of the joints (rad or m), -inf..inf where a joint is unlimited: MuJoCo keeps an unlimited
    joint's ``jnt_range`` at [0, 0], and clipping to it would pin the joint at 0."""
    ids = np.asarray(joint_ids, dtype=int)
    limited = model.jnt_limited[ids].astype(bool)[:, None]
    return np.where(limited, model.jnt_range[ids], np.array([[-np.inf, np.inf]]))


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
                               f"joint=\"{joint_name}\"); fix 'arm_joints', give it a <position> or <motor> actuator, or "
                               "set add_actuators = true (a PD servo on every arm joint without one)")
    position_gain(model, a, model.actuator(a).name or f"#{a}", where)
    return a
