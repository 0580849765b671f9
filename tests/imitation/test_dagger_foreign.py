"""DAgger and HG-DAgger on a foreign (Gymnasium) environment: the expert that collected the data labels the
states the learner drives to, from the observation alone (the docs' point-reach example stands in for
gym-aloha, whose expert is asked the same way)."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from demo.cli.main import main
from demo.imitation.dagger import ActionParts, deviation
from demo.store import EpisodeStore
from demo.training.data import LABEL_KEY

LEARNER = ["--steps", "300", "--round-steps", "100", "--chunk", "1", "--no-ensemble", "--batch-size", "64",
           "--rounds", "2", "--episodes-per-round", "3", "--seed", "0"]


def point_expert(state: np.ndarray) -> np.ndarray:
    """tests/conftest.py's POINT_REACH expert, on a batch of observations ``[T, 4]`` (position, goal)."""
    return np.clip((state[:, 2:] - state[:, :2]) / 0.05, -1.0, 1.0)


@pytest.fixture()
def demos(tmp_path: Path, user_module: str) -> Path:
    out = tmp_path / "p.zarr"
    assert main(["collect", "--env", "point_reach:PointReach-v0", "--expert", "point_reach:expert", "--episodes", "4",
                 "--seed", "3", "--out", str(out)]) == 0
    return out


def test_hg_dagger_asks_the_recorded_expert_where_the_learner_strays(demos: Path, tmp_path: Path) -> None:
    run = tmp_path / "hg"
    assert main(["train", str(demos), "--algo", "dagger", "--gate", "deviation:0.5", *LEARNER, "--out", str(run)]) == 0
    with EpisodeStore.open(run / "data.zarr") as store, EpisodeStore.open(demos) as source:
        rounds = store.column("dagger_round")
        assert rounds.tolist() == [0] * 4 + [1] * 3 + [2] * 3
        new = np.flatnonzero(rounds >= 1)
        total = 0
        for i in new:
            ep = store.read_episode(int(i))
            # Every visited state holds the expert's answer there, from the observation the learner drove to.
            np.testing.assert_allclose(ep["action"], point_expert(ep["obs.state"]), atol=1e-6)
            flags = ep[LABEL_KEY].astype(bool)
            same = np.all(np.isclose(ep["info.executed_action"], ep["action"]), axis=1)
            assert np.array_equal(same[flags], np.ones(flags.sum(), bool))  # the expert executed where it labelled
            assert int(store.column("labels")[i]) == int(flags.sum())
            total += int(flags.sum())
        lengths = store.episode_lengths[new]
        assert 0 < total < lengths.sum()  # it took over somewhere, and the learner drove elsewhere
        demo_frames = source.num_frames
    summary = json.loads((run / "run.json").read_text())
    assert summary["data"]["expert_labels"] == demo_frames + total


def test_rollouts_are_the_same_on_workers(demos: Path, tmp_path: Path) -> None:
    for name, workers in (("a", "0"), ("b", "2")):
        assert main(["train", str(demos), "--algo", "dagger", "--gate", "deviation:0.5", *LEARNER,
                     "--rounds", "1", "--workers", workers, "--out", str(tmp_path / name)]) == 0
    with EpisodeStore.open(tmp_path / "a" / "data.zarr") as a, EpisodeStore.open(tmp_path / "b" / "data.zarr") as b:
        assert a.num_episodes == b.num_episodes == 7
        for i in range(4, 7):
            ea, eb = a.read_episode(i), b.read_episode(i)
            for key in ("action", "obs.state", "info.executed_action", LABEL_KEY):
                np.testing.assert_allclose(ea[key], eb[key], atol=1e-5, err_msg=key)


@pytest.mark.slow  # ~25 s: ACT's transformer, a few steps
def test_the_learner_can_be_act(demos: Path, tmp_path: Path) -> None:
    """HG-DAgger over ACT (--learner act), the policy that reaches gym-aloha's insertion from its camera: the run
    is an ACT policy that demo eval loads and rolls out."""
    run = tmp_path / "act"
    assert main(["train", str(demos), "--algo", "dagger", "--learner", "act", "--gate", "deviation:0.5", "--steps", "30",
                 "--round-steps", "10", "--rounds", "1", "--episodes-per-round", "2", "--out", str(run)]) == 0
    record = json.loads((run / "run.json").read_text())
    assert record["algo"] == "dagger" and record["policy"]["algo"] == "act"
    with EpisodeStore.open(run / "data.zarr") as store:
        assert store.column("dagger_round").tolist() == [0] * 4 + [1] * 2
    assert main(["eval", str(run), "--episodes", "2", "--json", str(tmp_path / "e.json")]) == 0
    assert json.loads((tmp_path / "e.json").read_text())["episodes"] == 2


@pytest.mark.parametrize("extra, needle", [
    (["--algo", "dagger", "--learner", "ppo"], "is not an imitation policy"),
    (["--algo", "dagger", "--chunk", "4"], "a foreign environment's state cannot be saved"),
    (["--algo", "aggrevate"], "needs a task's simulator and expert"),
    (["--algo", "dagger", "--gate", "deviation:0.5", "--robot", "nothing.toml"], "brings its own robot"),
])
def test_what_a_foreign_environment_cannot_do_fails_with_one_line(demos: Path, tmp_path: Path, one_line_error,
                                                                  extra: list[str], needle: str) -> None:
    one_line_error(["train", str(demos), *extra, "--steps", "10", "--out", str(tmp_path / "x")], needle)
    assert not (tmp_path / "x").exists()


def test_a_bimanual_action_s_grippers_are_found_by_name() -> None:
    """gym-aloha's 14 numbers: each arm's six joint targets, then its gripper; either gripper wrong opens the gate."""
    names = [f"{arm}.{j}" for arm in ("left", "right") for j in ("waist", "shoulder", "elbow", "forearm_roll",
                                                                  "wrist_angle", "wrist_rotate", "gripper")]
    env = SimpleNamespace(robot=None, action_spec=SimpleNamespace(dim=14, names=tuple(names)))
    parts = ActionParts.of(env)
    assert parts.grippers == (6, 13) and parts.targets == (*range(6), *range(7, 13))
    expert = np.zeros(14, np.float32)
    for gripper in (6, 13):
        mine = expert.copy()
        mine[gripper] = 1.0
        assert deviation(mine, expert, parts, 0.05) == pytest.approx(0.1)  # 2 x the gate
    mine = expert.copy()
    mine[8] = 0.03
    assert deviation(mine, expert, parts, 0.05) == pytest.approx(0.03)
