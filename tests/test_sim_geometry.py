"""Rotation helpers against MuJoCo's own conversions."""

from __future__ import annotations

import math

import numpy as np
import pytest

from demo.sim.geometry import (
    axis_angle_quat,
    canonical,
    down_quat,
    lookat_quat,
    nearest_symmetric,
    quat2mat,
    quat_angle,
    quat_conj,
    quat_mul,
    quat_step,
    wrap,
    yaw_of,
)


def test_down_quat_points_down_with_heading():
    for yaw in (-2.0, 0.0, 0.7, 3.0):
        m = quat2mat(down_quat(yaw))
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
    m = quat2mat(lookat_quat(eye, target))
    fwd = (target - eye) / np.linalg.norm(target - eye)
    np.testing.assert_allclose(-m[:, 2], fwd, atol=1e-12)
    assert m[2, 1] > 0  # image up points up
