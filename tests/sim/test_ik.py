"""ArmIK (mink + daqp): one step per control period, limits respected, obstacles avoided."""

from __future__ import annotations

import numpy as np

from demo.sim import make_env
from demo.sim.geometry import down_quat, quat_angle


def test_solve_pose_reaches_and_respects_limits():
    env = make_env("reach")
    env.reset(0)
    ik = env.ik
    target = np.array([0.4, 0.2, 0.15])
    quat = down_quat(env.home_yaw + 0.5)
    q = ik.solve_pose(env.data.qpos[env.arm_qadr], env.to_world(target), env.quat_to_world(quat))
    env.set_arm(q)
    pos, ee_quat = env.ee_pose()
    assert np.linalg.norm(pos - target) < 1e-3 and quat_angle(ee_quat, quat) < 1e-2
    m = env.model
    rng = m.jnt_range[[m.joint(j).id for j in env.robot.arm_joints]]
    assert ((q >= rng[:, 0]) & (q <= rng[:, 1])).all()


def test_one_step_moves_at_most_the_joint_speed_limit():
    env = make_env("reach")
    env.reset(1)
    q0 = env.data.qpos[env.arm_qadr].copy()
    far = env.ee_pose()[0] + np.array([0.0, 0.4, -0.3])
    q1 = env.ik_step(far, down_quat(env.home_yaw))
    step = np.abs(q1 - q0)
    assert step.max() <= 2.0 / env.fps + 1e-9 and step.max() > 0.01


def test_collision_limit_stops_the_arm_at_the_obstacle():
    env = make_env("avoid")
    env.reset(2)
    o = env.task.obstacle(env)
    through = np.array([o[0], o[1], 0.12])  # the obstacle's centre: unreachable
    obstacle = env.model.geom("obstacle").id
    start = env.ee_pose()[0]
    for _ in range(60):
        q = env.ik_step(through, down_quat(env.home_yaw))
        env.step(np.concatenate([q, [0.0]]))
        # the limit holds the arm at the obstacle: it may graze it, never push into it
        assert all(c.dist > -0.002 for c in env.data.contact if obstacle in c.geom)
    ee = env.ee_pose()[0]
    assert abs(ee[0] - o[0]) > 0.03 or abs(ee[1] - o[1]) > 0.07  # outside the box footprint
    assert np.linalg.norm(ee - start) > 0.03  # it did move toward the target
    assert env.ik.failures == 0


def test_direct_daqp_matches_mink_solve_ik():
    """ArmIK solves mink's QP with daqp directly; the answer is mink.solve_ik's."""
    import mink

    rng = np.random.default_rng(0)
    for task in ("reach", "avoid"):
        env = make_env(task)
        env.reset(3)
        ik = env.ik
        for _ in range(5):
            q = env.data.qpos[env.arm_qadr] + rng.uniform(-0.2, 0.2, 7)
            ik.set_state(q, env.data.mocap_pos, env.data.mocap_quat)
            target = env.ee_pose()[0] + rng.uniform(-0.05, 0.05, 3)
            ik.frame_task.set_target(mink.SE3(wxyz_xyz=np.r_[env.quat_to_world(down_quat(env.home_yaw)), env.to_world(target)]))
            ours = ik._solve()
            ref = mink.solve_ik(ik.configuration, ik.tasks, ik.dt, "daqp", damping=ik.params.damping, limits=ik.limits)
            np.testing.assert_allclose(ours, ref * ik.dt, atol=1e-9)


def test_daqp_fast_path_solves_minks_problem() -> None:
    """Bounds instead of limit rows: the same dq as mink.solve_ik with the same tasks and limits."""
    import mink

    for task in ("pick", "avoid"):  # avoid adds the collision-avoidance rows
        env = make_env(task)
        rng = np.random.default_rng(0)
        for seed in range(6):
            env.reset(seed)
            ik = env.ik
            q = env.data.qpos[env.arm_qadr] + rng.normal(0.0, 0.3, len(env.arm_qadr))
            ik.set_state(q, env.data.mocap_pos, env.data.mocap_quat)
            pos = env.ee_pose()[0] + rng.normal(0.0, 0.1, 3)
            ik.frame_task.set_target(mink.SE3(wxyz_xyz=np.r_[env.quat_to_world(down_quat(rng.uniform(-3, 3))), env.to_world(pos)]))
            ours = ik._solve()
            theirs = mink.solve_ik(ik.configuration, ik.tasks, ik.dt, "daqp", damping=ik.params.damping, limits=ik.limits) * ik.dt
            assert ours is not None
            np.testing.assert_allclose(ours, theirs, atol=1e-7)


def test_in_place_objective_is_minks_bit_for_bit() -> None:
    """ArmIK assembles the QP cost in place; the numbers are those of the tasks' own residuals."""
    from pathlib import Path

    rng = np.random.default_rng(1)
    arm7 = Path(__file__).parents[1] / "assets" / "convert_arm7" / "robot.toml"
    for task, robot in (("pick", None), ("avoid", None), ("reach", arm7)):
        env = make_env(task, robot=robot)
        env.reset(2)
        ik = env.ik
        assert ik._fast_objective
        for _ in range(10):
            q = env.data.qpos[env.arm_qadr] + rng.normal(0.0, 0.3, len(env.arm_qadr))
            ik.set_state(q, env.data.mocap_pos, env.data.mocap_quat)
            quat = rng.normal(size=4)
            target = ik.frame_task.transform_target_to_world.wxyz_xyz
            target[:4], target[4:] = quat / np.linalg.norm(quat), env.ee_pose()[0] + rng.normal(0.0, 0.05, 3)
            (H, c), (H_ref, c_ref) = ik._objective(), ik._task_objective()
            assert H.tobytes() == H_ref.tobytes() and c.tobytes() == c_ref.tobytes()
