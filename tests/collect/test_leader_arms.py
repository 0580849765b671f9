"""Leader-follower capture for a robot of several arms (gym-aloha's pair in demo's rebuild of its scene):
a leader file played through the follower's servos, calibrated per arm, with its tracking error."""

from __future__ import annotations

import csv
import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from demo.cli.main import main
from demo.collect.foreign import foreign_episode
from demo.collect.human_files import LEADER_PROFILES, write_leader_arms_file
from demo.collect.leader_arms import LeaderArms
from demo.curate.curate import analyse
from demo.sim import make_env
from demo.sim.arms import load_arms
from demo.store import EpisodeStore

pytestmark = pytest.mark.skipif(importlib.util.find_spec("gym_aloha") is None,
                                reason="gym-aloha==0.1.5 is not installed beside demo (pip install --no-deps "
                                       "gym-aloha==0.1.5: its MJCF is the scene's)")

ROBOTS = Path(__file__).resolve().parents[2] / "sim" / "assets" / "robots"
ARMS = str(ROBOTS / "aloha_vx300s.toml")
ENV = "demo.sim.aloha_scene:transfer_cube"
EXPERT = "demo.collect.aloha:transfer_cube"
SEED = 5


def _collect(leader_csv: Path, out: Path, robot: str = ARMS, capsys: pytest.CaptureFixture | None = None) -> dict:
    assert main(["collect", "--env", ENV, "--source", "leader", "--input", str(leader_csv), "--robot", robot,
                 "--out", str(out), "--json", str(out) + ".json"]) == 0
    return json.loads(Path(str(out) + ".json").read_text())


@pytest.fixture(scope="module")
def expert_actions() -> np.ndarray:
    env = make_env("env:" + ENV)
    try:
        data, info = foreign_episode(env, EXPERT, SEED)
    finally:
        env.close()
    assert info["success"]
    return data["action"].astype(np.float64)


def assert_replays(episode: dict[str, np.ndarray], seed: int) -> None:
    """A stored episode replays identically: its actions from its seed give the same followers, frame by frame."""
    env = make_env("env:" + ENV)
    try:
        env.reset(seed)
        replayed = []
        for a in episode["action"]:
            replayed.append(env.frame()["obs.agent_pos"])
            env.step(a)
    finally:
        env.close()
    np.testing.assert_array_equal(np.array(replayed, dtype=np.float32), episode["obs.agent_pos"])


def _calibrated_arms(tmp_path: Path) -> str:
    """The pair with a [leader] table on the left arm: its waist read reversed and offset, its gripper 0.2 .. 0.9."""
    left = (ROBOTS / "aloha_vx300s_left.toml").read_text()
    (tmp_path / "left.toml").write_text(left + '\n[leader]\nsign = [-1, 1, 1, 1, 1, 1]\noffset = [0.3, 0, 0, 0, 0, 0]\n'
                                               'gripper = [0.2, 0.9]\n')
    (tmp_path / "right.toml").write_text((ROBOTS / "aloha_vx300s_right.toml").read_text())
    arms = tmp_path / "arms.toml"
    arms.write_text('name = "aloha_calibrated"\n[[arms]]\nname = "left"\nconfig = "left.toml"\n'
                    '[[arms]]\nname = "right"\nconfig = "right.toml"\n')
    return str(arms)


def test_a_leader_file_at_the_control_rate_replays_the_expert_exactly(expert_actions: np.ndarray, tmp_path: Path) -> None:
    """Leaders held exactly on the expert's targets, read through a calibration: the followers do what the expert
    did, and the recorded actions are the expert's."""
    robot = _calibrated_arms(tmp_path)
    leaders = LeaderArms(load_arms(robot))
    left = leaders.calibrations[0]
    readings = expert_actions.copy()
    readings[:, :6] = left.readings(expert_actions[:, :6])  # what the reversed, offset left leader reads
    readings[:, 6] = left.gripper_reading(1.0 - expert_actions[:, 6])  # closedness from gym-aloha's opening
    readings[:, 13] = 1.0 - expert_actions[:, 13]  # the right arm: identity (closedness 0 .. 1)
    path = tmp_path / "LEADER.csv"
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["episode_seed", "t", *leaders.joint_columns[:6], "left.gripper", *leaders.joint_columns[6:], "right.gripper"])
        w.writerows([SEED, k / 50.0, *row] for k, row in enumerate(readings))
    assert readings[0, 0] != pytest.approx(expert_actions[0, 0])  # the calibration is not the identity
    summary = _collect(path, tmp_path / "lead.zarr", robot)
    assert summary["successes"] == summary["episodes"] == 1
    with EpisodeStore.open(tmp_path / "lead.zarr") as store:
        episode = store.read_episode(0)
        assert store.meta.action.names[0] == "left.waist"
        np.testing.assert_allclose(episode["action"][:len(expert_actions)], expert_actions, atol=1e-5)
        assert episode["info.ik_ok"].all()
    assert_replays(episode, SEED)
    lag = summary["tracking_error_rad"]
    assert set(lag) == {f"{arm}.{j}" for arm in ("left", "right")
                        for j in ("waist", "shoulder", "elbow", "forearm_roll", "wrist_angle", "wrist_rotate")}
    assert all(0.0 < e["mean"] < 0.05 for e in lag.values())  # the followers lag their leaders by their servos


def test_people_of_every_profile_move_the_leaders_and_curation_drops_the_shaky(tmp_path: Path) -> None:
    """The poor operator's leaders overshoot and tremble: the followers lag more, and `demo curate`'s jerk (on
    gym-aloha's joint targets, in rad) drops those episodes while it keeps the good operator's."""
    lags, kept = {}, {}
    for profile in ("good", "poor"):
        path = tmp_path / profile / "LEADER.csv"
        made = write_leader_arms_file(path, ENV, EXPERT, ARMS, episodes=2, seed=0, profile=LEADER_PROFILES[profile])
        assert made["scripted_successes"] == 2
        summary = _collect(path, tmp_path / f"{profile}.zarr")
        assert summary["episodes"] == 2 and summary["successes"] >= 1
        lags[profile] = np.mean([e["mean"] for e in summary["tracking_error_rad"].values()])
        with EpisodeStore.open(tmp_path / f"{profile}.zarr") as store:
            curation = analyse(store)
        kept[profile] = (int(curation.kept.sum()), sorted({r.split()[0] for rs in curation.reasons for r in rs}))
    assert lags["poor"] > lags["good"]  # overshoot and tremor: the followers chase a jumpier leader
    # The good operator's tremor alone reads ~250-350 range/s^3 here (10 episodes: 226-297), below the 400 limit;
    # the poor one's 2,300-3,100.
    assert kept == {"good": (2, []), "poor": (0, ["jerk"])}


def test_bad_leader_input_is_one_line_and_stores_nothing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    good = tmp_path / "LEADER.csv"
    write_leader_arms_file(good, ENV, EXPERT, ARMS, episodes=1, seed=SEED)
    lines = good.read_text().splitlines()
    cases = []
    no_gripper = tmp_path / "no_gripper.csv"
    no_gripper.write_text("\n".join([lines[0].replace(",right.gripper", "")] +
                                    [line.rsplit(",", 1)[0] for line in lines[1:]]) + "\n")
    cases.append((["--input", str(no_gripper), "--robot", ARMS], f"{no_gripper}:1: header lacks column(s) right.gripper"))
    nan = tmp_path / "nan.csv"
    nan.write_text("\n".join(lines[:3] + [lines[3].replace(lines[3].split(",")[4], "nan", 1)] + lines[4:]) + "\n")
    cases.append((["--input", str(nan), "--robot", ARMS], f"{nan}:4: "))
    repeated = tmp_path / "repeated.csv"  # a time given twice: a rate of 0
    repeated.write_text("\n".join(lines[:3] + [lines[2]] + lines[3:]) + "\n")
    cases.append((["--input", str(repeated), "--robot", ARMS], f"{repeated}:4: "))
    cases.append((["--input", str(good)], "--robot: --source leader in an environment needs its robot of several arms"))
    cases.append((["--input", str(good), "--robot", str(ROBOTS / "aloha_vx300s_left.toml")], "aloha_vx300s_left.toml"))
    for argv, needle in cases:
        out = tmp_path / "x.zarr"
        assert main(["collect", "--env", ENV, "--source", "leader", "--out", str(out), *argv]) != 0
        err = capsys.readouterr().err
        assert needle in err and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
        assert not out.exists()
    # An environment whose action is not these arms' joints: refused before anything is stored.
    assert main(["collect", "--env", "Pendulum-v1", "--source", "leader", "--input", str(good), "--robot", ARMS,
                 "--out", str(tmp_path / "c.zarr")]) != 0
    err = capsys.readouterr().err
    assert "--env Pendulum-v1" in err and "left.waist" in err and not (tmp_path / "c.zarr").exists()
