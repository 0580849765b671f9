"""Retargeting: a hand pose in the robot base frame -> arm joint targets, by differential IK.

One call per control step. The retargeter runs ``iters`` IK iterations from its *last commanded*
configuration (not the measured one: retargeting is kinematic, so a pose stream gives the same
joint targets live, from a file and in the benchmark), each allowed ``1/(fps*iters)`` s of joint
motion, so the joint speed limit holds over the whole control period.

Backends (``ik=``):

- ``"mink"`` (default) reuses :class:`demo.sim.ik.ArmIK`: FrameTask on the EE site, PostureTask
  toward home, ConfigurationLimit, VelocityLimit and a CollisionAvoidanceLimit between every
  moving robot geom and the table (plus the task's own obstacles, e.g. ``avoid``'s wall).
- ``"placo"`` (:mod:`demo.collect.ik_placo`): the same tasks and limits in placo, for any
  URDF/MJCF robot pinocchio loads; the table is a linearised half-space on the EE site (offset by
  how far the fingers reach past it), the task's mocap obstacles are not modelled.

A frame is *reached* (``ok``) when the commanded configuration puts the EE site within
``pos_tol`` (m) and ``rot_tol`` (rad) of the hand pose, checked with MuJoCo's own forward
kinematics whatever the backend. Unreached frames (out of the workspace, through the table, past a
joint limit, or faster than the joints can follow) are flagged: the command is the closest the
limits allow, never a silent clip.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, NamedTuple, Protocol

import mujoco
import numpy as np

from demo.collect.ik_placo import PlacoBackend
from demo.errors import DemoError
from demo.sim.geometry import quat_angle, quat_conj, quat_mul
from demo.sim.ik import ArmIK, IKParams
from demo.sim.scene import ik_spec
from demo.store import FeatureSpec

IK_BACKENDS = ("mink", "placo")
TABLE_GEOM = "table"  # the scene's table (demo.sim.scene)


@dataclass(frozen=True)
class RetargetParams:
    iters: int = 2  # IK iterations per control step
    pos_tol: float = 0.01  # m: a hand pose counts as reached within this ...
    rot_tol: float = 0.1  # rad: ... and this
    ik: IKParams = field(
        default_factory=lambda: IKParams(
            collision_min_distance=0.002,  # m kept from the table: grasps bring fingertips ~6 mm close
            collision_detect_distance=0.05,
        )
    )


class RetargetStep(NamedTuple):
    q: np.ndarray  # (n_arm,) joint targets, rad, robot.arm_joints order
    ok: bool  # the hand pose is reached by q (within pos_tol / rot_tol)
    pos_err: float  # m, EE site at q vs hand pose
    rot_err: float  # rad


class IKBackend(Protocol):
    """One differential-IK iteration: from arm configuration ``q`` toward an EE pose (world frame)."""

    name: str

    def set_mocap(self, mocap_pos: np.ndarray, mocap_quat: np.ndarray) -> None: ...
    def iterate(self, q: np.ndarray, pos_world: np.ndarray, quat_world: np.ndarray) -> np.ndarray: ...


class MinkBackend:
    """:class:`demo.sim.ik.ArmIK` with the table added to its collision-avoidance geoms."""

    name = "mink"

    def __init__(self, env: Any, dt: float, params: IKParams):
        avoid = (TABLE_GEOM, *[g for g in env.task.avoid_geoms if g != TABLE_GEOM])
        self.ik = ArmIK(scene_spec_of(env), env.robot, dt, avoid_geoms=avoid, params=params)
        self._mocap: tuple[np.ndarray, np.ndarray] | None = None

    def set_mocap(self, mocap_pos: np.ndarray, mocap_quat: np.ndarray) -> None:
        self._mocap = (np.array(mocap_pos), np.array(mocap_quat))

    def iterate(self, q: np.ndarray, pos_world: np.ndarray, quat_world: np.ndarray) -> np.ndarray:
        mocap = self._mocap
        if mocap is not None:
            self.ik.set_state(q, *mocap)
            self._mocap = None  # static within an episode: copy once
        else:
            self.ik.set_state(q)
        return self.ik.step(pos_world, quat_world)


def scene_spec_of(env: Any) -> mujoco.MjSpec:
    """The env's scene MjSpec (robot + table + task objects), which the IK models are built from."""
    return env.spec


def make_backend(env: Any, dt: float, params: IKParams, ik: str = "mink") -> IKBackend:
    if ik == "mink":
        return MinkBackend(env, dt, params)
    if ik == "placo":
        return PlacoBackend(env, dt, params)
    raise DemoError("--ik", f"unknown IK backend {ik!r} (choose from {', '.join(IK_BACKENDS)})")


class ArmFK:
    """MuJoCo forward kinematics of the arm alone: EE site pose (base frame) at arm joints ``q``."""

    def __init__(self, env: Any):
        self.model = ik_spec(scene_spec_of(env), env.robot.arm_joints).compile()
        self.data = mujoco.MjData(self.model)
        m = self.model
        self._qadr = np.array([m.jnt_qposadr[m.joint(j).id] for j in env.robot.arm_joints])
        self._site = m.site(env.robot.ee_site).id
        self._base_pos = np.asarray(env.base.pos, dtype=np.float64)
        self._base_rot = np.asarray(env.base.rot, dtype=np.float64)
        self._base_quat_inv = quat_conj(np.asarray(env.base.quat, dtype=np.float64))
        self._quat = np.empty(4)

    def __call__(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Position (m) and quaternion (wxyz) of the EE site, base frame."""
        d = self.data
        d.qpos[self._qadr] = q
        mujoco.mj_kinematics(self.model, d)
        pos = self._base_rot.T @ (d.site_xpos[self._site] - self._base_pos)
        mujoco.mju_mat2Quat(self._quat, d.site_xmat[self._site])
        return pos, quat_mul(self._base_quat_inv, self._quat)


class Retargeter:
    """Hand poses (base frame) -> joint targets for one env, one call per control step."""

    def __init__(self, env: Any, ik: str = "mink", params: RetargetParams = RetargetParams()):
        if params.iters < 1:
            raise DemoError("retarget", "iters must be >= 1")
        self.env = env
        self.params = params
        self.dt = 1.0 / float(env.fps)
        self.backend = make_backend(env, self.dt / params.iters, params.ik, ik)
        # MuJoCo's forward kinematics is the one judge of "reached", whatever the backend.
        self.fk = ArmFK(env)
        self.fk_model, self.fk_data = self.fk.model, self.fk.data
        self._base_pos = np.asarray(env.base.pos, dtype=np.float64)
        self._base_rot = np.asarray(env.base.rot, dtype=np.float64)
        self._base_quat = np.asarray(env.base.quat, dtype=np.float64)
        self.q = np.zeros(len(env.robot.arm_joints))

    def reset(self, q_arm: np.ndarray | None = None) -> None:
        """Start from ``q_arm`` (default: the env's measured arm configuration) and its mocap poses."""
        env = self.env
        self.q = np.array(env.data.qpos[env.arm_qadr] if q_arm is None else q_arm, dtype=np.float64)
        if env.model.nmocap:
            self.backend.set_mocap(env.data.mocap_pos, env.data.mocap_quat)

    def ee_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Pose the commanded configuration puts the EE at (base frame)."""
        return self.fk(self.q)

    def __call__(self, pos: np.ndarray, quat: np.ndarray) -> RetargetStep:
        """Joint targets one control step toward the hand pose ``pos`` (m), ``quat`` (wxyz), base frame."""
        pos_w = self._base_pos + self._base_rot @ np.asarray(pos, dtype=np.float64)
        quat_w = quat_mul(self._base_quat, np.asarray(quat, dtype=np.float64))
        q = self.q
        for _ in range(self.params.iters):
            q = self.backend.iterate(q, pos_w, quat_w)
        self.q = q
        reached_pos, reached_quat = self.fk(q)
        diff = reached_pos - pos
        pos_err = math.sqrt(float(diff @ diff))
        quat = np.asarray(quat, dtype=np.float64)
        rot_err = quat_angle(reached_quat, quat / math.sqrt(float(quat @ quat)))
        ok = pos_err <= self.params.pos_tol and rot_err <= self.params.rot_tol
        return RetargetStep(q.copy(), ok, pos_err, rot_err)

    def hold(self) -> RetargetStep:
        """Keep the last command (clutch released, or no hand pose yet)."""
        return RetargetStep(self.q.copy(), True, 0.0, 0.0)


def retarget_features() -> dict[str, FeatureSpec]:
    """Per-frame keys a retargeted (or otherwise human) episode adds to ``recorded_features(env)``."""
    return {
        "info.ik_ok": FeatureSpec((1,), "bool", "the person's command was executable as given (VR: hand pose reached)", ""),
        "info.ik_error": FeatureSpec(
            (2,), "float32",
            "VR: EE at the commanded joints vs hand pose (position, rotation); kinesthetic: 0, joint-limit excess",
            "m,rad", ("pos", "rot"),
        ),
    }
