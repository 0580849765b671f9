"""`demo robot init MJCF`: write a starting robot config TOML for an arm's MJCF.

What it guesses, in order (:mod:`demo.sim.robot_guess` reads the model):

1. The arm chain, the hand and the base body from the kinematic tree; ``add_actuators = true`` when an arm
   joint has no actuator of its own (arms published without actuators).
2. The gripper actuator(s) and each one's ``gripper_range`` = [open, closed] ctrl, by simulating the gripper.
3. The EE site between the finger pads (reusing a site already there), as ``ee_site_body``/``ee_site_pos``/
   ``ee_site_quat`` in the hand body's frame.
4. The home pose: a keyframe whose EE points down over the table (``home_key``), else the experts' IK
   (:class:`demo.sim.ik.ArmIK`) solved for the EE pointing down at ``HOME_TARGET`` (scene frame, m: in
   front of the base, above the table) from several starts, keeping the solution clear of the table, with
   the gripper clear of the arm, farthest from the joint limits and elbow up (``home``).
5. Reach: from home, the IK must reach ``MIN_REACH`` of each group of the poses the tasks' experts reach
   (``DOWN``, ``TILTED``: over and past the table pointing down, and tilted and turned as reach's goals;
   1 cm / 0.1 rad, as `demo robot check` counts). Below that, base positions from
   ``BASE_MOVES`` are tried (nearest first) and the best is written as ``base_pos``.

The TOML is written to a temporary file beside ``out``, loaded with :func:`demo.sim.robot.load_robot` (every
name and actuator checked) and renamed into place, so no half-written config is left; an existing ``out``
is replaced only with ``overwrite``. Each guess that may be wrong has a ``# guessed: ...`` comment above
its key. The report (:class:`RobotInit`) lists the model's joints, actuators, bodies and sites too.
"""

from __future__ import annotations

import importlib.util
import math
import os
import textwrap
import warnings
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

import demo
from demo.errors import DemoError, one_line
from demo.sim.actuation import kind_of
from demo.sim.geometry import axis_angle_quat, down_quat, mat_to_quat, quat_angle, quat_mul
from demo.sim.ik import ArmIK
from demo.sim.robot import RobotConfig, default_gripper_prefix, load_robot, robot_from_keys
from demo.sim.robot_guess import (
    ArmGuess,
    GripperGuess,
    SiteGuess,
    gripper_actuators,
    guess_arm,
    guess_ee_site,
    guess_mount,
    simulate_gripper,
)
from demo.sim.robot_model import file_spec, is_descendant, joint_limits, mujoco_message, robot_spec
from demo.sim.scene import SCENE_CONAFFINITY, SCENE_CONTYPE, base_frame

HOME_TARGET = (0.45, 0.0, 0.25)  # m, scene frame: the EE at home, pointing down over the table
HOME_YAWS = (0.0, math.pi / 2, math.pi, -math.pi / 2)  # rad: the gripper headings tried at home
HOME_STARTS = 8  # IK starts per heading: qpos0, mid-range, then random configurations (seed 0)
IK_DT = 0.05  # s: the experts' control step, so the IK takes the experts' steps (max_joint_velocity * dt)
POS_TOL, ROT_TOL = 0.01, 0.1  # m, rad: a pose counts as reached (as `demo robot check` counts)
MIN_REACH = 0.95  # of each group of poses: `demo robot check` needs 90% of each task's targets, and these are not those
# The poses the tasks' experts reach, in two groups, as (position (m, scene frame), heading change from home (rad),
# direction of the tilt in the table plane (rad), tilt from pointing down (rad)): pointing down over the table and
# past it (pick, push, stack, avoid), and tilted and turned as reach's goals are (up to 0.35 rad, 0.8 rad).
Pose = tuple[tuple[float, float, float], float, float, float]
DOWN: list[Pose] = ([((x, y, z), 0.0, 0.0, 0.0) for x in (0.38, 0.5, 0.62) for y in (-0.25, 0.0, 0.25) for z in (0.02, 0.15, 0.3)]
                    + [((x, y, z), 0.0, 0.0, 0.0) for x, zs in ((0.28, (0.1, 0.2)), (0.68, (0.05, 0.2))) for y in (-0.08, 0.08)
                       for z in zs])  # avoid's starts and goals, near and far
TILTED: list[Pose] = [((x, y, z), turn, phi, 0.35) for x in (0.37, 0.5, 0.62) for y in (-0.2, 0.2) for z in (0.1, 0.35)
                      for turn, phi in ((0.8, math.pi), (-0.8, 0.0), (0.8, math.pi / 2), (-0.8, -math.pi / 2))]
REACH_TARGETS = len(DOWN) + len(TILTED)
BASE_MOVES = sorted(((dx, 0.0, dz) for dx in (-0.2, -0.1, -0.05, 0.0, 0.05, 0.1, 0.2, 0.3) for dz in (0.0, 0.1, 0.25, 0.4)
                     if (dx, dz) != (0.0, 0.0)), key=lambda m: math.hypot(m[0], m[2]))
TABLE_CLEARANCE = 0.1  # m: every arm link's origin above the table top at home (elbows off the table)
PENETRATION = 0.001  # m: a deeper contact at home (gripper with arm, arm with table) rules that home out
KEY_WINDOW = ((0.25, 0.75), (-0.25, 0.25), (0.05, 0.7))  # m, scene frame: a keyframe's EE over the table
COMMENT_WIDTH = 110  # characters of a TOML comment line
KEY_DOWN = math.cos(math.radians(25.0))  # a keyframe's EE z axis within 25 deg of straight down


@dataclass
class RobotInit:
    """What `demo robot init` read and wrote (JSON-able): the model's elements, the keys written, the notes."""

    out: str
    mjcf: str
    joints: list[dict[str, Any]]  # name, type, range (rad or m; None: unlimited), body, role
    actuators: list[dict[str, Any]]  # name, kind, drives, role
    bodies: list[str]
    sites: list[dict[str, str]]  # name, body
    config: dict[str, Any]  # the keys written
    notes: list[str]  # every '# guessed: ...' comment, and what was reused
    reach: dict[str, float] = field(default_factory=dict)  # IK from home: reached, targets, per group, worst group's rate
    png: str | None = None

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def init_robot(
    mjcf: str | Path,
    out: str | Path | None = None,
    gripper: str | Path | None = None,
    mount: str | None = None,
    png: str | Path | None = None,
    overwrite: bool = False,
    arm_prefix: str | None = None,
) -> RobotInit:
    """Guess a robot config for the arm MJCF ``mjcf`` (with a separate ``gripper`` MJCF attached to the arm body
    ``mount``, guessed when None) and write it to ``out`` (default: ``<model name>.toml`` in the current folder).
    ``arm_prefix``: in a file with several arms (a bimanual scene), the one to configure (see ``arm_prefix`` in
    :mod:`demo.sim.robot`)."""
    with warnings.catch_warnings():
        # A gripper attached with names kept makes every compile warn that the model may not save to XML; demo
        # never saves it (as demo.sim.scene.compile_scene drops the same warning for the scene).
        warnings.filterwarnings("ignore", message="Attaching a spec with an empty prefix")
        return _init_robot(mjcf, out, gripper, mount, png, overwrite, arm_prefix)


def _init_robot(mjcf: str | Path, out: str | Path | None, gripper: str | Path | None, mount: str | None,
                png: str | Path | None, overwrite: bool, arm_prefix: str | None) -> RobotInit:
    mjcf = Path(mjcf).expanduser().resolve()
    if not mjcf.is_file():
        raise DemoError(mjcf, "MJCF file not found")
    gripper_path = Path(gripper).expanduser().resolve() if gripper is not None else None
    if gripper_path is not None and not gripper_path.is_file():
        raise DemoError(gripper_path, "gripper MJCF file not found")
    if arm_prefix is not None and not arm_prefix:
        raise DemoError("--arm-prefix", "names the arm of a file with several (the start of its top-level body's name)")
    stub = replace(_stub(mjcf), arm_prefix=arm_prefix or "")
    arm_model = _compile(stub)
    mount_note = []
    if gripper_path is not None:
        if mount is None:
            mount = guess_mount(arm_model)
            mount_note.append(f"guessed: the gripper mounts on '{mount}', the last body of the arm's hinge chain")
        stub = _with_gripper(stub, gripper_path, mount)
        arm_model = _compile(stub)
    out_path = Path(out).expanduser() if out is not None else Path(f"{_safe_name(arm_model, mjcf)}.toml")
    if out_path.exists() and not overwrite:
        raise DemoError(out_path, "already exists; pass --overwrite to replace it")

    arm = guess_arm(arm_model, mjcf)
    undriven = [j for j in arm.arm_joints if not _has_joint_actuator(arm_model, j)]
    actuators, actuator_notes = gripper_actuators(arm_model, arm, mjcf)
    probe = replace(stub, arm_joints=arm.arm_joints, gripper_actuator=actuators[0], add_actuators=bool(undriven),
                    gripper_actuators=actuators if len(actuators) > 1 else ())
    grip = simulate_gripper(robot_spec(probe), arm, actuators, mjcf)
    site = guess_ee_site(arm_model, arm, grip)
    keys, comments = _keys(arm_model, mjcf, out_path, stub, arm, grip, site, undriven)
    comments.setdefault("gripper_mount", []).extend(mount_note)
    comments.setdefault("gripper_actuators" if len(actuators) > 1 else "gripper_actuator", []).extend(actuator_notes)
    robot = robot_from_keys({**keys, "mjcf": str(mjcf), **({"gripper_mjcf": str(gripper_path)} if gripper_path else {})},
                            out_path.parent, mjcf, default_name=str(keys["name"]))
    home = _home(robot, arm_model)
    keys.pop("home", None)
    keys.update(home.keys)
    comments.update(home.comments)

    written = _write(out_path, keys, comments, mjcf)
    report = RobotInit(
        out=str(written), mjcf=str(mjcf), joints=_joint_rows(arm_model, arm), actuators=_actuator_rows(arm_model, arm, grip),
        bodies=[arm_model.body(b).name for b in range(1, arm_model.nbody)],
        sites=[{"name": arm_model.site(s).name, "body": arm_model.body(int(arm_model.site_bodyid[s])).name}
               for s in range(arm_model.nsite)],
        config=keys, notes=[line for key in keys for line in comments.get(key, [])],
        reach={"reached": home.reached.total, "targets": REACH_TARGETS, "worst_group_rate": home.reached.rate,
               **{f"{group}_reached": n for group, n in home.reached.counts.items()}},
    )
    if png is not None:
        from demo.sim.robot_check import render_home  # deferred: the env and its tasks, for the picture only

        report.png = str(render_home(load_robot(written), png))
    return report


# ---------------------------------------------------------------- loading the MJCF
def _stub(mjcf: Path) -> RobotConfig:
    """A config naming only the MJCF, to load it the way demo loads a robot (names given to unnamed actuators)."""
    return RobotConfig(name="robot", mjcf_path=mjcf, arm_joints=(), gripper_actuator="", gripper_range=(0.0, 1.0),
                       ee_site="", base_body="", home_key=None, config_path=mjcf)


def _compile(stub: RobotConfig) -> mujoco.MjModel:
    try:
        return file_spec(stub).compile()
    except DemoError:
        raise
    except Exception as exc:  # mujoco's compiler: the message on one line
        raise DemoError(stub.mjcf_path, f"MJCF does not compile: {mujoco_message(exc)}") from None


def _with_gripper(stub: RobotConfig, gripper: Path, mount: str) -> RobotConfig:
    """The stub with the gripper attached at ``mount``, its names carrying the default prefix (the file's stem)."""
    attached = replace(stub, gripper_mjcf=gripper, gripper_mount=mount, gripper_prefix=default_gripper_prefix(gripper))
    _compile(attached)
    return attached


def _safe_name(model: mujoco.MjModel, mjcf: Path) -> str:
    name = (model.names[:model.names.index(b"\0")].decode() if model.names else "") or mjcf.stem
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in name) or "robot"


def _has_joint_actuator(model: mujoco.MjModel, joint: str) -> bool:
    j = model.joint(joint).id
    return any(int(model.actuator_trntype[a]) == int(mujoco.mjtTrn.mjTRN_JOINT) and int(model.actuator_trnid[a, 0]) == j
               for a in range(model.nu))


# ---------------------------------------------------------------- the keys
def config_path(file: Path, toml_dir: Path) -> str:
    """How a TOML in ``toml_dir`` names ``file``: ``pkg://PACKAGE/PATH`` inside an installed Python package,
    else a path relative to the TOML (absolute when that would climb more than two folders)."""
    roots = [(Path(list(demo.__path__)[0]).resolve(), "demo")]
    for parent in file.parents:
        # An installed package's folder (namespace packages have no __init__.py); not a folder that imports only
        # because the current folder or a repository root is on sys.path.
        if parent.name.isidentifier() and parent.parent.name in ("site-packages", "dist-packages"):
            try:
                found = importlib.util.find_spec(parent.name)
            except (ImportError, ValueError):
                found = None
            if found is not None and found.submodule_search_locations and \
                    Path(list(found.submodule_search_locations)[0]).resolve() == parent:
                roots.append((parent, parent.name))
    for root, package in sorted(roots, key=lambda r: -len(r[0].parts)):  # the innermost: a venv may lie inside demo's folder
        if file.is_relative_to(root):
            return f"pkg://{package}/{file.relative_to(root).as_posix()}"
    rel = Path(os.path.relpath(file, toml_dir.resolve()))
    return str(file) if rel.parts[:3] == ("..", "..", "..") else rel.as_posix()


def _keys(model: mujoco.MjModel, mjcf: Path, out: Path, stub: RobotConfig, arm: ArmGuess, grip: GripperGuess,
          site: SiteGuess, undriven: list[str]) -> tuple[dict[str, Any], dict[str, list[str]]]:
    """The config's keys (a provisional ``home`` at qpos0) and the comment lines above each."""
    keys: dict[str, Any] = {"name": out.stem, "mjcf": config_path(mjcf, out.parent)}
    comments: dict[str, list[str]] = {}
    if stub.gripper_mjcf is not None:
        keys["gripper_mjcf"] = config_path(stub.gripper_mjcf, out.parent)
        keys["gripper_mount"] = stub.gripper_mount
        comments["gripper_mjcf"] = [f"the gripper's names carry the prefix '{stub.gripper_prefix}' (its file's stem; "
                                    "names below may leave it out)"]
    if stub.arm_prefix:
        keys["arm_prefix"] = stub.arm_prefix
        comments["arm_prefix"] = [f"one arm of {mjcf.name}: its other top-level bodies (arms, table, objects) are left out "
                                  "(keep_bodies = [...] keeps some)"]
    keys["arm_joints"] = list(arm.arm_joints)
    comments["arm_joints"] = [f"the hinge joints from the base to the hand '{arm.hand_body}', in action order", *arm.notes]
    if undriven:
        keys["add_actuators"] = True
        comments["add_actuators"] = [f"no actuator drives {', '.join(undriven)}: demo adds a PD position servo on each "
                                     "(gains pd_kp/pd_kd, default from the inertia at home)"]
    elif any(_is_motor_joint(model, j) for j in arm.arm_joints):
        comments["arm_joints"].append("torque motors drive them: demo's PD layer makes them position servos (pd_kp/pd_kd)")
    if len(grip.actuators) == 1:
        keys["gripper_actuator"] = grip.actuators[0]
        keys["gripper_range"] = list(grip.ranges[0])
    else:
        keys["gripper_actuators"] = list(grip.actuators)
        same = len(set(grip.ranges)) == 1
        keys["gripper_range"] = list(grip.ranges[0]) if same else [list(r) for r in grip.ranges]
    comments["gripper_range"] = [
        f"guessed: simulated, the fingers ({', '.join(arm.finger_roots)}) spread widest at ctrl {_pairs(grip.ranges, 0)} "
        f"(open) and narrowest at {_pairs(grip.ranges, 1)} (closed); check gripper_range = [open, closed]", *grip.notes]
    if site.reuse is not None:
        keys["ee_site"] = site.reuse
    else:
        keys["ee_site"] = _free_site_name(model)
        keys["ee_site_body"] = arm.hand_body
        keys["ee_site_pos"] = list(site.pos)
        keys["ee_site_quat"] = list(site.quat)
    comments["ee_site"] = list(site.notes)
    keys["base_body"] = arm.base_body
    q0 = joint_limits(model, [model.joint(j).id for j in arm.arm_joints])
    keys["home"] = [float(np.clip(model.qpos0[model.jnt_qposadr[model.joint(j).id]], lo, hi)) for j, (lo, hi) in zip(arm.arm_joints, q0)]
    if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, "wrist") >= 0:
        keys["wrist_camera"] = "wrist"
        comments["wrist_camera"] = ["the MJCF's own camera 'wrist' renders as the wrist camera"]
    return keys, comments


def _pairs(ranges: tuple[tuple[float, float], ...], i: int) -> str:
    return "/".join(f"{r[i]:g}" for r in ranges)


def _is_motor_joint(model: mujoco.MjModel, joint: str) -> bool:
    j = model.joint(joint).id
    return any(int(model.actuator_trntype[a]) == int(mujoco.mjtTrn.mjTRN_JOINT) and int(model.actuator_trnid[a, 0]) == j
               and kind_of(model, a) == "motor" for a in range(model.nu))


def _free_site_name(model: mujoco.MjModel) -> str:
    name, n = "tcp", 1
    while mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, name) >= 0:
        n += 1
        name = f"tcp_{n}"
    return name


# ---------------------------------------------------------------- home and base
@dataclass(frozen=True)
class Reach:
    """How many poses of each group (DOWN, TILTED) the IK reached from home."""

    counts: dict[str, int]

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    @property
    def rate(self) -> float:
        """The worst group's fraction reached (`demo robot check` fails on its worst task)."""
        sizes = {"down": len(DOWN), "tilted": len(TILTED)}
        return min(n / sizes[g] for g, n in self.counts.items())

    def __str__(self) -> str:
        return f"{self.total}/{REACH_TARGETS} (down {self.counts['down']}/{len(DOWN)}, tilted {self.counts['tilted']}/{len(TILTED)})"


NONE = Reach({"down": 0, "tilted": 0})


@dataclass
class _Home:
    keys: dict[str, Any]  # home_key, or home (and base_pos)
    comments: dict[str, list[str]]
    reached: Reach  # from home


class _Kinematics:
    """The experts' IK on the robot alone, with targets in the scene frame for a base at ``base_pos``."""

    def __init__(self, robot: RobotConfig):
        spec = robot.spec()
        self.robot = robot
        self.frame = base_frame(robot, spec)
        self.ik = ArmIK(spec, robot, IK_DT)
        self.model, self.data = self.ik.model, self.ik.configuration.data
        self.site = self.model.site(robot.ee_site).id
        self.link_bodies = [int(self.model.jnt_bodyid[self.model.joint(j).id]) for j in robot.arm_joints[1:]]
        self.limits = joint_limits(self.model, [self.model.joint(j).id for j in robot.arm_joints])
        # The whole robot and a table top, for collisions at home: the gripper with the arm, the arm with the table.
        full = robot.spec()
        table = full.worldbody.add_body(name="demo_init_table", mocap=True, quat=self.frame.quat.tolist())  # moved with the base
        table.add_geom(name="demo_init_table", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[3.0, 3.0, 0.1],
                       contype=SCENE_CONTYPE, conaffinity=SCENE_CONAFFINITY)
        self.full = full.compile()
        self.full_data = mujoco.MjData(self.full)
        self.full_qadr = [int(self.full.jnt_qposadr[self.full.joint(j).id]) for j in robot.arm_joints]
        self.table = self.full.geom("demo_init_table").id
        hand = int(self.full.site_bodyid[self.full.site(robot.ee_site).id])
        self.gripper = {b for b in range(self.full.nbody) if b == hand or is_descendant(self.full, b, hand)}
        weld = self.full.body_weldid
        first = int(self.full.jnt_bodyid[self.full.joint(robot.arm_joints[0]).id])
        table_body = self.full.body("demo_init_table").id
        self.on_table = {b for b in range(self.full.nbody) if weld[b] in (0, first, table_body)}  # the base and first link stand there
        self.on_hand = {b for b in range(self.full.nbody) if weld[b] == weld[hand]}  # the flange the gripper is fixed to

    def solve(self, q0: np.ndarray, pos: tuple[float, ...], quat: np.ndarray, base: np.ndarray, iters: int) -> tuple[np.ndarray, bool]:
        """Arm joints reaching ``pos`` and ``quat`` (scene frame) for the base at ``base``, and whether they do."""
        target = self.frame.pos + self.frame.rot @ (np.asarray(pos) - base)
        quat = quat_mul(self.frame.quat, quat)
        q = self.ik.solve_pose(q0, target, quat, iters=iters)
        self.ik.set_state(q)
        err = float(np.linalg.norm(self.data.site_xpos[self.site] - target))
        turn = quat_angle(mat_to_quat(self.data.site_xmat[self.site].reshape(3, 3)), quat)
        return q, err < POS_TOL and turn < ROT_TOL

    def heights(self, q: np.ndarray, base: np.ndarray) -> np.ndarray:
        """The arm links' origins' heights above the table top (m) at ``q``."""
        self.ik.set_state(q)
        return base[2] + (self.data.xpos[self.link_bodies] - self.frame.pos) @ self.frame.rot[:, 2]

    def collides(self, q: np.ndarray, base: np.ndarray) -> bool:
        """Whether at ``q`` the gripper touches the arm, or the arm the table top (penetrating over PENETRATION)."""
        m, d = self.full, self.full_data
        d.qpos[:] = m.qpos0
        d.qpos[self.full_qadr] = q
        d.mocap_pos[0] = self.frame.pos - self.frame.rot @ base  # the table top (scene z = 0) in the robot's world
        mujoco.mj_fwdPosition(m, d)
        for g1, g2, dist in zip(d.contact.geom1[:d.ncon], d.contact.geom2[:d.ncon], d.contact.dist[:d.ncon]):
            if dist > -PENETRATION:
                continue
            b1, b2 = int(m.geom_bodyid[g1]), int(m.geom_bodyid[g2])
            if self.table in (g1, g2):
                if (b2 if g1 == self.table else b1) not in self.on_table:
                    return True
            elif (b1 in self.gripper) != (b2 in self.gripper) and not {b1, b2} & self.on_hand:
                return True
        return False

    def margin(self, q: np.ndarray) -> float:
        """The smallest distance to a joint limit, as a fraction of that joint's range (0.5 when unlimited)."""
        lo, hi = self.limits[:, 0], self.limits[:, 1]
        span = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
        frac = np.where(np.isfinite(hi - lo), np.minimum(q - lo, hi - q) / span, 0.5)
        return float(np.min(frac))

    def reach(self, q_home: np.ndarray, yaw: float, base: np.ndarray) -> Reach:
        """How many of each group of poses the IK reaches from home (``yaw``: the gripper's heading there)."""
        def quat(pose: Pose) -> np.ndarray:
            _, turn, phi, tilt = pose
            return quat_mul(axis_angle_quat(np.array([math.cos(phi), math.sin(phi), 0.0]), tilt), down_quat(yaw + turn))

        return Reach({name: sum(self.solve(q_home, p[0], quat(p), base, iters=100)[1] for p in poses)
                      for name, poses in (("down", DOWN), ("tilted", TILTED))})

    def home(self, base: np.ndarray, starts: int = HOME_STARTS, yaws: tuple[float, ...] = HOME_YAWS) -> tuple[np.ndarray, float] | None:
        """The best arm configuration with the EE pointing down at HOME_TARGET: clear of the table, the gripper
        clear of the arm, far from the joint limits, its links high (elbow up), near mid-range; None when no
        start reaches it."""
        lo, hi = self.limits[:, 0], self.limits[:, 1]
        q_zero = np.array([self.robot.home_qpos[j] for j in self.robot.arm_joints])
        finite = np.isfinite(lo) & np.isfinite(hi)
        mid = np.where(finite, (np.where(finite, lo, 0.0) + np.where(finite, hi, 0.0)) / 2, q_zero)
        rng = np.random.default_rng(0)
        firsts = [q_zero, mid] + [rng.uniform(np.maximum(lo, -math.pi), np.minimum(hi, math.pi)) for _ in range(max(0, starts - 2))]
        best: tuple[float, np.ndarray, float] | None = None
        for yaw in yaws:
            for q0 in firsts:
                q, ok = self.solve(q0, HOME_TARGET, down_quat(yaw), base, iters=300)
                if not ok:
                    continue
                heights = self.heights(q, base)
                if (heights.size and float(heights.min()) < TABLE_CLEARANCE) or self.collides(q, base):
                    continue
                # Far enough from the limits, links high (elbow up), then near mid-range (no wound-up joints).
                score = (min(self.margin(q), 0.1) + 0.5 * float(heights.mean() if heights.size else 0.0)
                         - 0.05 * float(np.mean(np.abs(q - mid))))
                if best is None or score > best[0]:
                    best = (score, q, yaw)
        return None if best is None else (best[1], best[2])


def _home(robot: RobotConfig, model: mujoco.MjModel) -> _Home:
    """home_key or home, and base_pos where the arm misses the table from the origin (module docstring)."""
    kin = _Kinematics(robot)
    origin = np.zeros(3)
    key = _keyframe_home(kin, model)
    if key is not None:
        name, q, yaw = key
        reached = kin.reach(q, yaw, origin)
        if reached.rate >= MIN_REACH:
            return _Home({"home_key": name}, {"home_key": [f"the MJCF's keyframe '{name}': the EE points down over the table; "
                                                           f"from it the IK reaches {reached} of the tasks' poses"]}, reached)
    found = kin.home(origin)
    reached = kin.reach(*found, origin) if found is not None else NONE
    if found is not None and reached.rate >= MIN_REACH:
        return _Home({"home": _rounded(found[0])}, {"home": [_home_comment(reached)]}, reached)
    at_origin = reached
    best = (reached, origin, found)
    for move in BASE_MOVES:  # nearest first: the first that reaches every pose ends the search
        base = np.array(move)
        moved = kin.home(base, starts=4, yaws=(0.0, math.pi))
        if moved is None:
            continue
        n = kin.reach(*moved, base)
        if (n.rate, n.total) > (best[0].rate, best[0].total):
            best = (n, base, moved)
        if n.total == REACH_TARGETS:
            break
    reached, base, found = best
    if found is None:
        raise DemoError(robot.mjcf_path, f"the arm cannot point its gripper down at {list(HOME_TARGET)} (scene frame, m) from "
                                         "any base position tried; write home = [...] and base_pos by hand")
    keys: dict[str, Any] = {"home": _rounded(found[0])}
    comments = {"home": [_home_comment(reached)]}
    if base.any():
        keys["base_pos"] = [round(float(v), 3) + 0.0 for v in base]
        comments["base_pos"] = [f"guessed: with the base at the scene's origin the IK reaches {at_origin} of the tasks' poses, "
                                f"moved here (m) {reached}; a base above the table stands on a riser"]
    return _Home(keys, comments, reached)


def _home_comment(reached: Reach) -> str:
    return (f"guessed: the IK's answer for the gripper pointing down {HOME_TARGET[2]} m above the table, {HOME_TARGET[0]} m in "
            f"front of the base (rad); from it the IK reaches {reached} of the tasks' poses over the table")


def _rounded(q: np.ndarray) -> list[float]:
    return [round(float(v), 4) + 0.0 for v in q]


def _keyframe_home(kin: _Kinematics, model: mujoco.MjModel) -> tuple[str, np.ndarray, float] | None:
    """A keyframe (``home`` first) whose EE points down within KEY_WINDOW over the table: (name, arm q, yaw)."""
    order = sorted(range(model.nkey), key=lambda k: model.key(k).name != "home")
    qadr = [model.jnt_qposadr[model.joint(j).id] for j in kin.robot.arm_joints]
    for k in order:
        name = model.key(k).name
        if not name or model.key_qpos.shape[1] != model.nq:
            continue
        q = model.key_qpos[k][qadr].copy()
        kin.ik.set_state(q)
        pos = kin.frame.rot.T @ (kin.data.site_xpos[kin.site] - kin.frame.pos)
        rot = kin.frame.rot.T @ kin.data.site_xmat[kin.site].reshape(3, 3)
        inside = all(lo <= v <= hi for v, (lo, hi) in zip(pos, KEY_WINDOW))
        if inside and -rot[2, 2] > KEY_DOWN:
            return name, q, math.atan2(rot[1, 0], rot[0, 0])
    return None


# ---------------------------------------------------------------- the TOML
def _toml(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, (int, float)):
        v = float(value) + 0.0
        return str(int(v)) if v.is_integer() and abs(v) < 1e15 else f"{v:.7g}"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    raise TypeError(f"no TOML form for {value!r}")


def toml_text(keys: dict[str, Any], comments: dict[str, list[str]], header: list[str]) -> str:
    """The config as TOML: ``header`` comment lines, then each key with its comment lines (if any) above it."""
    lines = [f"# {h}" for h in header]
    for key, value in keys.items():
        lines += [f"# {part}" for c in comments.get(key, []) for part in textwrap.wrap(one_line(c), COMMENT_WIDTH)]
        lines.append(f"{key} = {_toml(value)}")
    return "\n".join(lines) + "\n"


def _write(out: Path, keys: dict[str, Any], comments: dict[str, list[str]], mjcf: Path) -> Path:
    """Write the TOML beside ``out`` under a temporary name, load it (every check), then rename it into place."""
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.parent / f".{out.name}.tmp"
    header = [f"Written by `demo robot init {mjcf.name}`: a starting config. Check each '# guessed' line, then run",
              f"`demo robot check {out.name} --png home.png` (see the Robots section of docs/robots.md)."]
    try:
        tmp.write_text(toml_text(keys, comments, header))
        try:
            load_robot(tmp)
        except DemoError as exc:
            raise DemoError(mjcf, f"the config guessed does not load: {exc.problem}") from None
        os.replace(tmp, out)
    finally:
        tmp.unlink(missing_ok=True)
    return out


# ---------------------------------------------------------------- the report's lists
_JOINT_TYPES = {int(mujoco.mjtJoint.mjJNT_FREE): "free", int(mujoco.mjtJoint.mjJNT_BALL): "ball",
                int(mujoco.mjtJoint.mjJNT_SLIDE): "slide", int(mujoco.mjtJoint.mjJNT_HINGE): "hinge"}


def _finger_bodies(model: mujoco.MjModel, arm: ArmGuess) -> set[int]:
    hand = model.body(arm.hand_body).id
    out = set()
    for b in range(model.nbody):
        a = b
        while a > 0 and a != hand:
            a = int(model.body_parentid[a])
        if a == hand and b != hand:
            out.add(b)
    return out


def _joint_rows(model: mujoco.MjModel, arm: ArmGuess) -> list[dict[str, Any]]:
    fingers = _finger_bodies(model, arm)
    rows = []
    for j in range(model.njnt):
        name = model.joint(j).name
        limited = bool(model.jnt_limited[j])
        role = "arm" if name in arm.arm_joints else "finger" if int(model.jnt_bodyid[j]) in fingers else "-"
        rows.append({"name": name, "type": _JOINT_TYPES.get(int(model.jnt_type[j]), "?"),
                     "range": [float(v) for v in model.jnt_range[j]] if limited else None,
                     "body": model.body(int(model.jnt_bodyid[j])).name, "role": role})
    return rows


def _actuator_rows(model: mujoco.MjModel, arm: ArmGuess, grip: GripperGuess) -> list[dict[str, Any]]:
    rows = []
    for a in range(model.nu):
        trn, target = int(model.actuator_trntype[a]), int(model.actuator_trnid[a, 0])
        drives = (model.joint(target).name if trn == int(mujoco.mjtTrn.mjTRN_JOINT) else
                  f"tendon {model.tendon(target).name}" if trn == int(mujoco.mjtTrn.mjTRN_TENDON) else "-")
        name = model.actuator(a).name
        role = "gripper" if name in grip.actuators else "arm" if drives in arm.arm_joints else "-"
        rows.append({"name": name, "kind": kind_of(model, a), "drives": drives, "role": role})
    return rows
