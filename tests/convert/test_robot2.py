"""A dataset recorded with a robot other than the built-in one (tests/assets/convert_arm7) converts
correctly: FK checked against MuJoCo's site pose as the env recorded it, and the round trip."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from demo.convert import representations as reps
from demo.convert.check import replay_check, round_trip
from demo.convert.context import load_context
from demo.convert.convert import ConvertOptions, convert_store
from demo.sim import geometry as rot
from demo.store import EpisodeStore

ARM7 = Path(__file__).parents[1] / "assets" / "convert_arm7" / "robot.toml"


@pytest.fixture(scope="module")
def pick7(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from demo.collect.scripted import CollectConfig, collect_scripted

    out = tmp_path_factory.mktemp("robot2") / "pick_arm7.zarr"
    collect_scripted(CollectConfig(task="pick", episodes=2, seed=0, robot=str(ARM7)), out)
    return out


def test_the_store_names_the_other_robot_and_fk_matches_mujocos_site_pose(pick7: Path):
    from demo.sim import make_env

    with EpisodeStore.open(pick7) as store:
        assert store.meta.robot["name"] == "arm7_iiwa_like"
        ctx = load_context(store.meta, pick7)
        assert ctx.robot.name == "arm7_iiwa_like" and ctx.robot.ee_site == "grasp_point"
        env = make_env("pick", robot=ctx.robot)
        try:
            for i in range(store.num_episodes):
                ep = store.read_episode(i)
                q = ctx.arm_q_from_states(ep["sim.state"], "test")  # measured joints of every frame
                pos, R = ctx.kin.fk(q)
                for t in range(0, len(q), 5):
                    env.set_state(ep["sim.state"][t])  # MuJoCo's own site pose, in the offset, yawed base frame
                    p_mj, quat_mj = env.ee_pose()
                    assert np.abs(pos[t] - p_mj).max() < 1e-12
                    assert rot.angle_between(R[t], rot.quat_to_mat(quat_mj)) < 1e-7
                # Frame 0 (right after reset) also matches what the env recorded as obs.ee_pos.
                assert np.abs(pos[0] - ep["obs.ee_pos"][0]).max() < 1e-6
        finally:
            env.close()


def test_the_other_robot_converts_and_round_trips(pick7: Path, tmp_path: Path):
    result = convert_store(pick7, tmp_path / "ee7.zarr", ConvertOptions(to="ee7"))
    assert result.fk_check["max_pos_err_m"] < 1e-12
    with EpisodeStore.open(tmp_path / "ee7.zarr") as out:
        assert out.meta.provenance[-1]["robot"]["name"] == "arm7_iiwa_like"
        ep = out.read_episode(0)
        # The anchor is the measured pose at frame 0 in the robot's base frame.
        assert np.abs(ep[reps.EE_ANCHOR_KEY][0, :3] - ep["obs.ee_pos"][0]).max() < 1e-6
    rt = round_trip(pick7, ConvertOptions(to="ee7"))
    assert rt.ik["converged_share"] >= 0.999
    assert rt.max_pos_err_m <= 1e-4 and rt.max_rot_err_rad <= 1e-3
    report = replay_check(pick7, ConvertOptions(to="ee7"))
    assert report.summary()["converted_success_given_original"] in (1.0, None)
