"""Rotations: every form, the conversions between them, and the orientation conventions of the scenes.

The one rotation module of the project (the simulator, its experts, collection and the action
converters all use it). Forms and their layouts (the last axes hold the components; the vectorised
functions accept any leading batch shape, float64 out):

- ``mat``    [..., 3, 3]  rotation matrix, columns are the rotated frame's axes in the parent frame.
- ``quat``   [..., 4]     unit quaternion **w, x, y, z** (MuJoCo's order). q and -q are one
                          rotation; :func:`canonical` picks ``w >= 0`` (what observations record).
- ``euler``  [..., 3]     roll, pitch, yaw (rad), **extrinsic x-y-z**: rotate about the fixed parent
                          x axis by roll, then fixed y by pitch, then fixed z by yaw, so
                          ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (MuJoCo ``mju_euler2Quat`` with
                          ``seq="XYZ"``; the same matrix as intrinsic z-y'-x''). Ranges returned:
                          roll, yaw in (-pi, pi], pitch in [-pi/2, pi/2]. At gimbal lock
                          (|pitch| = pi/2) roll is set to 0 and yaw carries the whole remaining angle;
                          near it the angles still reproduce the matrix to rounding error.
- ``rotvec`` [..., 3]     rotation vector axis * angle (rad), angle in [0, pi].
- ``rot6d``  [..., 6]     the first two **rows** of the matrix, ``R[0, :], R[1, :]`` (Zhou et al. 2019,
                          in the layout of pytorch3d's ``matrix_to_rotation_6d`` that Diffusion Policy
                          uses); decoded by Gram-Schmidt, so any two independent 3-vectors decode.

Quaternion <-> matrix and the quaternion product are MuJoCo's own routines (``mju_quat2Mat``,
``mju_mat2Quat``, ``mju_mulQuat``), applied rotation by rotation: the simulator's state, the
experts and the converters agree to the last bit, and collected data do not depend on which of
two formulas ran. :func:`quat_to_mat` takes a unit quaternion as it is (normalise data first,
e.g. through :func:`to_mat`); :func:`mat_to_quat` returns a unit quaternion with MuJoCo's sign.

"Down" end-effector orientations: the EE site's z axis (approach) points along -z of the base
frame and its x axis is ``(cos yaw, sin yaw, 0)``, so ``yaw`` is the gripper's heading on the table.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import mujoco
import numpy as np

from demo.sim.numeric import norm

ROTATION_DIMS: dict[str, int] = {"euler": 3, "rotvec": 3, "rot6d": 6, "quat": 4}
ROTATION_NAMES: dict[str, tuple[str, ...]] = {
    "euler": ("roll", "pitch", "yaw"),
    "rotvec": ("rx", "ry", "rz"),
    "rot6d": ("r00", "r01", "r02", "r10", "r11", "r12"),
    "quat": ("qw", "qx", "qy", "qz"),
}

# Below this angle (rad) the series expansions replace the closed forms (their error is ~angle^4).
_SMALL = 1e-6
# cos(pitch) below this counts as gimbal lock for Euler extraction (roll is then 0).
_GIMBAL_EPS = 1e-12


def _f64(x: np.ndarray) -> np.ndarray:
    return np.asarray(x, dtype=np.float64)


def _each(routine: Callable[[np.ndarray, np.ndarray], None], rows: np.ndarray, width: int) -> np.ndarray:
    """``routine(out, row)`` (a MuJoCo function of one rotation) on every row of ``rows`` [N, k]."""
    out = np.empty((len(rows), width))
    for src, dst in zip(rows, out):
        routine(dst, src)
    return out


# ---------------------------------------------------------------------------------------------- quat
def quat_to_mat(quat: np.ndarray) -> np.ndarray:
    """Unit quaternion(s) (w, x, y, z) [..., 4] -> rotation matrices [..., 3, 3] (``mju_quat2Mat``)."""
    q = np.ascontiguousarray(quat, dtype=np.float64)
    if q.ndim == 1:  # one rotation (the experts' per-step case): no batch loop
        out = np.empty(9)
        mujoco.mju_quat2Mat(out, q)
        return out.reshape(3, 3)
    return _each(mujoco.mju_quat2Mat, q.reshape(-1, 4), 9).reshape(*q.shape[:-1], 3, 3)


def mat_to_quat(mat: np.ndarray) -> np.ndarray:
    """Rotation matrices [..., 3, 3] (or MuJoCo's flat [..., 9]) -> unit quaternions (w, x, y, z)
    [..., 4] (``mju_mat2Quat``: from the largest of w, x, y, z, so accurate at every angle; the sign
    is MuJoCo's, see :func:`canonical`)."""
    R = np.ascontiguousarray(mat, dtype=np.float64)
    batch = R.shape[:-1] if R.shape[-1] == 9 else R.shape[:-2]
    if not batch:  # one rotation (observations, experts): no batch loop
        out = np.empty(4)
        mujoco.mju_mat2Quat(out, R if R.ndim == 1 else R.reshape(9))
        return out
    return _each(mujoco.mju_mat2Quat, R.reshape(-1, 9), 4).reshape(*batch, 4)


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a * b`` of two quaternions: rotate by ``b`` then by ``a`` (``mju_mulQuat``)."""
    out = np.empty(4)
    mujoco.mju_mulQuat(out, np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64))
    return out


def quat_conj(q: np.ndarray) -> np.ndarray:
    return np.array([q[0], -q[1], -q[2], -q[3]])


_CONJ = np.array([1.0, -1.0, -1.0, -1.0])  # q * _CONJ: quat_conj's numbers (x * -1.0 == -x exactly), one operation


def canonical(q: np.ndarray) -> np.ndarray:
    """The same rotation(s) with w >= 0 (q and -q are one rotation; observations use this sign)."""
    if q.ndim == 1:  # one quaternion (observations): the same choice without broadcasting
        return -q if q[0] < 0 else q.copy()
    return np.where(q[..., :1] < 0, -q, q)


def canonical_f32(q: np.ndarray) -> np.ndarray:
    """``canonical(q).astype(np.float32)`` of one quaternion, one copy fewer (observations, every step)."""
    return (-q if q[0] < 0 else q).astype(np.float32)


def quat_angle(a: np.ndarray, b: np.ndarray) -> float:
    """Angle (rad) of the rotation between two unit quaternions."""
    d = abs(float(np.dot(a, b)))
    return 2.0 * math.acos(min(1.0, d))


def axis_angle_quat(axis: np.ndarray, angle: float) -> np.ndarray:
    axis = np.asarray(axis, dtype=np.float64)
    n = norm(axis)
    if n < 1e-12 or angle == 0.0:
        return np.array([1.0, 0.0, 0.0, 0.0])
    s = math.sin(angle / 2) / n
    x, y, z = axis.tolist()  # Python floats: the same double products, without numpy scalars
    return np.array([math.cos(angle / 2), x * s, y * s, z * s])


def quat_step(current: np.ndarray, target: np.ndarray, max_angle: float) -> np.ndarray:
    """Rotate ``current`` toward ``target`` by at most ``max_angle`` rad (shortest way)."""
    current = np.asarray(current, dtype=np.float64)
    diff = np.empty(4)  # quat_mul(target, conj(current)), its wrapper left out (every control step)
    mujoco.mju_mulQuat(diff, np.asarray(target, dtype=np.float64), current * _CONJ)
    w = float(diff[0])
    if w < 0:
        diff, w = -diff, -w
    angle = 2.0 * math.acos(min(1.0, w))
    if angle <= max_angle:
        return np.array(target, dtype=np.float64)
    out = np.empty(4)
    mujoco.mju_mulQuat(out, axis_angle_quat(diff[1:], max_angle), current)
    return out / norm(out)


# ---------------------------------------------------------------------------------------------- euler
def euler_to_mat(e: np.ndarray) -> np.ndarray:
    """(roll, pitch, yaw) extrinsic x-y-z -> ``Rz(yaw) @ Ry(pitch) @ Rx(roll)``."""
    e = _f64(e)
    cr, cp, cy = np.cos(e[..., 0]), np.cos(e[..., 1]), np.cos(e[..., 2])
    sr, sp, sy = np.sin(e[..., 0]), np.sin(e[..., 1]), np.sin(e[..., 2])
    R = np.stack(
        [
            cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr,
            sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr,
            -sp, cp * sr, cp * cr,
        ],
        axis=-1,
    )
    return R.reshape(*e.shape[:-1], 3, 3)


def mat_to_euler(R: np.ndarray) -> np.ndarray:
    """Rotation matrix -> (roll, pitch, yaw), the inverse of :func:`euler_to_mat`.

    Roll comes from the last row (``atan2(R21, R22)``); yaw and pitch are then read from
    ``R @ Rx(roll)^T = Rz(yaw) Ry(pitch)``, whose entries are O(1), so the angles reproduce the
    matrix to rounding error at every pitch. Near gimbal lock (|pitch| -> pi/2) only yaw - roll
    (pitch = +pi/2) or yaw + roll (pitch = -pi/2) is well defined; once the last row's roll terms
    vanish (below 1e-12) roll is set to 0 and yaw carries the whole angle.
    """
    R = _f64(R)
    r21, r22 = R[..., 2, 1], R[..., 2, 2]
    roll = np.where(np.hypot(r21, r22) < _GIMBAL_EPS, 0.0, np.arctan2(r21, r22))
    cr, sr = np.cos(roll), np.sin(roll)
    m01 = cr * R[..., 0, 1] - sr * R[..., 0, 2]
    m11 = cr * R[..., 1, 1] - sr * R[..., 1, 2]
    m22 = sr * r21 + cr * r22
    yaw = np.arctan2(-m01, m11)
    pitch = np.arctan2(-R[..., 2, 0], m22)
    return np.stack([roll, pitch, yaw], axis=-1)


# ---------------------------------------------------------------------------------------------- rotvec
def _skew(v: np.ndarray) -> np.ndarray:
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    o = np.zeros_like(x)
    return np.stack([o, -z, y, z, o, -x, -y, x, o], axis=-1).reshape(*v.shape[:-1], 3, 3)


def rotvec_to_mat(v: np.ndarray) -> np.ndarray:
    """Rotation vector (axis * angle, rad) -> matrix (Rodrigues; Taylor series for tiny angles)."""
    v = _f64(v)
    theta = np.linalg.norm(v, axis=-1)
    small = theta < _SMALL
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    K = _skew(v)
    return np.eye(3) + a[..., None, None] * K + b[..., None, None] * (K @ K)


def quat_to_rotvec(q: np.ndarray) -> np.ndarray:
    """Quaternion -> rotation vector with angle in [0, pi] (uses the ``w >= 0`` representative)."""
    q = _f64(q)
    q = canonical(q / np.linalg.norm(q, axis=-1, keepdims=True))
    w, xyz = q[..., 0], q[..., 1:]
    s = np.linalg.norm(xyz, axis=-1)
    angle = 2.0 * np.arctan2(s, w)
    small = s < _SMALL
    # angle / s -> 2 / w (1 - s^2 / (3 w^2)) as s -> 0 (w -> 1 there, since w >= 0).
    w_safe = np.where(small, w, 1.0)  # w -> 1 where small; elsewhere w may be 0 (angle pi)
    scale = np.where(small, 2.0 / w_safe * (1.0 - s**2 / (3.0 * w_safe**2)), angle / np.where(small, 1.0, s))
    return xyz * scale[..., None]


def mat_to_rotvec(R: np.ndarray) -> np.ndarray:
    """Rotation matrix -> rotation vector, angle in [0, pi]; goes through the quaternion, so it
    stays accurate near angle pi where ``(R - R^T) / 2 sin`` breaks down."""
    return quat_to_rotvec(mat_to_quat(R))


# ---------------------------------------------------------------------------------------------- rot6d
def mat_to_rot6d(R: np.ndarray) -> np.ndarray:
    """Matrix -> its first two rows, flattened (r00 r01 r02 r10 r11 r12)."""
    R = _f64(R)
    return R[..., :2, :].reshape(*R.shape[:-2], 6)


def rot6d_to_mat(d: np.ndarray) -> np.ndarray:
    """6D -> matrix by Gram-Schmidt on the two rows; raises ValueError when they are (near) parallel
    or zero, where no rotation is defined."""
    d = _f64(d)
    a1, a2 = d[..., 0:3], d[..., 3:6]
    n1 = np.linalg.norm(a1, axis=-1, keepdims=True)
    b1 = a1 / np.where(n1 > 0, n1, 1.0)
    u2 = a2 - np.sum(b1 * a2, axis=-1, keepdims=True) * b1
    n2 = np.linalg.norm(u2, axis=-1, keepdims=True)
    bad = (n1[..., 0] < 1e-9) | (n2[..., 0] < 1e-9 * np.maximum(1.0, np.linalg.norm(a2, axis=-1)))
    if np.any(bad):
        raise ValueError("6D rotation has zero or parallel rows; it defines no rotation")
    b2 = u2 / n2
    b3 = np.cross(b1, b2)
    return np.stack([b1, b2, b3], axis=-2)


# ---------------------------------------------------------------------------------------------- dispatch
def _unit_quat_to_mat(q: np.ndarray) -> np.ndarray:
    q = _f64(q)
    return quat_to_mat(q / np.linalg.norm(q, axis=-1, keepdims=True))


def _canonical_mat_to_quat(R: np.ndarray) -> np.ndarray:
    return canonical(mat_to_quat(R))


# Quaternions in are normalised (data and network outputs are not exactly unit); out, w >= 0.
_TO_MAT = {"euler": euler_to_mat, "rotvec": rotvec_to_mat, "rot6d": rot6d_to_mat, "quat": _unit_quat_to_mat}
_FROM_MAT = {"euler": mat_to_euler, "rotvec": mat_to_rotvec, "rot6d": mat_to_rot6d, "quat": _canonical_mat_to_quat}


def _converter(table: dict[str, Callable[[np.ndarray], np.ndarray]], form: str) -> Callable[[np.ndarray], np.ndarray]:
    if form not in table:
        raise ValueError(f"unknown rotation form {form!r} (known: {', '.join(ROTATION_DIMS)})")
    return table[form]


def to_mat(x: np.ndarray, form: str) -> np.ndarray:
    """Any rotation form (see the module docstring) -> matrix; quaternions are normalised first."""
    return _converter(_TO_MAT, form)(x)


def from_mat(R: np.ndarray, form: str) -> np.ndarray:
    """Matrix -> any rotation form (quaternions with ``w >= 0``)."""
    return _converter(_FROM_MAT, form)(R)


def rotation_angle(R: np.ndarray) -> np.ndarray:
    """Angle (rad, in [0, pi]) of each rotation matrix; accurate for tiny angles as well."""
    q = mat_to_quat(R)
    return 2.0 * np.arctan2(np.linalg.norm(q[..., 1:], axis=-1), np.abs(q[..., 0]))


def angle_between(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Angle (rad) of the rotation taking ``Rb`` to ``Ra``: ``|log(Ra Rb^T)|``."""
    return rotation_angle(_f64(Ra) @ np.swapaxes(_f64(Rb), -1, -2))


# ---------------------------------------------------------------------------------------------- scenes
def down_quat(yaw: float) -> np.ndarray:
    """EE orientation pointing down (site z = -z) with site x = (cos yaw, sin yaw, 0)."""
    c, s = math.cos(yaw), math.sin(yaw)
    # columns: x = (c, s, 0), y = z cross x = (s, -c, 0), z = (0, 0, -1); row-major, flat
    out = np.empty(4)  # mat_to_quat's one-rotation case, called directly (experts, every control step)
    mujoco.mju_mat2Quat(out, np.array([c, s, 0.0, s, -c, 0.0, 0.0, 0.0, -1.0]))
    return out


def yaw_of(quat: np.ndarray) -> float:
    """Heading of a body's x axis projected on the table plane (rad)."""
    m = quat_to_mat(quat)
    return math.atan2(m[1, 0], m[0, 0])


def wrap(angle: float) -> float:
    """Angle wrapped to [-pi, pi)."""
    return (angle + math.pi) % (2 * math.pi) - math.pi


def nearest_symmetric(yaw: float, reference: float, period: float) -> float:
    """The angle ``yaw + k * period`` closest to ``reference``."""
    return reference + wrap((yaw - reference) * (2 * math.pi / period)) * (period / (2 * math.pi))


def lookat_quat(eye: np.ndarray, target: np.ndarray, up: np.ndarray = np.array([0.0, 0.0, 1.0])) -> np.ndarray:
    """Camera orientation (MuJoCo cameras look along their -z, y up) from ``eye`` to ``target``."""
    fwd = np.asarray(target, dtype=np.float64) - np.asarray(eye, dtype=np.float64)
    fwd /= np.linalg.norm(fwd)
    x = np.cross(fwd, up)
    if np.linalg.norm(x) < 1e-6:
        x = np.cross(fwd, np.array([0.0, 1.0, 0.0]))
    x /= np.linalg.norm(x)
    y = np.cross(x, fwd)
    return mat_to_quat(np.stack([x, y, -fwd], axis=1))
