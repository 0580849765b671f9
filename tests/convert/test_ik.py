"""mink IK for the way back: converges on reachable trajectories, respects limits, flags failures."""

from __future__ import annotations

import numpy as np
import pytest

from demo.convert.ik import IKConfig, IKSolver
from demo.convert.kinematics import Kinematics
from demo.sim import geometry as rot


@pytest.fixture(scope="module")
def kin() -> Kinematics:
    from demo.sim import load_robot

    robot = load_robot(None)
    return Kinematics(robot.spec().compile(), robot.arm_joints, robot.ee_site, robot.base_body)


def _home(kin: Kinematics) -> np.ndarray:
    from demo.sim import load_robot

    robot = load_robot(None)
    return np.array([robot.home_qpos[j] for j in robot.arm_joints])


def test_smooth_trajectory_converges_to_tolerance(kin):
    rng = np.random.default_rng(0)
    home = _home(kin)
    q = np.clip(home + np.cumsum(rng.normal(0, 0.01, (150, 7)), axis=0), kin.lower, kin.upper)
    pos, R = kin.fk(q)
    config = IKConfig()
    result = IKSolver(kin, config).solve_track(pos, R, home)
    assert result.converged.all()
    assert result.pos_err.max() <= config.pos_tol and result.rot_err.max() <= config.rot_tol
    # The errors it reports are the real ones: recompute them with FK.
    p2, R2 = kin.fk(result.q)
    assert np.abs(np.linalg.norm(p2 - pos, axis=1) - result.pos_err).max() < 1e-12
    assert rot.angle_between(R2, R).max() <= config.rot_tol
    assert result.iters.mean() < 4  # warm starts: a couple of Newton steps per frame


def test_solutions_stay_within_joint_limits(kin):
    rng = np.random.default_rng(1)
    # Targets from configurations close to the limits of joints 4 and 6.
    q = kin.random_q(40, rng)
    q[:, 3] = kin.upper[3] - 0.01
    q[:, 5] = kin.lower[5] + 0.01
    pos, R = kin.fk(q)
    solver = IKSolver(kin)
    for i in range(len(q)):
        start = np.clip(q[i] + rng.normal(0, 0.05, 7), kin.lower, kin.upper)
        sol, ok, pe, re, _ = solver.solve(pos[i], R[i], start)
        assert (sol >= kin.lower - 1e-9).all() and (sol <= kin.upper + 1e-9).all()
        assert ok and pe < 1e-5 and re < 1e-4


def test_unreachable_targets_are_reported_not_hidden(kin):
    home = _home(kin)
    pos, R = kin.fk(home[None])
    targets = np.repeat(pos, 3, axis=0)
    targets[1] = [2.0, 0.0, 0.5]  # 2 m away: out of reach
    result = IKSolver(kin, IKConfig(max_iters=15)).solve_track(targets, np.repeat(R, 3, axis=0), home)
    assert result.converged.tolist() == [True, False, True]
    assert result.failed_frames.tolist() == [1]
    assert result.pos_err[1] > 0.5  # the remaining error is reported
    assert result.iters[1] == 15
