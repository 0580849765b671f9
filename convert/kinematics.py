"""Batched forward kinematics of an arm's end-effector site, in the robot base frame.

:class:`Kinematics` reads the kinematic chain from the robot's base body to the body holding the
EE site out of a compiled ``mujoco.MjModel`` (body offsets, joint axes and anchors, ``qpos0``) and
evaluates it for many frames at once with numpy, applying the exact operations of MuJoCo's
``mj_kinematics`` (hinge: rotate about the joint axis through its anchor by ``qpos - qpos0``;
slide: translate along the axis by ``qpos - qpos0``). The result equals MuJoCo's
``site_xpos``/``site_xmat`` expressed in the base frame to ~1e-15; :meth:`Kinematics.fk_mujoco`
computes the same with a plain ``mj_kinematics`` loop and :meth:`Kinematics.verify` compares the two.

Frames and units: positions in m, rotations as 3x3 matrices (columns = EE axes) in the frame of
``base_body``. Only the joints on the base -> EE chain move the EE; each must be one of the arm
joints (the action's joints), and each must be a hinge or slide joint.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from demo.errors import DemoError
from demo.sim.geometry import angle_between, quat_to_mat
from demo.sim.robot_model import joint_limits

_HINGE = int(mujoco.mjtJoint.mjJNT_HINGE)
_SLIDE = int(mujoco.mjtJoint.mjJNT_SLIDE)
_CHUNK = 4096  # frames per block: keeps the working set of the chain product in cache


@dataclass(frozen=True)
class _Step:
    """One operation of the chain: a fixed body offset, or one joint."""

    kind: str  # "body" | "hinge" | "slide"
    pos: np.ndarray  # body: offset in the parent frame; joint: anchor in the body frame
    rot: np.ndarray | None = None  # body: fixed rotation relative to the parent (None: identity)
    axis: np.ndarray | None = None  # joint axis in the body frame (unit)
    col: int = -1  # joint: column of q holding its value
    qpos0: float = 0.0


class Kinematics:
    """FK of ``ee_site`` relative to ``base_body`` as a function of the arm joints' positions.

    ``q`` arrays hold the arm joints in ``arm_joints`` order (the joint part of a ``joint_pos``
    action), shape ``[N, n_arm]``.
    """

    def __init__(self, model: mujoco.MjModel, arm_joints: Sequence[str], ee_site: str, base_body: str,
                 where: object = None):
        self.model = model
        self.arm_joints = tuple(arm_joints)
        self.ee_site, self.base_body = ee_site, base_body
        where = where if where is not None else "robot"
        site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, ee_site)
        base = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, base_body)
        if site < 0:
            raise DemoError(where, f"ee site '{ee_site}' is not in the model")
        if base < 0:
            raise DemoError(where, f"base body '{base_body}' is not in the model")
        self.site_id, self.base_id = site, base
        self.joint_ids = []
        for name in self.arm_joints:
            j = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
            if j < 0:
                raise DemoError(where, f"arm joint '{name}' is not in the model")
            self.joint_ids.append(j)
        self.qpos_adr = np.array([model.jnt_qposadr[j] for j in self.joint_ids], dtype=np.int64)
        self.dof_adr = np.array([model.jnt_dofadr[j] for j in self.joint_ids], dtype=np.int64)
        self.lower, self.upper = joint_limits(model, self.joint_ids).T
        self._steps = self._chain(where)
        self.site_pos = model.site_pos[site].astype(np.float64).copy()
        self.site_rot = _rot_or_none(model.site_quat[site])
        self._data = mujoco.MjData(model)

    @property
    def n_arm(self) -> int:
        return len(self.arm_joints)

    # ------------------------------------------------------------------------------ chain
    def _chain(self, where: object) -> list[_Step]:
        m = self.model
        bodies = []
        b = int(m.site_bodyid[self.site_id])
        while b != self.base_id:
            if b == 0:
                raise DemoError(where, f"ee site '{self.ee_site}' is not attached below base body '{self.base_body}'")
            bodies.append(b)
            b = int(m.body_parentid[b])
        col_of = {j: c for c, j in enumerate(self.joint_ids)}
        steps: list[_Step] = []
        for b in reversed(bodies):
            steps.append(_Step("body", m.body_pos[b].astype(np.float64).copy(), _rot_or_none(m.body_quat[b])))
            for j in range(m.body_jntadr[b], m.body_jntadr[b] + m.body_jntnum[b]):
                name = m.joint(j).name
                if j not in col_of:
                    raise DemoError(where, f"joint '{name}' moves the ee site but is not one of the arm joints")
                kind = {_HINGE: "hinge", _SLIDE: "slide"}.get(int(m.jnt_type[j]))
                if kind is None:
                    raise DemoError(where, f"joint '{name}' on the ee chain must be a hinge or slide joint")
                axis = m.jnt_axis[j].astype(np.float64)
                steps.append(
                    _Step(kind, m.jnt_pos[j].astype(np.float64).copy(), axis=axis / np.linalg.norm(axis),
                          col=col_of[j], qpos0=float(m.qpos0[m.jnt_qposadr[j]]))
                )
        return steps

    # ------------------------------------------------------------------------------ FK
    def fk(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """EE pose for each row of ``q`` [N, n_arm] (rad or m): positions [N, 3], rotations [N, 3, 3]."""
        q = np.asarray(q, dtype=np.float64)
        if q.ndim != 2 or q.shape[1] != self.n_arm:
            raise ValueError(f"q must be [N, {self.n_arm}], got {q.shape}")
        n = len(q)
        pos = np.empty((n, 3))
        rot = np.empty((n, 3, 3))
        for a in range(0, n, _CHUNK):
            pos[a:a + _CHUNK], rot[a:a + _CHUNK] = self._fk_block(q[a:a + _CHUNK])
        return pos, rot

    def _fk_block(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # Columns-of-R layout: C[j] is column j of every frame's rotation, shape [3, n], so that
        # products with the chain's constant matrices (mostly 0 and +-1 entries) are a few
        # scaled adds of contiguous vectors, with zero terms skipped.
        n = len(q)
        C = np.zeros((3, 3, n))
        C[0, 0] = C[1, 1] = C[2, 2] = 1.0
        p = np.zeros((3, n))
        for s in self._steps:
            if s.kind == "body":
                p += _rotate(C, s.pos)
                C = _times_const(C, s.rot)
                continue
            angle = q[:, s.col] - s.qpos0
            if s.kind == "slide":
                p += _rotate(C, s.axis) * angle
                continue
            # Hinge through anchor c (body frame): R' = R Rot(axis, angle), p' = p + R c - R' c.
            anchor = bool(s.pos.any())
            if anchor:
                p += _rotate(C, s.pos)
            C = _times_axis_angle(C, s.axis, np.cos(angle), np.sin(angle))
            if anchor:
                p -= _rotate(C, s.pos)
        p = p + _rotate(C, self.site_pos)
        C = _times_const(C, self.site_rot)
        return np.ascontiguousarray(p.T), np.ascontiguousarray(C.transpose(2, 1, 0))

    def fk_mujoco(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The same as :meth:`fk` with a ``mj_kinematics`` loop (the reference; ~20x slower)."""
        q = np.asarray(q, dtype=np.float64)
        m, d = self.model, self._data
        d.qpos[:] = m.qpos0
        pos = np.empty((len(q), 3))
        rot = np.empty((len(q), 3, 3))
        for i in range(len(q)):
            d.qpos[self.qpos_adr] = q[i]
            mujoco.mj_kinematics(m, d)
            Rb = d.xmat[self.base_id].reshape(3, 3)
            pos[i] = Rb.T @ (d.site_xpos[self.site_id] - d.xpos[self.base_id])
            rot[i] = Rb.T @ d.site_xmat[self.site_id].reshape(3, 3)
        return pos, rot

    def verify(self, q: np.ndarray) -> tuple[float, float]:
        """Max position (m) and rotation (rad) difference between :meth:`fk` and ``mj_kinematics``."""
        p1, R1 = self.fk(q)
        p2, R2 = self.fk_mujoco(q)
        return float(np.abs(p1 - p2).max(initial=0.0)), float(angle_between(R1, R2).max(initial=0.0))

    # ------------------------------------------------------------------------------ helpers
    def base_pose_world(self, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
        """World pose of the base body in ``data`` (after kinematics)."""
        return data.xpos[self.base_id].copy(), data.xmat[self.base_id].reshape(3, 3).copy()

    def arm_qpos(self, data: mujoco.MjData) -> np.ndarray:
        return data.qpos[self.qpos_adr].copy()

    def random_q(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` joint vectors drawn uniformly within the joint limits ([-pi, pi] where unlimited)."""
        lo = np.where(np.isfinite(self.lower), self.lower, -np.pi)
        hi = np.where(np.isfinite(self.upper), self.upper, np.pi)
        return rng.uniform(lo, hi, size=(n, self.n_arm))


def _rot_or_none(quat: np.ndarray) -> np.ndarray | None:
    """Rotation matrix of ``quat``, or None when it is the identity (the product is skipped)."""
    R = quat_to_mat(quat)
    return None if np.array_equal(R, np.eye(3)) else R


def _axpy_terms(C: np.ndarray, coef: np.ndarray) -> np.ndarray:
    """sum_j C[j] * coef[j] for constant coefficients; zero terms are skipped, +-1 cost no multiply."""
    out: np.ndarray | None = None
    for j in range(3):
        a = float(coef[j])
        if abs(a) < 1e-15:
            continue
        if out is None:
            out = C[j].copy() if a == 1.0 else C[j] * a
        elif a == 1.0:
            out += C[j]
        elif a == -1.0:
            out -= C[j]
        else:
            out += C[j] * a
    return np.zeros_like(C[0]) if out is None else out


def _rotate(C: np.ndarray, v: np.ndarray) -> np.ndarray:
    """R @ v for every frame ([3, n]) given R's columns C."""
    return _axpy_terms(C, v)


def _times_const(C: np.ndarray, M: np.ndarray | None) -> np.ndarray:
    """Columns of R @ M for a constant 3x3 M (None: identity)."""
    if M is None:
        return C
    return np.stack([_axpy_terms(C, M[:, k]) for k in range(3)])


def _times_axis_angle(C: np.ndarray, axis: np.ndarray, c: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Columns of R @ Rot(axis, angle) given cos/sin per frame ([n])."""
    for k in range(3):  # a coordinate axis: a plane rotation of the two other columns
        if abs(abs(axis[k]) - 1.0) < 1e-15:
            i, j = (k + 1) % 3, (k + 2) % 3
            s = s * np.sign(axis[k])
            out = np.empty_like(C)
            out[k] = C[k]
            out[i] = C[i] * c + C[j] * s
            out[j] = C[j] * c - C[i] * s
            return out
    # General axis (Rodrigues): R Rot = c R + s R [a]x + (1 - c) (R a) a^T.
    K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    Ra = _axpy_terms(C, axis)
    RK = _times_const(C, K)
    return np.stack([C[k] * c + RK[k] * s + Ra * ((1.0 - c) * axis[k]) for k in range(3)])
