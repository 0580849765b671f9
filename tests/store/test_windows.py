"""Window sampling: the right frames, padded at episode edges."""

from __future__ import annotations

import numpy as np

from demo.store import WindowSampler


def frames_with_ids(lengths: list[int]) -> tuple[dict[str, np.ndarray], np.ndarray]:
    total = sum(lengths)
    ids = np.arange(total, dtype=np.float32)
    data = {"obs.x": np.stack([ids, -ids], axis=1), "action": ids[:, None] * 10}
    return data, np.cumsum(lengths)


def test_windows_inside_an_episode() -> None:
    data, ends = frames_with_ids([10, 8])
    sampler = WindowSampler(data, ends, ["obs.x"], n_obs=2, horizon=4)
    batch = sampler.get(np.array([5]))
    assert batch.obs["obs.x"][0, :, 0].tolist() == [4, 5]
    assert batch.action[0, :, 0].tolist() == [50, 60, 70, 80]
    assert not batch.action_pad.any()


def test_windows_pad_at_episode_start_and_end() -> None:
    data, ends = frames_with_ids([10, 8])
    sampler = WindowSampler(data, ends, ["obs.x"], n_obs=3, horizon=4)
    first_of_second = sampler.get(np.array([10]))
    assert first_of_second.obs["obs.x"][0, :, 0].tolist() == [10, 10, 10]  # never reaches episode 0
    end_of_first = sampler.get(np.array([8]))
    assert end_of_first.action[0, :, 0].tolist() == [80, 90, 90, 90]  # never reaches episode 1
    assert end_of_first.action_pad[0].tolist() == [False, False, True, True]
    last = sampler.get(np.array([17]))
    assert last.action[0, :, 0].tolist() == [170] * 4


def test_action_offset_and_episode_subset() -> None:
    data, ends = frames_with_ids([5, 5, 5])
    sampler = WindowSampler(data, ends, ["obs.x"], n_obs=2, horizon=3, action_offset=-1, episodes=np.array([1]))
    assert len(sampler) == 5
    assert set(sampler.indices.tolist()) == {5, 6, 7, 8, 9}
    batch = sampler.get(np.array([5]))
    assert batch.action[0, :, 0].tolist() == [50, 50, 60]
    rng = np.random.default_rng(0)
    sampled = sampler.sample(64, rng)
    assert np.all((sampled.index >= 5) & (sampled.index < 10))
    assert sampled.obs["obs.x"].shape == (64, 2, 2) and sampled.action.shape == (64, 3, 1)
