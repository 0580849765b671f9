"""Leader-follower capture from a file (`demo collect --source leader`): a leader recording made from scripted
`pick` episodes drives the follower into successful demonstrations that replay identically, the leader's
calibration (sign, offset, gripper range) in the robot config is applied, the tracking error is reported per
joint, a poor operator's leader data is what curation drops, and bad files fail in one line writing nothing."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from demo.collect.human_files import LEADER_PROFILES, write_human_files
from demo.collect.kinesthetic import collect_kinesthetic
from demo.curate.curate import curate
from demo.sim import load_robot
from demo.sim.robot import ASSETS
from demo.store import EpisodeStore

EPISODES = 4
JOINTS = load_robot(None).arm_joints


def calibrated_robot(folder: Path) -> Path:
    """The built-in arm with a leader whose joints 2 and 4 read backwards, offset, named l1..l7, and whose
    gripper reads 0.2 open and 0.9 closed."""
    toml = (ASSETS / "panda.toml").read_text().replace('mjcf = "panda.xml"', f'mjcf = "{ASSETS / "panda.xml"}"')
    toml += ('\n[leader]\njoints = ["l1", "l2", "l3", "l4", "l5", "l6", "l7"]\nsign = [1, -1, 1, -1, 1, 1, 1]\n'
             'offset = [0, 0.1, 0, -0.2, 0, 0, 0]\ngripper = [0.2, 0.9]\n')
    path = folder / "calibrated.toml"
    path.write_text(toml)
    return path


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("leader")
    robot = calibrated_robot(root)
    out = {"robot": robot}
    for name in ("good", "poor"):
        write_human_files(root / name, "pick", episodes=EPISODES, seed=5, leader=LEADER_PROFILES[name])
        out[name] = root / name / "LEADER.csv"
    write_human_files(root / "calibrated", "pick", episodes=EPISODES, seed=5, robot=str(robot))
    out["calibrated"] = root / "calibrated" / "LEADER.csv"
    return out


def test_a_leader_file_drives_the_follower_into_demonstrations_that_replay(files: dict[str, Path], tmp_path: Path,
                                                                          replays) -> None:
    out = tmp_path / "good.zarr"
    result = collect_kinesthetic("pick", files["good"], out, operator="ann", leader=True)
    assert result.successes == EPISODES
    assert set(result.tracking_error_rad) == set(JOINTS)
    assert all(0 < e["mean"] <= e["max"] < 0.02 for e in result.tracking_error_rad.values())
    with EpisodeStore.open(out) as store:
        assert set(store.column("source")) == {"leader"} and set(store.column("operator")) == {"ann"}
        assert (store.column("tracking_error_rad") < 0.02).all()
        ep = store.read_episode(0, ["action", "obs.joint_pos", "sim.state"])
    # The follower lags its leader: the action (the leader's position) leads the measured joints.
    lead = np.abs(ep["action"][:-1, :7] - ep["obs.joint_pos"][1:]).mean()
    assert 0 < lead < 0.02
    replays("pick", ep)  # from the first recorded state, the recorded actions give every recorded state

def test_the_robot_configs_leader_calibration_is_applied(files: dict[str, Path], tmp_path: Path) -> None:
    """The same paths written in a calibrated leader's readings give the same follower commands."""
    header = files["calibrated"].read_text().splitlines()[0]
    assert header == "episode_seed,t,l1,l2,l3,l4,l5,l6,l7,gripper"
    plain = collect_kinesthetic("pick", files["good"], tmp_path / "plain.zarr", leader=True)
    calibrated = collect_kinesthetic("pick", files["calibrated"], tmp_path / "cal.zarr", robot=str(files["robot"]), leader=True)
    assert calibrated.successes == plain.successes == EPISODES
    with EpisodeStore.open(tmp_path / "plain.zarr") as a, EpisodeStore.open(tmp_path / "cal.zarr") as b:
        x, y = a.read_episode(1, ["action"])["action"], b.read_episode(1, ["action"])["action"]
    np.testing.assert_allclose(y, x, atol=1e-5)  # 6-decimal readings, calibrated back
    readings = np.loadtxt(files["calibrated"], delimiter=",", skiprows=1)
    assert readings[:, -1].min() == pytest.approx(0.2) and readings[:, -1].max() == pytest.approx(0.9)


def test_curation_drops_a_poor_operators_leader_data(files: dict[str, Path], tmp_path: Path) -> None:
    kept = {}
    for name in ("good", "poor"):
        collect_kinesthetic("pick", files[name], tmp_path / f"{name}.zarr", leader=True)
        report = curate(tmp_path / f"{name}.zarr", mask="curated")
        kept[name] = int(np.sum(report.kept))
    assert kept["good"] == EPISODES and kept["poor"] < EPISODES, kept


@pytest.mark.parametrize("edit, needle", [
    (lambda lines: [lines[0].replace(",joint3", "")] + [",".join(r.split(",")[:4] + r.split(",")[5:]) for r in lines[1:]],
     "header lacks column(s) joint3"),
    (lambda lines: lines[:3] + [lines[3].replace(lines[3].split(",")[4], "nan", 1)] + lines[4:], "'joint3' is not finite"),
    (lambda lines: lines[:3] + [",".join([lines[3].split(",")[0], lines[2].split(",")[1], *lines[3].split(",")[2:]])]
     + lines[4:], "time repeats"),  # a rate of 0: two readings at the same time
])
def test_bad_leader_files_fail_in_one_line_and_store_nothing(files: dict[str, Path], tmp_path: Path, one_line_error,
                                                             edit, needle: str) -> None:
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(edit(files["good"].read_text().splitlines()[:20])) + "\n")
    out = tmp_path / "out.zarr"
    one_line_error(["collect", "--source", "leader", "--input", str(bad), "--task", "pick", "--out", str(out)],
                   str(bad), needle)
    assert not out.exists()


@pytest.mark.parametrize("table, needle", [
    ('sign = [1, 2, 1, 1, 1, 1, 1]', "[leader] sign must be +1 or -1 per joint"),
    ('joints = ["a", "a", "b", "c", "d", "e", "f"]', "[leader] joints must name 7 distinct columns"),
    ('gripper = [0.5, 0.5]', "open and closed readings must differ"),
    ('speed = 2', "unknown key(s) in [leader]: speed"),
])
def test_a_bad_leader_table_fails_in_one_line(tmp_path: Path, one_line_error, table: str, needle: str) -> None:
    toml = (ASSETS / "panda.toml").read_text().replace('mjcf = "panda.xml"', f'mjcf = "{ASSETS / "panda.xml"}"')
    (tmp_path / "bad.toml").write_text(toml + f"\n[leader]\n{table}\n")
    one_line_error(["robot", "check", str(tmp_path / "bad.toml")], str(tmp_path / "bad.toml"), needle)

