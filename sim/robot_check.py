"""`demo robot check CFG`: is a robot config enough for every task?

What it measures, in order (each a field of :class:`RobotCheck`):

1. The config loads (:func:`demo.sim.robot.load_robot`: names, actuator kinds, gripper; any problem
   is one DemoError naming the robot file and what to write).
2. The arm: DOF, joint limits (rad or m) and how each joint is driven (position servo, or motor
   with the PD layer's gains, see :mod:`demo.sim.actuation`); the gripper actuators.
3. Reach: every task's scene is built and reset from ``targets`` seeds; the targets are poses
   its expert must reach (reach's goal pose; 5 cm above the goal position of push, avoid and stack;
   a top-down grasp at each object's centre and the same 10 cm above it), in the scene frame. Each is solved from the episode's start by the experts'
   IK (:meth:`demo.sim.env.Env.place_ee`, kinematics only) and counts as reached within 1 cm and
   0.1 rad. Fewer than ``MIN_REACH`` of them reached is an error naming ``base_pos``: the arm
   stands where its workspace misses the table, and the error says where to move it (:func:`base_hint`).
4. The gripper closes: from home, commanded closed for 1 s with nothing between the fingers, the
   measured closedness must pass 0.5.
5. Expert success on ``reach`` and ``pick``: ``episodes`` episodes each, seeds
   ``episode_seed(seed, i)`` as ``demo collect`` uses them.
6. A PNG of the robot at home in the ``pick`` scene, from the ``front`` camera (``png``).

``ok`` is true when 3-5 pass (IK >= ``MIN_REACH``, the gripper closes, expert success >= ``MIN_SUCCESS``).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from demo.errors import DemoError
from demo.progress import Progress, Tick, or_silent
from demo.seeds import episode_seed
from demo.sim.actuation import is_motor
from demo.sim.env import Env, make_env
from demo.sim.geometry import down_quat, quat_angle
from demo.sim.ik import ArmIK
from demo.sim.robot import RobotConfig, load_robot
from demo.sim.rollout import run_expert
from demo.sim.tasks import TASK_NAMES

MIN_REACH = 0.9  # fraction of workspace targets the IK must reach
MIN_SUCCESS = 0.9  # expert success on reach and pick
POS_TOL, ROT_TOL = 0.01, 0.1  # m, rad: a target counts as reached (reach's success tolerances)
EXPERT_TASKS = ("reach", "pick")


@dataclass
class JointInfo:
    name: str
    lower: float | None  # rad (hinge) or m (slide); None: unlimited
    upper: float | None
    actuation: str  # "position servo" or "motor + PD (kp, kd)"


@dataclass
class RobotCheck:
    robot: str
    config: str
    mjcf: str
    dof: int
    joints: list[JointInfo]
    gripper: list[str]
    base_pos: list[float]
    base_quat: list[float]
    ik: dict[str, dict[str, float]] = field(default_factory=dict)  # task -> reached, targets, rate
    gripper_closes: float | None = None  # measured closedness after 1 s commanded closed
    experts: dict[str, dict[str, float]] = field(default_factory=dict)  # task -> successes, episodes, rate
    png: str | None = None
    ok: bool = False

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def check_robot(
    config: str | Path | RobotConfig | None,
    episodes: int = 20,
    seed: int = 0,
    targets: int = 10,
    png: str | Path | None = None,
    progress: Progress | None = None,
) -> RobotCheck:
    """Run every check of the module docstring on ``config`` (None: the built-in arm)."""
    robot = load_robot(config)
    report = _describe(robot)
    tick = or_silent(progress)
    for task in TASK_NAMES:
        with make_env(task, robot=robot) as env:
            reached, total, misses, home_ee = _reach_targets(env, seed, targets)
        report.ik[task] = {"reached": reached, "targets": total, "rate": reached / max(total, 1),
                           "mean_missed_target": np.mean(misses, axis=0).tolist() if misses else home_ee.tolist(),
                           "home_ee": home_ee.tolist()}
        tick(Tick("ik", len(report.ik), len(TASK_NAMES)))
    worst = min(report.ik, key=lambda t: report.ik[t]["rate"])
    if report.ik[worst]["rate"] < MIN_REACH:
        r = report.ik[worst]
        raise DemoError(robot.config_path, f"the arm reaches {r['reached']}/{r['targets']} of the {worst} task's targets "
                                           f"(needs {MIN_REACH:.0%}): {base_hint(robot.base_pos, r['mean_missed_target'], r['home_ee'])}")
    with make_env("pick", robot=robot) as env:
        report.gripper_closes = _close_gripper(env)
    if report.gripper_closes < 0.5:
        raise DemoError(robot.config_path, f"the gripper does not close: commanded closed for 1 s it reaches closedness "
                                           f"{report.gripper_closes:.2f} of 1; check gripper_range = [open, closed] "
                                           f"(now {[list(r) for _, r in robot.grippers]}) and the gripper actuators' force")
    for task in EXPERT_TASKS:
        with make_env(task, robot=robot) as env:
            wins = 0
            for i in range(episodes):
                wins += bool(run_expert(env, episode_seed(seed, i)).success)
                tick(Tick(f"expert {task}", i + 1, episodes))
        report.experts[task] = {"successes": wins, "episodes": episodes, "rate": wins / max(episodes, 1)}
    if png is not None:
        report.png = str(render_home(robot, png))
    report.ok = all(e["rate"] >= MIN_SUCCESS for e in report.experts.values())
    return report


def _describe(robot: RobotConfig) -> RobotCheck:
    model = robot.spec().compile()
    file_model = mujoco.MjSpec.from_file(str(robot.mjcf_path)).compile()
    joints = []
    for name in robot.arm_joints:
        j = model.joint(name).id
        limited = bool(model.jnt_limited[j])
        lo, hi = (float(v) for v in model.jnt_range[j]) if limited else (None, None)
        joints.append(JointInfo(name, lo, hi, _actuation(model, file_model, j)))
    return RobotCheck(
        robot=robot.name, config=str(robot.config_path), mjcf=str(robot.mjcf_path), dof=robot.n_arm, joints=joints,
        gripper=[name for name, _ in robot.grippers], base_pos=list(robot.base_pos), base_quat=list(robot.base_quat),
    )


def _actuation(model: mujoco.MjModel, file_model: mujoco.MjModel, joint: int) -> str:
    for a in range(model.nu):
        if int(model.actuator_trntype[a]) == int(mujoco.mjtTrn.mjTRN_JOINT) and model.actuator_trnid[a, 0] == joint:
            kp, kd = float(model.actuator_gainprm[a, 0]), -float(model.actuator_biasprm[a, 2])
            if a < file_model.nu and is_motor(file_model, a):
                return f"motor + PD (kp {kp:.4g}, kd {kd:.4g})"
            return f"position servo (kp {kp:.4g}, kd {kd:.4g})"
    return "-"


def base_hint(base_pos: tuple[float, ...], mean_missed_target: list[float], home_ee: list[float]) -> str:
    """Where to move the base (scene frame, m): so that the targets it missed sit, on average, where its gripper
    is at home (in the table's plane), the arm's own working spot: that covers targets beyond its reach,
    too close under it and behind it alike."""
    move = np.asarray(mean_missed_target, dtype=float) - np.asarray(home_ee, dtype=float)
    move[2] = 0.0
    axis = int(np.argmax(np.abs(move[:2])))
    way = ("forward (+x)", "back (-x)", "left (+y)", "right (-y)")[2 * axis + (move[axis] < 0)]
    suggested = [round(float(v), 2) + 0.0 for v in np.asarray(base_pos, dtype=float) + move]
    return (f"the targets it missed lie {np.linalg.norm(move):.2f} m from where its gripper is at home; move the base "
            f"{way}: base_pos = {suggested} (now {list(base_pos)}; scene frame, m)")


def _reach_targets(env: Env, seed: int, n: int) -> tuple[int, int, list[np.ndarray], np.ndarray]:
    """(reached, tried, missed target positions, the gripper's position at home) over the poses the task's
    expert must reach, ``n`` episodes' worth (m, scene frame)."""
    reached = total = 0
    misses: list[np.ndarray] = []
    home_ee = np.zeros(3)
    ik = ArmIK(env.spec, env.robot, 1.0 / env.fps)  # the experts' IK without obstacle avoidance: reachability only
    free = [b for b in range(env.model.nbody) if any(
        int(env.model.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_FREE)
        for j in range(env.model.body_jntadr[b], env.model.body_jntadr[b] + env.model.body_jntnum[b]))]
    for i in range(n):
        s = episode_seed(seed, i)
        env.reset(s)
        poses = []
        goal = env.task.goal(env) if hasattr(env.task, "goal") else None  # type: ignore[attr-defined]
        if isinstance(goal, tuple):  # a goal pose (reach)
            poses.append(goal)
        elif goal is not None:  # a goal position (push, avoid, stack): the gripper above it, pointing down
            poses.append((np.asarray(goal) + np.array([0.0, 0.0, 0.05]), down_quat(env.home_yaw)))
        for b in free:
            pos, _ = env.body_pose(b)
            for lift in (0.0, 0.10):
                poses.append((pos + np.array([0.0, 0.0, lift]), down_quat(env.home_yaw)))
        q0 = env.data.qpos[env.arm_qadr].copy()
        env.set_arm(np.array([env.robot.home_qpos[j] for j in env.robot.arm_joints]))  # the arm's own home pose
        home_ee = env.ee_pose()[0].copy()
        for pos, quat in poses:
            q = ik.solve_pose(q0, env.to_world(pos), env.quat_to_world(quat), iters=100)
            env.set_arm(q)
            ee_pos, ee_quat = env.ee_pose()
            total += 1
            ok = bool(np.linalg.norm(ee_pos - pos) < POS_TOL and quat_angle(ee_quat, quat) < ROT_TOL)
            reached += ok
            if not ok:
                misses.append(np.asarray(pos, dtype=float))
    return reached, total, misses, home_ee


def _close_gripper(env: Env, seconds: float = 1.0) -> float:
    """Measured closedness after commanding the gripper closed at home (nothing between the fingers)."""
    env.reset(0)
    action = np.concatenate([env.data.qpos[env.arm_qadr], [1.0]])  # hold the arm where it is, close
    for _ in range(int(math.ceil(seconds * env.fps))):
        env.step(action)
    return env.gripper_closedness()


def render_home(robot: RobotConfig, path: str | Path, width: int = 640, height: int = 480) -> Path:
    """A PNG of the robot at home in the ``pick`` scene, from the ``front`` camera."""
    from PIL import Image  # deferred: Pillow only for --png

    path = Path(path)
    with make_env("pick", robot=robot, cameras=[("front", width, height)]) as env:
        env.reset(0)
        image = env.observe()["obs.image_front"]
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(image).save(path)
    return path
