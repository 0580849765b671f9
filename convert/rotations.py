"""Rotation forms, vectorised over any leading batch shape (float64 numpy).

Forms and their layouts (the last axis holds the components):

- ``mat``    [..., 3, 3]  rotation matrix, columns are the rotated frame's axes in the parent frame.
- ``quat``   [..., 4]     unit quaternion **w, x, y, z** (MuJoCo's order); :func:`mat_to_quat` returns
                          the representative with ``w >= 0``.
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
"""

from __future__ import annotations

import numpy as np

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


# ---------------------------------------------------------------------------------------------- quat
def quat_to_mat(q: np.ndarray) -> np.ndarray:
    """Quaternion (w, x, y, z) -> rotation matrix; normalises ``q`` first."""
    q = _f64(q)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz, wx, wy, wz = x * y, x * z, y * z, w * x, w * y, w * z
    R = np.stack(
        [
            1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy),
            2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx),
            2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy),
        ],
        axis=-1,
    )
    return R.reshape(*q.shape[:-1], 3, 3)


def mat_to_quat(R: np.ndarray) -> np.ndarray:
    """Rotation matrix -> quaternion (w, x, y, z) with ``w >= 0``.

    Shepperd's method: each row takes the formula whose divisor is the largest of
    ``1 + trace``, ``1 + 2 R_ii - trace``, so it is accurate for every angle up to and including pi.
    """
    R = _f64(R)
    m00, m01, m02 = R[..., 0, 0], R[..., 0, 1], R[..., 0, 2]
    m10, m11, m12 = R[..., 1, 0], R[..., 1, 1], R[..., 1, 2]
    m20, m21, m22 = R[..., 2, 0], R[..., 2, 1], R[..., 2, 2]
    trace = m00 + m11 + m22
    cand = np.stack([trace, m00, m11, m22], axis=-1)
    case = np.argmax(cand, axis=-1)
    q = np.empty(R.shape[:-2] + (4,))
    # Each case: t = 4 * (largest component)^2; compute that component from t, the rest from
    # off-diagonal sums/differences divided by it.
    t0 = 1.0 + trace
    t1 = 1.0 + m00 - m11 - m22
    t2 = 1.0 - m00 + m11 - m22
    t3 = 1.0 - m00 - m11 + m22
    with np.errstate(divide="ignore", invalid="ignore"):
        s0 = 0.5 / np.sqrt(np.maximum(t0, 1e-300))
        s1 = 0.5 / np.sqrt(np.maximum(t1, 1e-300))
        s2 = 0.5 / np.sqrt(np.maximum(t2, 1e-300))
        s3 = 0.5 / np.sqrt(np.maximum(t3, 1e-300))
        c0 = np.stack([t0 * s0, (m21 - m12) * s0, (m02 - m20) * s0, (m10 - m01) * s0], axis=-1)
        c1 = np.stack([(m21 - m12) * s1, t1 * s1, (m01 + m10) * s1, (m02 + m20) * s1], axis=-1)
        c2 = np.stack([(m02 - m20) * s2, (m01 + m10) * s2, t2 * s2, (m12 + m21) * s2], axis=-1)
        c3 = np.stack([(m10 - m01) * s3, (m02 + m20) * s3, (m12 + m21) * s3, t3 * s3], axis=-1)
    for k, c in enumerate((c0, c1, c2, c3)):
        sel = case == k
        q[sel] = c[sel]
    q *= np.where(q[..., :1] < 0, -1.0, 1.0)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a * b`` (w, x, y, z): rotate by ``b`` then by ``a``."""
    a, b = _f64(a), _f64(b)
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


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
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    q = q * np.where(q[..., :1] < 0, -1.0, 1.0)
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
def to_mat(x: np.ndarray, form: str) -> np.ndarray:
    """Any rotation form (see the module docstring) -> matrix."""
    if form == "euler":
        return euler_to_mat(x)
    if form == "rotvec":
        return rotvec_to_mat(x)
    if form == "rot6d":
        return rot6d_to_mat(x)
    if form == "quat":
        return quat_to_mat(x)
    raise ValueError(f"unknown rotation form {form!r} (known: {', '.join(ROTATION_DIMS)})")


def from_mat(R: np.ndarray, form: str) -> np.ndarray:
    """Matrix -> any rotation form."""
    if form == "euler":
        return mat_to_euler(R)
    if form == "rotvec":
        return mat_to_rotvec(R)
    if form == "rot6d":
        return mat_to_rot6d(R)
    if form == "quat":
        return mat_to_quat(R)
    raise ValueError(f"unknown rotation form {form!r} (known: {', '.join(ROTATION_DIMS)})")


def rotation_angle(R: np.ndarray) -> np.ndarray:
    """Angle (rad, in [0, pi]) of each rotation matrix; accurate for tiny angles as well."""
    q = mat_to_quat(R)
    return 2.0 * np.arctan2(np.linalg.norm(q[..., 1:], axis=-1), np.abs(q[..., 0]))


def angle_between(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Angle (rad) of the rotation taking ``Rb`` to ``Ra``: ``|log(Ra Rb^T)|``."""
    return rotation_angle(_f64(Ra) @ np.swapaxes(_f64(Rb), -1, -2))
