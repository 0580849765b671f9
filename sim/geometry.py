"""Small rotation helpers. Quaternions are wxyz (MuJoCo's order), matrices are 3x3 row-major.

"Down" end-effector orientations: the EE site's z axis (approach) points along -z of the base
frame and its x axis is ``(cos yaw, sin yaw, 0)``, so ``yaw`` is the gripper's heading on the table.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np


def mat2quat(mat: np.ndarray) -> np.ndarray:
    q = np.empty(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(mat, dtype=np.float64).reshape(9))
    return q


def quat2mat(quat: np.ndarray) -> np.ndarray:
    m = np.empty(9)
    mujoco.mju_quat2Mat(m, np.asarray(quat, dtype=np.float64))
    return m.reshape(3, 3)


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    out = np.empty(4)
    mujoco.mju_mulQuat(out, np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64))
    return out


def quat_conj(q: np.ndarray) -> np.ndarray:
    return np.array([q[0], -q[1], -q[2], -q[3]])


def canonical(q: np.ndarray) -> np.ndarray:
    """The same rotation with w >= 0 (q and -q are one rotation; observations use this sign)."""
    return -q if q[0] < 0 else q


def quat_angle(a: np.ndarray, b: np.ndarray) -> float:
    """Angle (rad) of the rotation between two unit quaternions."""
    d = abs(float(np.dot(a, b)))
    return 2.0 * math.acos(min(1.0, d))


def axis_angle_quat(axis: np.ndarray, angle: float) -> np.ndarray:
    axis = np.asarray(axis, dtype=np.float64)
    n = float(np.linalg.norm(axis))
    if n < 1e-12 or angle == 0.0:
        return np.array([1.0, 0.0, 0.0, 0.0])
    s = math.sin(angle / 2) / n
    return np.array([math.cos(angle / 2), axis[0] * s, axis[1] * s, axis[2] * s])


def quat_step(current: np.ndarray, target: np.ndarray, max_angle: float) -> np.ndarray:
    """Rotate ``current`` toward ``target`` by at most ``max_angle`` rad (shortest way)."""
    diff = quat_mul(target, quat_conj(current))
    if diff[0] < 0:
        diff = -diff
    angle = 2.0 * math.acos(min(1.0, diff[0]))
    if angle <= max_angle:
        return np.array(target, dtype=np.float64)
    axis = diff[1:]
    step = axis_angle_quat(axis, max_angle)
    out = quat_mul(step, current)
    return out / np.linalg.norm(out)


def down_quat(yaw: float) -> np.ndarray:
    """EE orientation pointing down (site z = -z) with site x = (cos yaw, sin yaw, 0)."""
    c, s = math.cos(yaw), math.sin(yaw)
    # columns: x = (c, s, 0), y = z cross x = (s, -c, 0), z = (0, 0, -1)
    mat = np.array([[c, s, 0.0], [s, -c, 0.0], [0.0, 0.0, -1.0]])
    return mat2quat(mat)


def yaw_of(quat: np.ndarray) -> float:
    """Heading of a body's x axis projected on the table plane (rad)."""
    m = quat2mat(quat)
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
    return mat2quat(np.stack([x, y, -fwd], axis=1))
