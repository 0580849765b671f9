"""Rotations (demo.sim.geometry): every form against MuJoCo's own conversions, near their
singularities, and the scenes' orientation conventions."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from demo.sim import geometry as rot
from demo.sim.geometry import (
    axis_angle_quat,
    canonical,
    down_quat,
    lookat_quat,
    nearest_symmetric,
    quat_angle,
    quat_conj,
    quat_mul,
    quat_step,
    quat_to_mat,
    wrap,
    yaw_of,
)


def test_down_quat_points_down_with_heading():
    for yaw in (-2.0, 0.0, 0.7, 3.0):
        m = quat_to_mat(down_quat(yaw))
        np.testing.assert_allclose(m[:, 2], [0, 0, -1], atol=1e-12)
        np.testing.assert_allclose(m[:, 0], [math.cos(yaw), math.sin(yaw), 0], atol=1e-12)
        assert yaw_of(down_quat(yaw)) == pytest.approx(wrap(yaw))
        assert np.linalg.det(m) == pytest.approx(1.0)


def test_quat_step_limits_the_angle():
    a = down_quat(0.0)
    b = quat_mul(axis_angle_quat(np.array([1.0, 0.0, 0.0]), 0.5), a)
    assert quat_angle(a, b) == pytest.approx(0.5)
    s = quat_step(a, b, 0.1)
    assert quat_angle(a, s) == pytest.approx(0.1) and quat_angle(s, b) == pytest.approx(0.4)
    np.testing.assert_allclose(quat_step(a, b, 1.0), b)


def test_conj_canonical_and_symmetry():
    q = axis_angle_quat(np.array([0.3, -0.2, 0.9]), 2.5)
    np.testing.assert_allclose(quat_mul(q, quat_conj(q)), [1, 0, 0, 0], atol=1e-12)
    assert canonical(-q)[0] >= 0 and quat_angle(canonical(-q), q) < 1e-7
    assert nearest_symmetric(3.0, 0.0, math.pi / 2) == pytest.approx(3.0 - math.pi)
    assert abs(nearest_symmetric(0.2, 0.0, math.pi / 2) - 0.2) < 1e-12


def test_lookat_looks_along_minus_z():
    eye, target = np.array([1.0, 0.5, 0.8]), np.array([0.3, 0.0, 0.1])
    m = quat_to_mat(lookat_quat(eye, target))
    fwd = (target - eye) / np.linalg.norm(target - eye)
    np.testing.assert_allclose(-m[:, 2], fwd, atol=1e-12)
    assert m[2, 1] > 0  # image up points up


# ------------------------------------------------------------------------------ rotation forms
def _mj_quat2mat(q: np.ndarray) -> np.ndarray:
    out = np.empty(9)
    mujoco.mju_quat2Mat(out, np.asarray(q, dtype=np.float64))
    return out.reshape(3, 3)


def _mj_mat2quat(R: np.ndarray) -> np.ndarray:
    out = np.empty(4)
    mujoco.mju_mat2Quat(out, np.ascontiguousarray(R, dtype=np.float64).reshape(9))
    return out


def _mj_euler(e: np.ndarray, seq: str) -> np.ndarray:
    out = np.empty(4)
    mujoco.mju_euler2Quat(out, np.asarray(e, dtype=np.float64), seq)
    return out


def _random_quats(n: int, seed: int = 0) -> np.ndarray:
    q = np.random.default_rng(seed).normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _orthonormal(R: np.ndarray) -> float:
    return float(np.abs(R @ np.swapaxes(R, -1, -2) - np.eye(3)).max())


def test_quat_and_matrix_are_mujocos_own_over_any_batch_shape():
    q = _random_quats(300)
    R = rot.quat_to_mat(q)
    # Bit for bit: the simulator, its experts and the converters compute the same numbers.
    assert np.array_equal(R, np.stack([_mj_quat2mat(x) for x in q]))
    back = rot.mat_to_quat(R)
    assert np.array_equal(back, np.stack([_mj_mat2quat(m) for m in R]))
    assert np.abs(canonical(back) - canonical(q)).max() < 1e-14
    assert (rot.from_mat(R, "quat")[:, 0] >= 0).all()
    assert np.array_equal(rot.quat_to_mat(q.reshape(20, 15, 4)), R.reshape(20, 15, 3, 3))
    assert np.array_equal(rot.mat_to_quat(R.reshape(300, 9)), back)  # MuJoCo's flat xmat rows
    assert rot.quat_to_mat(q[0]).shape == (3, 3) and rot.mat_to_quat(R[0]).shape == (4,)
    assert rot.quat_to_mat(np.zeros((0, 4))).shape == (0, 3, 3)


def test_euler_is_mujoco_extrinsic_xyz():
    """roll, pitch, yaw about the fixed x, y, z axes: R = Rz(yaw) Ry(pitch) Rx(roll) = mju_euler2Quat 'XYZ'."""
    e = np.random.default_rng(1).uniform(-np.pi, np.pi, (300, 3)) * [1, 0.5, 1]
    R = rot.euler_to_mat(e)
    assert np.abs(R - np.stack([_mj_quat2mat(_mj_euler(x, "XYZ")) for x in e])).max() < 1e-14
    # The same matrix is the intrinsic z-y'-x'' sequence with the angles reversed.
    assert np.abs(R - np.stack([_mj_quat2mat(_mj_euler(x[::-1], "zyx")) for x in e])).max() < 1e-14
    # Spelled out for one case: a pure yaw of +90 deg turns base x into base y.
    Ryaw = rot.euler_to_mat(np.array([0.0, 0.0, np.pi / 2]))
    assert np.allclose(Ryaw @ [1, 0, 0], [0, 1, 0])
    assert np.abs(rot.mat_to_euler(R) - e).max() < 1e-12


def test_rotvec_matches_mujoco_quat2vel_and_subquat():
    q = _random_quats(300, seed=2)
    v = rot.quat_to_rotvec(q)
    ref = np.empty((len(q), 3))
    for i, x in enumerate(q):
        mujoco.mju_quat2Vel(ref[i], x if x[0] >= 0 else -x, 1.0)
    assert np.abs(v - ref).max() < 1e-13
    assert np.abs(rot.rotvec_to_mat(v) - rot.quat_to_mat(q)).max() < 1e-14
    # mju_subQuat(qa, qb) is the rotation vector of qb^-1 qa (in qb's frame): R_b^T R_a.
    qa, qb = _random_quats(2, seed=3)
    sub = np.empty(3)
    mujoco.mju_subQuat(sub, qa, qb)
    Rrel = rot.quat_to_mat(qb).T @ rot.quat_to_mat(qa)
    assert np.abs(rot.mat_to_rotvec(Rrel) - sub).max() < 1e-12


@pytest.mark.parametrize("pitch", [np.pi / 2, -np.pi / 2, np.pi / 2 - 1e-7, -np.pi / 2 + 1e-9, np.pi / 2 - 1e-3])
def test_euler_near_gimbal_lock_reconstructs_the_matrix(pitch):
    rng = np.random.default_rng(4)
    e = np.column_stack([rng.uniform(-3, 3, 50), np.full(50, pitch), rng.uniform(-3, 3, 50)])
    R = rot.euler_to_mat(e)
    back = rot.mat_to_euler(R)
    assert np.isfinite(back).all()
    assert np.abs(rot.euler_to_mat(back) - R).max() < 1e-9
    assert np.abs(back[:, 1] - pitch).max() < 1e-6
    if abs(abs(pitch) - np.pi / 2) < 1e-12:  # exactly locked: roll is set to 0 (documented)
        assert np.all(back[:, 0] == 0.0)


def test_rotation_by_pi():
    axes = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [1, -2, 3], [-1, 0, 1e-9]], dtype=float)
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    v = axes * np.pi
    R = rot.rotvec_to_mat(v)
    back = rot.mat_to_rotvec(R)
    assert np.allclose(np.linalg.norm(back, axis=1), np.pi, atol=1e-12)
    # Axis up to sign (v and -v are the same rotation at angle pi).
    assert np.abs(np.abs(np.sum(back * axes, axis=1)) - np.pi).max() < 1e-9
    assert np.abs(rot.rotvec_to_mat(back) - R).max() < 1e-12
    # The matrix diag(1, -1, -1) (a gripper pointing down) and its quaternion/euler/6D forms.
    flip = np.diag([1.0, -1.0, -1.0])
    for form in ("quat", "euler", "rotvec", "rot6d"):
        assert np.abs(rot.to_mat(rot.from_mat(flip, form), form) - flip).max() < 1e-14
    assert np.allclose(rot.rotation_angle(flip), np.pi)
    # Just below pi: the angle stays accurate.
    near = rot.rotvec_to_mat(np.array([0.0, 0.0, np.pi - 1e-8]))
    assert abs(rot.rotation_angle(near) - (np.pi - 1e-8)) < 1e-12


def test_small_angles_keep_full_precision():
    v = np.array([[1e-9, -2e-9, 3e-10], [1e-14, 0, 0], [0, 0, 0], [2e-7, 1e-7, 0]])
    R = rot.rotvec_to_mat(v)
    assert np.abs(rot.mat_to_rotvec(R) - v).max() < 1e-20 + 1e-9 * np.abs(v).max()
    assert np.allclose(rot.rotation_angle(R), np.linalg.norm(v, axis=1), rtol=1e-6, atol=1e-22)
    assert _orthonormal(R) < 1e-15


def test_rot6d_is_first_two_rows_and_gram_schmidt():
    R = rot.quat_to_mat(_random_quats(200, seed=5))
    d = rot.mat_to_rot6d(R)
    assert np.array_equal(d[:, :3], R[:, 0]) and np.array_equal(d[:, 3:], R[:, 1])
    assert np.abs(rot.rot6d_to_mat(d) - R).max() < 1e-14
    # A network's raw output (scaled, not orthogonal) still decodes to a proper rotation.
    noisy = d * 3.0 + np.random.default_rng(6).normal(0, 0.05, d.shape)
    M = rot.rot6d_to_mat(noisy)
    assert _orthonormal(M) < 1e-14 and np.allclose(np.linalg.det(M), 1.0)
    with pytest.raises(ValueError, match="parallel"):
        rot.rot6d_to_mat(np.array([1.0, 0, 0, 2.0, 0, 0]))
    with pytest.raises(ValueError):
        rot.rot6d_to_mat(np.zeros(6))


@pytest.mark.parametrize("form", ["euler", "rotvec", "rot6d", "quat"])
def test_every_form_round_trips_random_rotations(form):
    R = rot.quat_to_mat(_random_quats(500, seed=7))
    x = rot.from_mat(R, form)
    assert x.shape == (500, rot.ROTATION_DIMS[form])
    assert np.abs(rot.to_mat(x, form) - R).max() < 1e-12
    assert rot.to_mat(x[:3].reshape(1, 3, -1), form).shape == (1, 3, 3, 3)  # any leading batch shape


def test_unknown_form_is_refused():
    with pytest.raises(ValueError, match="unknown rotation form"):
        rot.to_mat(np.zeros(3), "axis_angle")


def test_one_rotation_fast_paths_give_the_batched_numbers():
    """Single rotations skip the batch machinery (the experts' per-step case); same bits, new arrays."""
    from demo.sim.numeric import clip, norm

    rng = np.random.default_rng(0)
    qs = rng.normal(size=(200, 4))
    qs[:5, 0] = [-0.0, 0.0, -1e-300, 1e-300, -2.0]
    for q in qs:
        out = canonical(q)
        assert out.tobytes() == np.where(q[..., :1] < 0, -q, q).tobytes() and out is not q
        assert norm(q) == float(np.linalg.norm(q))
        R = quat_to_mat(q / np.linalg.norm(q))
        assert rot.mat_to_quat(R).tobytes() == rot.mat_to_quat(R[None])[0].tobytes()
        assert rot.mat_to_quat(R.reshape(9)).tobytes() == rot.mat_to_quat(R[None])[0].tobytes()
    x = np.array([-0.0, 0.0, -3.0, 3.0, np.nan, 0.5])
    lo, hi = np.array([0.0, -0.0, -1.0, -1.0, 0.0, 0.0]), np.array([1.0, 0.0, 1.0, 1.0, 1.0, 1.0])
    assert clip(x, lo, hi).tobytes() == np.clip(x, lo, hi).tobytes()  # signed zeros and NaN included


def test_quat_step_is_the_composition_of_the_public_rotations():
    """quat_step's inlined conjugate and norm: the numbers of quat_conj / np.linalg.norm."""
    rng = np.random.default_rng(3)
    for _ in range(200):
        a, b = rng.normal(size=4), rng.normal(size=4)
        a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
        max_angle = rng.uniform(0.0, 1.0)
        diff = quat_mul(b, quat_conj(a))
        diff = -diff if diff[0] < 0 else diff
        if 2.0 * math.acos(min(1.0, diff[0])) <= max_angle:
            expected = b
        else:
            axis = diff[1:]
            n = float(np.linalg.norm(axis))
            s = math.sin(max_angle / 2) / n
            step = np.array([math.cos(max_angle / 2), axis[0] * s, axis[1] * s, axis[2] * s])
            out = quat_mul(step, a)
            expected = out / np.linalg.norm(out)
        assert quat_step(a, b, max_angle).tobytes() == np.asarray(expected, dtype=np.float64).tobytes()
