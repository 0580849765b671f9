"""Retargeting (mink): reachable poses are reached within the joint speed limit, unreachable ones
(out of the workspace, through the table) are flagged while the arm stays clear of the table;
`demo bench retarget` reports poses/s next to the bare IK solve."""

from __future__ import annotations

import json
from pathlib import Path

import mujoco
import numpy as np
import pytest

from demo.collect.retarget import Retargeter, RetargetParams
from demo.errors import DemoError
from demo.sim import make_env
from demo.sim.geometry import quat_angle


@pytest.fixture(scope="module")
def env():
    e = make_env("pick")
    e.reset(1)
    yield e
    e.close()


def test_reachable_pose_is_reached_within_speed_limits(env) -> None:
    rt = Retargeter(env)
    rt.reset()
    p0, q0 = rt.ee_pose()
    target = p0 + np.array([0.06, 0.08, -0.12])
    vmax = np.array(env.robot.max_joint_velocity)
    q_prev = rt.q.copy()
    steps = []
    for _ in range(40):
        steps.append(rt(target, q0))
        assert np.all(np.abs(steps[-1].q - q_prev) <= vmax / env.fps + 1e-6)  # VelocityLimit over the step
        q_prev = steps[-1].q
    last = steps[-1]
    assert last.ok and last.pos_err < 1e-3 and last.rot_err < 1e-2
    pos, quat = rt.fk(last.q)
    assert np.linalg.norm(pos - target) == pytest.approx(last.pos_err, abs=1e-9)
    assert quat_angle(quat, q0) < 1e-2


def test_unreachable_poses_are_flagged(env) -> None:
    rt = Retargeter(env)
    rt.reset()
    p0, q0 = rt.ee_pose()
    far = [rt(np.array([1.6, 0.0, 0.4]), q0) for _ in range(60)]  # beyond the arm's reach
    assert not far[-1].ok and far[-1].pos_err > 0.5
    rt.reset()
    below = [rt(np.array([p0[0], p0[1], -0.10]), q0) for _ in range(60)]  # 10 cm into the table
    assert not below[-1].ok
    # The collision limit stops every moving robot geom at the table, instead of clipping the target.
    m, d = rt.fk_model, rt.fk_data
    rt.fk(below[-1].q)
    table = m.geom("table").id
    robot = [g for g in range(m.ngeom) if m.body_weldid[m.geom_bodyid[g]] != 0]
    fromto = np.zeros(6)
    gap = min(mujoco.mj_geomDistance(m, d, g, table, 0.1, fromto) for g in robot)
    assert gap > 0.0
    assert below[-1].pos_err == pytest.approx(rt.ee_pose()[0][2] + 0.10, abs=1e-6)


def test_retargeting_is_deterministic(env) -> None:
    def run() -> np.ndarray:
        rt = Retargeter(env, params=RetargetParams(iters=3))
        rt.reset()
        p0, q0 = rt.ee_pose()
        return np.array([rt(p0 + 0.01 * np.array([k, -k, 0.5 * k]), q0).q for k in range(10)])

    np.testing.assert_array_equal(run(), run())


def test_unknown_backend(env) -> None:
    with pytest.raises(DemoError, match="unknown IK backend 'ikfast'"):
        Retargeter(env, "ikfast")


def test_bench_retarget_cli_reports_rate_and_reference(tmp_path: Path) -> None:
    from demo.cli.main import main

    out = tmp_path / "bench.json"
    assert main(["bench", "retarget", "--seconds", "0.3", "--ik", "mink", "--json", str(out)]) == 0
    r = json.loads(out.read_text())
    b = r["backends"]["mink"]
    assert b["poses_per_s"] > 0 and b["reference_bare_solves_per_s"] > 0
    # One pose is `iters` solves plus bookkeeping: dearer than one bare solve, not many times dearer.
    assert 1.0 < b["pose_cost_in_bare_solves"] < 4 * b["ik_iterations_per_pose"]
    assert b["poses_reached"] == 1.0
    assert r["target_poses_per_s"] == 200.0 and "machine" in r
    assert main(["bench", "retarget", "--ik", "nope"]) == 1
