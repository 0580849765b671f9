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
matters because the experts solve it at every control step of every demonstration. For the same
reason the QP's cost is assembled in place (:meth:`ArmIK._objective`): the posture task's weighted
Jacobian is a constant block, the frame task's residual comes from the same compiled SE(3) routines
that ``mink.FrameTask`` calls, and the products are the very ones ``mink.build_ik`` forms, so the
numbers are bit for bit mink's (tested).
"""

from __future__ import annotations

import ctypes
from collections.abc import Sequence
from dataclasses import dataclass

import daqp
import mink
import mujoco
import numpy as np

from demo.sim.numeric import clip
from demo.sim.robot import RobotConfig
from demo.sim.robot_model import joint_limits
from demo.sim.scene import ik_spec

try:  # mink's compiled SE(3) routines: what mink.FrameTask itself computes its residual with
    from mink.lie import _lie_ops_c as _se3
except ImportError:  # a mink without them: the tasks' own compute_qp_residual (same QP, slower)
    _se3 = None


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
        rng = joint_limits(m, [m.joint(j).id for j in robot.arm_joints])
        self.q_lo, self.q_hi = rng[:, 0] + params.limit_margin, rng[:, 1] - params.limit_margin  # inf stays inf

        # The measured configuration lives in the configuration's own qpos (qpos0 until set_state).
        self.q = self.configuration.data.qpos
        self.frame_task = mink.FrameTask(
            robot.ee_site, "site", position_cost=params.position_cost, orientation_cost=params.orientation_cost
        )
        self.posture_task = mink.PostureTask(m, cost=params.posture_cost)
        home = m.qpos0.copy()
        for j, adr in zip(robot.arm_joints, self.qadr):
            home[adr] = robot.home_qpos[j]
        self.posture_task.set_target(home)
        # step() writes each target into this array in place instead of building an SE3 per call.
        self.frame_task.set_target(mink.SE3(wxyz_xyz=np.array([1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])))
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
        self._range_lo[dof], self._range_hi[dof] = rng[:, 0], rng[:, 1]  # -inf..inf where unlimited
        self._max_step = np.full(m.nv, np.inf)
        self._max_step[dof] = np.asarray(robot.max_joint_velocity, dtype=float) * self.dt
        self._neg_max_step = -self._max_step
        self._qadr_of_dof = np.zeros(m.nv, dtype=int)
        self._qadr_of_dof[dof] = self.qadr
        # Usually qpos holds exactly the arm joints in their config order: plain (view) access then.
        self._arm_is_q = bool(np.array_equal(self.qadr, np.arange(m.nq)) and np.array_equal(dof, self.qadr))
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
        self._upper, self._lower = np.empty(m.nv), np.empty(m.nv)  # the per-DOF bounds on dq, per solve
        self._init_objective()
        self.failures = 0

    def _init_objective(self) -> None:
        """Buffers of the in-place QP cost (see :meth:`_objective`): ``W`` stacks the frame task's
        weighted Jacobian (6 rows, per solve) over the posture task's, ``cost * I`` (constant, as
        ``PostureTask.compute_jacobian`` weighted by ``Task._weighted_residual``); ``e`` their
        weighted errors."""
        m, nv = self.model, self.model.nv
        data = self.configuration.data
        self._site = m.site(self.frame_task.frame_name).id
        self._site_xpos, self._site_xmat = data.site_xpos[self._site], data.site_xmat[self._site]
        self._jac = np.empty((6, nv))  # mj_jacSite: translational rows, then rotational
        self._jacp, self._jacr = self._jac[:3], self._jac[3:]
        self._W = np.empty((6 + nv, nv))
        self._W[6:] = self.posture_task.cost[:, None] * np.eye(nv)
        self._e = np.empty(6 + nv)
        self._W_frame, self._e_frame, self._e_posture = self._W[:6], self._e[:6], self._e[6:]
        self._frame_cost_column = self.frame_task.cost[:, None]
        self._posture_error = np.empty(nv)
        self._H, self._c = np.empty((nv, nv)), np.empty(nv)  # the cost daqp gets, overwritten per solve
        self._H_diagonal = self._H.reshape(-1)[:: nv + 1]  # a view
        # The in-place path covers what this class builds: a site frame task and a posture task
        # without Levenberg-Marquardt terms (mink's mu is then 0) on a model without free joints.
        self._fast_objective = (
            _se3 is not None
            and self.frame_task.frame_type == "site"
            and self.frame_task.lm_damping == 0.0
            and self.posture_task.lm_damping == 0.0
            and self.posture_task._v_ids is None
        )

    def set_state(self, q_arm: np.ndarray, mocap_pos: np.ndarray | None = None, mocap_quat: np.ndarray | None = None) -> None:
        """Load the measured arm configuration (clipped into the joint range) and mocap poses."""
        if self._arm_is_q:
            clip(np.asarray(q_arm, dtype=np.float64), self.q_lo, self.q_hi, out=self.q)
        else:
            self.q[self.qadr] = np.clip(q_arm, self.q_lo, self.q_hi)
        # Mocap poses only matter to the collision limit (goal markers are visual).
        if mocap_pos is not None and self._uses_mocap:
            self.configuration.data.mocap_pos[:] = mocap_pos
            self.configuration.data.mocap_quat[:] = mocap_quat
        self.configuration.update()  # kinematics of the qpos just written (self.q is that qpos)

    def step(self, pos_world: np.ndarray, quat_world: np.ndarray) -> np.ndarray:
        """Arm joint targets (rad, robot.arm_joints order) one control step toward the EE pose."""
        target = self.frame_task.transform_target_to_world.wxyz_xyz  # the task's own copy (see __init__)
        target[:4] = quat_world
        target[4:] = pos_world
        dq = self._solve()
        if dq is None:
            # Rare (e.g. a learner drove the arm into a collision constraint): hold still.
            self.failures += 1
            return self.q[self.qadr].copy()
        if self._arm_is_q:
            return self.q + dq
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
        q = self.q if self._arm_is_q else self.q[self._qadr_of_dof]
        # The bounds of ConfigurationLimit and VelocityLimit, computed in the solver's own buffers:
        # upper = min(gain (hi - q), max_step), lower = max(-gain (q - lo), -max_step).
        upper, lower = self._upper, self._lower
        np.multiply(self._range_gain, np.subtract(self._range_hi, q, out=upper), out=upper)
        np.minimum(upper, self._max_step, out=upper)
        np.multiply(-self._range_gain, np.subtract(q, self._range_lo, out=lower), out=lower)
        np.maximum(lower, self._neg_max_step, out=lower)
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
        """The QP cost ``(H, c)`` of the tasks, assembled as ``mink.build_ik`` does.

        In place: the same operations as ``FrameTask.compute_qp_residual`` (frame pose, site
        Jacobian rotated into the frame, ``se3_rminus``, ``-jlog(T_tb) @ J``, cost weighting),
        ``PostureTask`` (``mj_differentiatePos`` from the target; its constant Jacobian block
        precomputed) and ``build_ik`` (``W^T W``, ``-e W``) on the same operands, without the
        per-call allocations and dispatch, so the result is identical (tested bit for bit).
        Products are ``np.dot``: the BLAS call that ``@`` makes for these shapes (gemm, syrk,
        gemv), without the ufunc machinery around it.
        """
        if not self._fast_objective:
            return self._task_objective()
        frame_task, posture = self.frame_task, self.posture_task
        target = frame_task.transform_target_to_world.wxyz_xyz
        xmat = self._site_xmat
        frame = _se3.xmat_xpos_to_wxyz_xyz(xmat, self._site_xpos)
        mujoco.mj_jacSite(self.model, self.configuration.data, self._jacp, self._jacr, self._site)
        body_jac = np.dot(_se3.se3_rotation_adjoint_from_xmat(xmat), self._jac)
        error = _se3.se3_rminus(target, frame)
        jacobian = np.dot(-_se3.se3_jlog(_se3.se3_inverse_multiply(target, frame)), body_jac)
        np.multiply(frame_task.cost, np.multiply(-frame_task.gain, error, out=self._e_frame), out=self._e_frame)
        np.multiply(self._frame_cost_column, jacobian, out=self._W_frame)
        mujoco.mj_differentiatePos(self.model, self._posture_error, 1.0, posture.target_q, self.q)
        np.multiply(posture.cost, np.multiply(-posture.gain, self._posture_error, out=self._e_posture), out=self._e_posture)
        W, H, c = self._W, self._H, self._c
        np.dot(W.T, W, out=H)
        self._H_diagonal += self.params.damping  # + mink's mu, which is 0 without LM damping
        np.dot(self._e, W, out=c)
        np.negative(c, out=c)
        return H, c

    def _task_objective(self) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_objective` through the tasks' own ``compute_qp_residual`` (any task setup)."""
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
