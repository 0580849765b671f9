"""avoid collection: the two episodes of a pair start from the same state and pass on opposite sides."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from demo.collect.scripted import CollectConfig, collect_scripted, start_seed
from demo.seeds import episode_seed
from demo.store import EpisodeStore


def test_a_pair_shares_its_start_state_and_takes_both_sides(tmp_path: Path) -> None:
    collect_scripted(CollectConfig(task="avoid", episodes=6, seed=3), tmp_path / "a.zarr", workers=0)
    store = EpisodeStore.open(tmp_path / "a.zarr", "r")
    seeds, modes = store.column("seed").tolist(), store.column("expert_mode").tolist()
    # the seed column is the reset seed: honest about the shared start state
    assert seeds == [episode_seed(3, k) for k in range(3) for _ in range(2)]
    assert all(modes[2 * k] != modes[2 * k + 1] for k in range(3)) and set(modes) == {"left", "right"}
    assert store.column("success").all()
    for k in range(3):
        a, b = store.read_episode(2 * k), store.read_episode(2 * k + 1)
        for key in ("obs.ee_pos", "obs.joint_pos", "obs.obstacle_pos", "obs.goal_pos"):
            np.testing.assert_array_equal(a[key][0], b[key][0])
        # ... and then they part: one passes at +y of the obstacle, the other at -y
        side = [np.sign(e["obs.ee_pos"][:, 1] - e["obs.obstacle_pos"][:, 1])[np.argmax(
            np.abs(e["obs.ee_pos"][:, 1] - e["obs.obstacle_pos"][:, 1]))] for e in (a, b)]
        assert side[0] == -side[1]
    # other tasks keep one start state per episode
    assert [start_seed(CollectConfig(task="reach", seed=3), i) for i in range(3)] == [episode_seed(3, i) for i in range(3)]


def test_append_after_an_odd_count_completes_the_pair(tmp_path: Path) -> None:
    collect_scripted(CollectConfig(task="avoid", episodes=4, seed=1), tmp_path / "whole.zarr", workers=0)
    collect_scripted(CollectConfig(task="avoid", episodes=1, seed=1), tmp_path / "parts.zarr", workers=0)
    collect_scripted(CollectConfig(task="avoid", episodes=3, seed=1), tmp_path / "parts.zarr", workers=0, append=True)
    whole, parts = EpisodeStore.open(tmp_path / "whole.zarr", "r"), EpisodeStore.open(tmp_path / "parts.zarr", "r")
    for column in ("seed", "expert_mode"):
        assert parts.column(column).tolist() == whole.column(column).tolist()
    for i in range(4):
        np.testing.assert_array_equal(parts.read_episode(i)["action"], whole.read_episode(i)["action"])
