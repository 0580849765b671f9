"""Differential IK for the arm with mink (QP solver daqp): EE pose target -> arm joint targets.

One solve per control step, from the *measured* arm configuration: ``q_cmd = q + dq`` where ``dq``
closes as much of the EE pose error as the limits allow (joint range, joint speed, and optional
collision avoidance between robot geoms and named scene geoms). The experts keep EE targets within
a few centimetres of the current pose, so one linearised step is accurate and the next step corrects
the rest. Limits are built once: ``limits=None`` makes mink rebuild them every call (2x slower).

The IK model is a copy of the scene with free objects removed and every non-arm joint frozen (see
:func:`demo.sim.scene.ik_spec`), so the QP has only the arm's degrees of freedom. Mocap bodies
(goal markers, obstacles) are copied from the simulation before each solve.
"""

from __future__ import annotations

import ctypes
from collections.abc import Sequence
from dataclasses import dataclass

import daqp
import mink
import mujoco
import numpy as np

from demo.sim.robot import RobotConfig
from demo.sim.scene import ik_spec


@dataclass(frozen=True)
class IKParams:
    position_cost: float = 1.0  # per m
    orientation_cost: float = 0.5  # per rad
    posture_cost: float = 5e-3  # pulls the redundant DOF toward home
    damping: float = 1e-6  # Levenberg-Marquardt damping on dq
    solver: str = "daqp"
    limit_margin: float = 1e-3  # rad kept from joint limits when reading the measured state
    collision_min_distance: float = 0.02  # m kept between robot and avoided geoms
    collision_detect_distance: float = 0.06  # m at which a pair becomes a constraint
    collision_rate: float = 0.5  # fraction of the remaining gap one step may close


class ArmIK:
    """EE-pose -> arm-joint-target solver for one env (reuses one mink.Configuration)."""

    def __init__(
        self,
        spec: mujoco.MjSpec,
        robot: RobotConfig,
        dt: float,
        avoid_geoms: Sequence[str] = (),
        params: IKParams = IKParams(),
    ):
        self.params = params
        self.dt = float(dt)
        self.model = ik_spec(spec, robot.arm_joints).compile()
        self.configuration = mink.Configuration(self.model)
        m = self.model
        self.qadr = np.array([m.jnt_qposadr[m.joint(j).id] for j in robot.arm_joints])
        rng = np.array([m.jnt_range[m.joint(j).id] for j in robot.arm_joints])
        limited = np.array([bool(m.jnt_limited[m.joint(j).id]) for j in robot.arm_joints])
        self.q_lo = np.where(limited, rng[:, 0] + params.limit_margin, -np.inf)
        self.q_hi = np.where(limited, rng[:, 1] - params.limit_margin, np.inf)
        self.q = m.qpos0.copy()

        self.frame_task = mink.FrameTask(
            robot.ee_site, "site", position_cost=params.position_cost, orientation_cost=params.orientation_cost
        )
        self.posture_task = mink.PostureTask(m, cost=params.posture_cost)
        home = m.qpos0.copy()
        for j, adr in zip(robot.arm_joints, self.qadr):
            home[adr] = robot.home_qpos[j]
        self.posture_task.set_target(home)
        self.tasks = [self.frame_task, self.posture_task]
        self.limits: list[mink.Limit] = [
            mink.ConfigurationLimit(m),
            mink.VelocityLimit(m, dict(zip(robot.arm_joints, robot.max_joint_velocity))),
        ]
        if avoid_geoms:
            robot_geoms = _moving_geoms(m)
            # mink divides the gap by dt; scaling the gain by dt makes it a per-step fraction.
            self.limits.append(
                mink.CollisionAvoidanceLimit(
                    m,
                    geom_pairs=[(robot_geoms, list(avoid_geoms))],
                    gain=min(1.0, params.collision_rate * self.dt),
                    minimum_distance_from_collisions=params.collision_min_distance,
                    collision_detection_distance=params.collision_detect_distance,
                )
            )
        self._uses_mocap = bool(avoid_geoms) and m.nmocap > 0
        self._lower: np.ndarray | None = None  # daqp's lower bounds (none) and constraint kinds
        self._sense: np.ndarray | None = None
        self._target = np.zeros(7)  # wxyz_xyz scratch
        self.failures = 0

    def set_state(self, q_arm: np.ndarray, mocap_pos: np.ndarray | None = None, mocap_quat: np.ndarray | None = None) -> None:
        """Load the measured arm configuration (clipped into the joint range) and mocap poses."""
        q = self.q
        q[self.qadr] = np.clip(q_arm, self.q_lo, self.q_hi)
        # Mocap poses only matter to the collision limit (goal markers are visual).
        if mocap_pos is not None and self._uses_mocap:
            self.configuration.data.mocap_pos[:] = mocap_pos
            self.configuration.data.mocap_quat[:] = mocap_quat
        self.configuration.update(q)

    def step(self, pos_world: np.ndarray, quat_world: np.ndarray) -> np.ndarray:
        """Arm joint targets (rad, robot.arm_joints order) one control step toward the EE pose."""
        t = self._target
        t[:4] = quat_world
        t[4:] = pos_world
        self.frame_task.set_target(mink.SE3(wxyz_xyz=t))
        dq = self._solve()
        if dq is None:
            # Rare (e.g. a learner drove the arm into a collision constraint): hold still.
            self.failures += 1
            return self.q[self.qadr].copy()
        return self.q[self.qadr] + dq[self.qadr]

    def _solve(self) -> np.ndarray | None:
        """One mink QP (tasks + limits) solved by daqp: the joint displacement dq, or None.

        Same problem as ``mink.solve_ik(..., solver="daqp")``, minus its per-call limit check (the
        state was clipped into the joint range in :meth:`set_state`) and the qpsolvers wrapper,
        which together cost about as much as the QP itself.
        """
        if self.params.solver != "daqp":
            try:
                v = mink.solve_ik(
                    self.configuration, self.tasks, self.dt, self.params.solver,
                    damping=self.params.damping, limits=self.limits,
                )
            except mink.NoSolutionFound:
                return None
            return v * self.dt
        problem = mink.build_ik(self.configuration, self.tasks, self.dt, self.params.damping, self.limits)
        G, h = problem.G, problem.h
        if G is None:
            G, h = np.zeros((0, self.model.nv)), np.zeros(0)
        if self._lower is None or self._lower.shape[0] != h.shape[0]:
            self._lower = np.full(h.shape[0], -1e30)
            self._sense = np.zeros(h.shape[0], dtype=ctypes.c_int)
        x, _, exitflag, _ = daqp.solve(problem.P, problem.q, G, h, self._lower, self._sense)
        return x if exitflag > 0 else None

    def solve_pose(
        self,
        q_arm: np.ndarray,
        pos_world: np.ndarray,
        quat_world: np.ndarray,
        mocap_pos: np.ndarray | None = None,
        mocap_quat: np.ndarray | None = None,
        iters: int = 60,
    ) -> np.ndarray:
        """Iterate kinematically (no physics) to a configuration reaching the pose; for resets."""
        q = np.array(q_arm, dtype=np.float64)
        self.set_state(q, mocap_pos, mocap_quat)
        for _ in range(iters):
            q_next = self.step(pos_world, quat_world)
            done = float(np.max(np.abs(q_next - q))) < 1e-6
            q = q_next
            self.set_state(q)
            if done:
                break
        return q


def _moving_geoms(model: mujoco.MjModel) -> list[int]:
    """Geoms on bodies that move with the arm (not welded to the world, not mocap)."""
    body = model.geom_bodyid
    return [g for g in range(model.ngeom) if model.body_weldid[body[g]] != 0 and model.body_mocapid[body[g]] < 0]
