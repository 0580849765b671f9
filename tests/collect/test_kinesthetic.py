"""Kinesthetic import: a 100 Hz joint file made from scripted `pick` episodes replays into
demonstrations with >= 90% success; bad files fail with the line number and write nothing."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from demo.collect.human_files import write_human_files
from demo.collect.kinesthetic import JointTrack, collect_kinesthetic, parse_joint_csv, resample_joints
from demo.collect.human import InputEpisode
from demo.errors import DemoError
from demo.seeds import episode_seed
from demo.sim import load_robot
from demo.store import EpisodeStore

EPISODES = 10
JOINTS = load_robot(None).arm_joints
HEADER = ",".join(["t", *JOINTS, "gripper"])


@pytest.fixture(scope="module")
def human_files(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("human")
    write_human_files(out, "pick", episodes=EPISODES, seed=3)
    return out


def _row(t: float, q: list[float] | None = None, g: float = 0.0) -> str:
    q = q if q is not None else [0.0, 0.0, 0.0, -1.6, 0.0, 1.6, 0.8]
    return ",".join(str(v) for v in [t, *q, g])


def _write(path: Path, lines: list[str]) -> Path:
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.slow
def test_joint_file_at_100hz_replays_into_successful_demos(human_files: Path, tmp_path: Path) -> None:
    csv = human_files / "JOINTS.csv"
    tracks = parse_joint_csv(csv, JOINTS)
    assert len(tracks) == EPISODES
    assert np.allclose(np.diff(tracks[0].t), 0.01)  # recorded at 100 Hz
    out = tmp_path / "kin.zarr"
    result = collect_kinesthetic("pick", csv, out, operator="bob")
    assert result.success_rate >= 0.9, result
    store = EpisodeStore.open(out)
    rows = store.table.to_pylist()
    assert {r["source"] for r in rows} == {"kinesthetic"} and {r["operator"] for r in rows} == {"bob"}
    assert store.column("seed").tolist() == [episode_seed(3, i) for i in range(EPISODES)]
    assert all(r["unreachable_frames"] == 0 for r in rows)
    ep = store.read_episode(1)
    # Resampled to the store's 20 Hz; the label is the recorded configuration one step later.
    q20, _ = resample_joints(tracks[1], store.meta.fps)
    np.testing.assert_allclose(ep["action"][:5, :7], q20[1:6], atol=1e-5)
    np.testing.assert_allclose(ep["obs.joint_pos"][0], q20[0], atol=2e-3)  # starts where the recording starts
    # info.ee_target: the EE pose the command puts the arm at, reached one step later.
    np.testing.assert_allclose(ep["info.ee_target"][:-12, :3], ep["obs.ee_pos"][1:-11], atol=0.01)
    assert store.meta.provenance[-1]["source"] == "kinesthetic"
    store.close()


def test_out_of_range_joints_are_flagged_not_silently_clipped(tmp_path: Path) -> None:
    q_bad = [0.0, 0.0, 0.0, -0.01, 0.0, 1.6, 0.8]  # joint4's range ends at -0.0698
    lines = [HEADER, *[_row(i / 100, None if i < 50 else q_bad) for i in range(100)]]
    out = tmp_path / "k.zarr"
    result = collect_kinesthetic("pick", _write(tmp_path / "j.csv", lines), out, seed=4)
    assert result.unreachable_frames > 0
    store = EpisodeStore.open(out)
    ep = store.read_episode(0)
    flagged = ~ep["info.ik_ok"][:, 0]
    assert flagged.sum() == store.episode_info(0)["unreachable_frames"] == result.unreachable_frames
    assert ep["action"][flagged, 3].max() <= -0.0698 + 1e-6  # executed within the range ...
    assert ep["info.ik_error"][flagged, 1].min() > 0.05  # ... and by how much it was off, recorded
    assert store.column("seed").tolist() == [episode_seed(4, 0)]  # no episode_seed column: --seed
    store.close()


@pytest.mark.parametrize(
    "bad, message",
    [
        (_row(0.04, g=float("nan")), "'gripper' is not finite"),
        (_row(0.01), "goes backwards"),
        (_row(0.03, g=2.0), "within 0 (open) .. 1 (closed)"),
        ("0.05,1,2", "expected 9 values"),
        (_row(0.05).replace("-1.6", "abc"), "'joint4' is not a number"),
        # finite, but no reading of the joint (before, accepted and clipped)
        (_row(0.05, [0.0, 0.0, 0.0, -1.6, 1e308, 1.6, 0.8]), "'joint5' = 1e+308 is far outside the joint's range"),
        (_row(0.05, [0.0, 0.0, 0.0, 3.5, 0.0, 1.6, 0.8]),
         "'joint4' = 3.5 is far outside the joint's range [-3.0718, -0.0698]"),
    ],
)
def test_bad_rows_name_file_and_line_and_write_nothing(tmp_path: Path, bad: str, message: str) -> None:
    path = _write(tmp_path / "bad.csv", ["# recorded by hand", HEADER, _row(0.0), _row(0.02), bad])
    out = tmp_path / "out.zarr"
    with pytest.raises(DemoError) as info:
        collect_kinesthetic("pick", path, out)
    assert info.value.where == f"{path}:5"
    assert message in info.value.problem
    assert not out.exists()


def test_header_errors(tmp_path: Path) -> None:
    with pytest.raises(DemoError, match="lacks column.*joint7"):
        parse_joint_csv(_write(tmp_path / "a.csv", [HEADER.replace(",joint7", ""), "0"]), JOINTS)
    with pytest.raises(DemoError, match="unknown column.*speed"):
        parse_joint_csv(_write(tmp_path / "b.csv", [HEADER + ",speed"]), JOINTS)
    with pytest.raises(DemoError, match="no samples"):
        parse_joint_csv(_write(tmp_path / "c.csv", [HEADER]), JOINTS)
    with pytest.raises(DemoError, match="empty file"):
        parse_joint_csv(_write(tmp_path / "d.csv", ["# nothing"]), JOINTS)
    with pytest.raises(DemoError, match="not found"):
        parse_joint_csv(tmp_path / "missing.csv", JOINTS)


def test_episode_seed_column_splits_episodes(tmp_path: Path) -> None:
    header = "episode_seed," + HEADER
    lines = [header, "9," + _row(0.0), "9," + _row(0.1), "4," + _row(0.0), "4," + _row(0.05)]
    tracks = parse_joint_csv(_write(tmp_path / "s.csv", lines), JOINTS)
    assert [(t.episode.seed, t.episode.line, len(t.t)) for t in tracks] == [(9, 2, 2), (4, 4, 2)]
    with pytest.raises(DemoError, match="s2.csv:3: 'episode_seed' must be an integer"):
        parse_joint_csv(_write(tmp_path / "s2.csv", [header, "9," + _row(0.0), "x," + _row(0.1)]), JOINTS)


def test_resample_joints_any_rate() -> None:
    t = np.array([0.0, 0.03, 0.07, 0.1])
    q = np.stack([t * 10, -t], axis=1)
    track = JointTrack(InputEpisode(1, None, None), t, q, np.array([0.0, 0.0, 1.0, 1.0]))
    q20, g20 = resample_joints(track, 20.0)
    np.testing.assert_allclose(q20, [[0.0, 0.0], [0.5, -0.05], [1.0, -0.1]])
    assert g20.tolist() == [0.0, 0.0, 1.0]  # the gripper command holds its latest value
