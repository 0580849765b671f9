"""`demo bench convert`: the figure, its reference and its peer in one JSON, from the same run."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from demo.bench.convert import EPISODE_LENGTH, synthetic_episodes
from demo.cli.main import main
from demo.convert.kinematics import Kinematics


@pytest.mark.filterwarnings("ignore::DeprecationWarning")  # placo imports hppfcl under its old name
def test_bench_json_has_figure_reference_and_peer(tmp_path: Path):
    path = tmp_path / "bench.json"
    assert main(["bench", "convert", "--frames", "20000", "--placo-frames", "500", "--json", str(path)]) == 0
    r = json.loads(path.read_text())
    res = r["results"]
    for key in ("joint_pos->ee7", "mj_kinematics loop", "placo FK loop"):
        assert res[key]["frames_per_s"] > 0, key
    assert r["ratio_vs_mj_kinematics"] == res["joint_pos->ee7"]["frames_per_s"] / res["mj_kinematics loop"]["frames_per_s"]
    assert r["target_frames_per_s"] == 100_000 and isinstance(r["target_met"], bool)
    assert r["fk_vs_mujoco"]["max_pos_err_m"] < 1e-12
    assert res["placo FK loop"]["max_pos_diff_vs_ours_m"] < 1e-6  # the peer computes the same FK
    assert r["cpu"].startswith("1 core")


def test_synthetic_trajectories_stay_within_limits():
    from demo.sim import load_robot

    robot = load_robot(None)
    kin = Kinematics(robot.spec().compile(), robot.arm_joints, robot.ee_site, robot.base_body)
    action, start, seg = synthetic_episodes(kin, 1000, np.random.default_rng(0))
    assert action.shape == (1000, 8) and len(start) == len(seg.ends) == 1000 // EPISODE_LENGTH
    assert (action[:, :7] >= kin.lower - 1e-6).all() and (action[:, :7] <= kin.upper + 1e-6).all()
