"""Inverse kinematics for the way back from EE commands to joint targets (mink, daqp).

Each frame is solved to convergence by Gauss-Newton steps of ``mink.solve_ik`` (a frame task on the
EE site with gain 1 and ``dt = 1``, so each step is a full, limit-constrained Newton step),
warm-started along the episode. A redundant arm has a null space the EE pose does not fix, and the
converged solution is the one reached by least-norm steps from the warm start: warm-starting each
frame from the *measured* joints of that frame, when the data has them, picks the null-space
posture the recorded commands had (the experts' commands are IK steps from the measured state), so
the joints do not drift along an episode. Without measurements, the previous frame's solution is
the warm start. Joint limits are enforced by an explicit ``ConfigurationLimit`` built once
(``limits=None`` would rebuild it every call). Convergence is judged on the base-frame pose itself:
position error (m) and rotation angle (rad) of the EE site against the target. Frames that do not
reach the tolerances are returned with their error and flagged, never silently accepted.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import mink
import numpy as np

from demo.convert.kinematics import Kinematics
from demo.sim.geometry import angle_between


@dataclass(frozen=True)
class IKConfig:
    """Tolerances and solver settings of :class:`IKSolver` (units: m, rad)."""

    pos_tol: float = 1e-6  # converged when the EE position error is below this (m) ...
    rot_tol: float = 1e-5  # ... and the EE rotation error below this (rad)
    max_iters: int = 40  # Newton steps per frame before giving up
    damping: float = 1e-8  # Tikhonov damping on the joint step (keeps the QP strictly convex)
    lm_damping: float = 1e-3  # frame-task Levenberg-Marquardt damping (scales with the error^2)
    limit_gain: float = 0.95  # share of the distance to a joint limit one step may use
    solver: str = "daqp"


@dataclass
class IKResult:
    """One episode's IK: arm joint targets and, per frame, whether and how well it converged."""

    q: np.ndarray  # [T, n_arm]
    converged: np.ndarray  # [T] bool
    pos_err: np.ndarray  # [T] m
    rot_err: np.ndarray  # [T] rad
    iters: np.ndarray  # [T] Newton steps taken

    @property
    def failed_frames(self) -> np.ndarray:
        return np.flatnonzero(~self.converged)


class IKSolver:
    """Solves for arm joint positions that put ``kin.ee_site`` at base-frame target poses.

    Joints other than the arm's keep the values of ``rest_qpos`` (default: the model's ``qpos0``);
    their Jacobian columns are zero for the EE, so the damped step leaves them in place.
    """

    def __init__(self, kin: Kinematics, config: IKConfig | None = None, rest_qpos: np.ndarray | None = None):
        self.kin = kin
        self.config = config or IKConfig()
        model = kin.model
        self.configuration = mink.Configuration(model)
        self.task = mink.FrameTask(kin.ee_site, "site", position_cost=1.0, orientation_cost=1.0,
                                   gain=1.0, lm_damping=self.config.lm_damping)
        self.limits = [mink.ConfigurationLimit(model, gain=self.config.limit_gain)]
        self.rest = np.array(model.qpos0 if rest_qpos is None else rest_qpos, dtype=np.float64)
        # Margins keep warm starts strictly inside the limits, where mink's limit QP is feasible.
        span = kin.upper - kin.lower
        margin = np.where(np.isfinite(span), 1e-6 * np.maximum(span, 1.0), 0.0)
        self._lo, self._hi = kin.lower + margin, kin.upper - margin
        # mink logs a warning on every call when a configuration is outside the limits.
        logging.getLogger("mink").setLevel(logging.ERROR)

    def set_rest(self, qpos: np.ndarray) -> None:
        """Values for the joints IK does not move (e.g. fingers, objects) from a full ``qpos``."""
        self.rest = np.array(qpos, dtype=np.float64)

    def _pose_error(self, pos: np.ndarray, rot: np.ndarray) -> tuple[float, float]:
        d = self.configuration.data
        kin = self.kin
        Rb = d.xmat[kin.base_id].reshape(3, 3)
        p = Rb.T @ (d.site_xpos[kin.site_id] - d.xpos[kin.base_id])
        R = Rb.T @ d.site_xmat[kin.site_id].reshape(3, 3)
        return float(np.linalg.norm(p - pos)), float(angle_between(R, rot))

    def solve(self, pos: np.ndarray, rot: np.ndarray, q_init: np.ndarray) -> tuple[np.ndarray, bool, float, float, int]:
        """One target (base frame) from ``q_init``: ``(q, converged, pos_err, rot_err, iters)``."""
        cfg, kin, c = self.configuration, self.kin, self.config
        q = self.rest.copy()
        q[kin.qpos_adr] = np.clip(q_init, self._lo, self._hi)
        cfg.update(q)
        d = cfg.data
        Rb, pb = d.xmat[kin.base_id].reshape(3, 3), d.xpos[kin.base_id]
        target = np.eye(4)
        target[:3, :3] = Rb @ rot
        target[:3, 3] = pb + Rb @ pos
        self.task.set_target(mink.SE3.from_matrix(target))
        pe, re = self._pose_error(pos, rot)
        it = 0
        while (pe > c.pos_tol or re > c.rot_tol) and it < c.max_iters:
            try:
                v = mink.solve_ik(cfg, [self.task], 1.0, c.solver, damping=c.damping, limits=self.limits)
            except mink.NoSolutionFound:
                break
            cfg.integrate_inplace(v, 1.0)
            it += 1
            pe, re = self._pose_error(pos, rot)
        q_arm = cfg.q[kin.qpos_adr].copy()
        return q_arm, bool(pe <= c.pos_tol and re <= c.rot_tol), pe, re, it

    def solve_track(self, pos: np.ndarray, rot: np.ndarray, q_start: np.ndarray,
                    q_measured: np.ndarray | None = None) -> IKResult:
        """Targets [T, 3] / [T, 3, 3] solved in order. Each frame starts from ``q_measured[t]`` (the
        measured joints of that frame) when given, else from the previous solution (``q_start`` first)."""
        T = len(pos)
        out = IKResult(np.empty((T, self.kin.n_arm)), np.zeros(T, bool), np.empty(T), np.empty(T), np.zeros(T, int))
        q = np.asarray(q_start, dtype=np.float64)
        for t in range(T):
            start = q if q_measured is None else q_measured[t]
            q, ok, pe, re, it = self.solve(pos[t], rot[t], start)
            out.q[t], out.converged[t], out.pos_err[t], out.rot_err[t], out.iters[t] = q, ok, pe, re, it
        return out
