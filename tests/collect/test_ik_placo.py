"""placo as the second IK backend: same kinematics as MuJoCo, the same joint solutions as mink on
100 random reachable targets, and a working `--ik placo` retargeting."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from demo.collect.ik_placo import PlacoIK, load_placo_robot
from demo.collect.retarget import Retargeter, scene_spec_of
from demo.collect.vr import collect_vr
from demo.sim import make_env
from demo.sim.geometry import mat_to_quat, quat_angle
from demo.sim.ik import ArmIK, IKParams

# A posture cost small enough that its pull leaves the EE < 0.3 mm off target, large enough that
# the redundant joint settles in ~100 iterations: both solvers then sit on the same fixed point.
CROSS_CHECK = IKParams(posture_cost=0.005)


@pytest.fixture(scope="module")
def env():
    e = make_env("reach")
    e.reset(0)
    yield e
    e.close()


def _random_reachable(env, rng: np.random.Generator, n: int) -> list[np.ndarray]:
    m = env.model
    lim = m.jnt_range[[m.joint(j).id for j in env.robot.arm_joints]]
    home = np.array([env.robot.home_qpos[j] for j in env.robot.arm_joints])
    return [np.clip(home + rng.uniform(-0.6, 0.6, 7), lim[:, 0] + 0.05, lim[:, 1] - 0.05) for _ in range(n)]


def _converge(step, q: np.ndarray, tol: float = 1e-9, max_iters: int = 400) -> np.ndarray:
    for _ in range(max_iters):
        q_next = step(q)
        if np.abs(q_next - q).max() < tol:
            return q_next
        q = q_next
    return q


def test_placo_forward_kinematics_matches_mujoco(env) -> None:
    rt = Retargeter(env)  # its MuJoCo FK
    wrapper = load_placo_robot(env.robot)
    for q in _random_reachable(env, np.random.default_rng(1), 20):
        for j, v in zip(env.robot.arm_joints, q):
            wrapper.set_joint(j, float(v))
        wrapper.update_kinematics()
        T = np.asarray(wrapper.get_T_world_frame(env.robot.ee_site))
        pos, quat = rt.fk(q)
        np.testing.assert_allclose(T[:3, 3], env.to_world(pos), atol=1e-9)
        assert quat_angle(mat_to_quat(T[:3, :3]), env.quat_to_world(quat)) < 1e-5  # the MJCF stores quaternions to 7 digits


def test_mink_and_placo_agree_on_100_random_reachable_targets(env) -> None:
    dt = 1.0 / env.fps
    mink_ik = ArmIK(scene_spec_of(env), env.robot, dt, params=CROSS_CHECK)
    placo_ik = PlacoIK(env.robot, dt, CROSS_CHECK)
    rt = Retargeter(env)
    home = np.array([env.robot.home_qpos[j] for j in env.robot.arm_joints])
    worst = np.zeros(5)
    for q_target in _random_reachable(env, np.random.default_rng(0), 100):
        pos, quat = rt.fk(q_target)
        pos_w, quat_w = env.to_world(pos), env.quat_to_world(quat)

        def mink_step(q: np.ndarray) -> np.ndarray:
            mink_ik.set_state(q)
            return mink_ik.step(pos_w, quat_w)

        q_mink = _converge(mink_step, home.copy())
        q_placo = _converge(lambda q: placo_ik.step(q, pos_w, quat_w), home.copy())
        (pm, qm), (pp, qp) = rt.fk(q_mink), rt.fk(q_placo)
        worst = np.maximum(worst, [
            np.linalg.norm(pm - pp), quat_angle(qm, qp), np.abs(q_mink - q_placo).max(),
            max(np.linalg.norm(pm - pos), np.linalg.norm(pp - pos)), max(quat_angle(qm, quat), quat_angle(qp, quat)),
        ])
    ee_pos, ee_rot, joints, reach_pos, reach_rot = worst
    assert ee_pos <= 1e-3 and ee_rot <= 0.01, worst  # same EE pose: <= 1 mm / 0.01 rad
    assert joints <= 0.01, worst  # and the same joint solution (a 7-DOF arm has many)
    assert reach_pos <= 1e-3 and reach_rot <= 0.01, worst  # both actually reach the target


def test_placo_keeps_the_ee_above_the_table(env) -> None:
    rt = Retargeter(env, "placo")
    rt.reset()
    p0, q0 = rt.ee_pose()
    steps = [rt(np.array([p0[0], p0[1], -0.1]), q0) for _ in range(60)]
    assert not steps[-1].ok  # flagged, not silently clipped
    z = rt.ee_pose()[0][2]
    assert 0.0 < z < 0.05  # went down to the table and stopped there


def test_vr_collection_with_placo(tmp_path: Path) -> None:
    from demo.collect.human_files import TrackerFrame, write_human_files

    write_human_files(tmp_path, "pick", episodes=5, seed=11)
    result = collect_vr("pick", tmp_path / "POSES.jsonl", tmp_path / "p.zarr", scale=1 / TrackerFrame().scale, ik="placo")
    assert result.successes >= 4, result
    from demo.store import EpisodeStore

    store = EpisodeStore.open(tmp_path / "p.zarr")
    assert set(store.column("ik").tolist()) == {"placo"}
    assert store.meta.provenance[-1]["ik"] == "placo"
    assert json.dumps(store.meta.provenance)  # JSON-able
    store.close()
