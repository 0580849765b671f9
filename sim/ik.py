"""Differential IK for the arm with mink (QP solver daqp): EE pose target -> arm joint targets.

One solve per control step, from the *measured* arm configuration: ``q_cmd = q + dq`` where ``dq``
closes as much of the EE pose error as the limits allow (joint range, joint speed, and optional
collision avoidance between robot geoms and named scene geoms). The experts keep EE targets within
a few centimetres of the current pose, so one linearised step is accurate and the next step corrects
the rest. Limits are built once: ``limits=None`` makes mink rebuild them every call (2x slower).

The IK model is a copy of the scene with free objects removed and every non-arm joint frozen (see
:func:`demo.sim.scene.ik_spec`), so the QP has only the arm's degrees of freedom. Mocap bodies
(goal markers, obstacles) are copied from the simulation before each solve.

With daqp (the default), the joint range and joint speed limits, which only bound each joint's
displacement, enter the QP as daqp's simple bounds instead of rows of ``G dq <= h``: the same
problem as ``mink.solve_ik`` with the same limits (tested), solved in about half the time, which
matters because the experts solve it at every control step of every demonstration.
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
        configuration_limit = mink.ConfigurationLimit(m)
        velocity_limit = mink.VelocityLimit(m, dict(zip(robot.arm_joints, robot.max_joint_velocity)))
        self.limits: list[mink.Limit] = [configuration_limit, velocity_limit]
        # The same two limits as per-DOF bounds on dq (every DOF of the IK model is an arm joint,
        # hinge or slide, so differences of positions are plain subtractions).
        dof = np.array([m.jnt_dofadr[m.joint(j).id] for j in robot.arm_joints])
        if m.nv != len(dof) or not np.array_equal(np.sort(dof), np.arange(m.nv)):
            raise ValueError("the IK model must have exactly the arm joints as degrees of freedom")
        self._range_gain = configuration_limit.gain
        self._range_lo = np.full(m.nv, -np.inf)
        self._range_hi = np.full(m.nv, np.inf)
        self._range_lo[dof[limited]] = rng[limited, 0]
        self._range_hi[dof[limited]] = rng[limited, 1]
        self._max_step = np.full(m.nv, np.inf)
        self._max_step[dof] = np.asarray(robot.max_joint_velocity, dtype=float) * self.dt
        self._qadr_of_dof = np.zeros(m.nv, dtype=int)
        self._qadr_of_dof[dof] = self.qadr
        self._row_limits: list[mink.Limit] = []  # limits that stay rows of G dq <= h (collisions)
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
            self._row_limits.append(self.limits[-1])
        self._uses_mocap = bool(avoid_geoms) and m.nmocap > 0
        self._sense: np.ndarray | None = None  # daqp's constraint kinds (all inequalities)
        self._no_rows = np.zeros((0, m.nv))  # G when no row limit is active
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
        """One IK QP (mink's tasks and limits) solved by daqp: the joint displacement dq, or None.

        Any other ``solver`` goes through ``mink.solve_ik`` and qpsolvers unchanged.
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
        H, c = self._objective()
        q = self.configuration.q[self._qadr_of_dof]
        gain = self._range_gain
        upper = np.minimum(gain * (self._range_hi - q), self._max_step)
        lower = np.maximum(-gain * (q - self._range_lo), -self._max_step)
        rows = [limit.compute_qp_inequalities(self.configuration, self.dt) for limit in self._row_limits]
        rows = [r for r in rows if not r.inactive]
        if rows:
            G = np.vstack([r.G for r in rows])
            h = np.concatenate([r.h for r in rows])
            bupper = np.concatenate([upper, h])
            blower = np.concatenate([lower, np.full(h.shape[0], -1e30)])
        else:  # simple bounds only (most steps): the same problem without building empty rows
            G, bupper, blower = self._no_rows, upper, lower
        n = bupper.shape[0]
        if self._sense is None or self._sense.shape[0] != n:
            self._sense = np.zeros(n, dtype=ctypes.c_int)
        x, _, exitflag, _ = daqp.solve(H, c, G, bupper, blower, self._sense)
        return x if exitflag > 0 else None

    def _objective(self) -> tuple[np.ndarray, np.ndarray]:
        """The QP cost ``(H, c)`` of the tasks, assembled as ``mink.build_ik`` does."""
        jacobians, errors, mu = [], [], 0.0
        for task in self.tasks:
            weighted_jacobian, weighted_error, task_mu = task.compute_qp_residual(self.configuration)
            jacobians.append(weighted_jacobian)
            errors.append(weighted_error)
            mu += task_mu
        W = np.vstack(jacobians)
        H = W.T @ W
        H.flat[:: H.shape[0] + 1] += self.params.damping + mu
        return H, -(np.concatenate(errors) @ W)

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
