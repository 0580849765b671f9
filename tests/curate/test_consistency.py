"""Action consistency: a contradicting episode stands out; the grid search finds true neighbours."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from demo.curate import synthetic
from demo.curate.frames import load_frames
from demo.curate.signals import consistency as cons
from demo.store import ActionSpec, EpisodeStore, FeatureSpec, StoreMeta


def scores_with_one_flawed(tmp_path: Path, flaws: synthetic.Flaws) -> dict[str, np.ndarray]:
    """Consistency scores of 30 clean episodes (six goals) and, last (index 30), one with ``flaws`` that
    starts like the others and has the first goal."""
    rng = np.random.default_rng(0)
    goals = rng.uniform(-0.5, 0.5, (6, 3))
    episodes = [(synthetic.episode(rng, goal=goals[i % 6]), {}) for i in range(30)]
    episodes.append((synthetic.episode(rng, flaws, goal=goals[0]), {}))
    path = synthetic.write_store(tmp_path / "s.zarr", episodes)
    with EpisodeStore.open(path) as store:
        return cons.compute(load_frames(store))


def test_contradicting_episode_is_the_least_consistent(tmp_path: Path) -> None:
    # From the same start, for the same goal as five others, it heads the other way.
    s = scores_with_one_flawed(tmp_path, synthetic.Flaws(mirror=True))
    c, d = s["consistency"], s["disagreement"]
    assert np.isfinite(c).all()
    assert np.argmin(c) == 30 and np.argmax(d) == 30
    assert c[30] < 0.5
    assert np.median(c[:30]) >= 0.9
    assert d[30] > 2 * np.median(d[:30])
    assert s["coverage"][30] < 0.5 <= np.median(s["coverage"][:30])  # it soon leaves the others' states


def test_reversed_episode_is_novel(tmp_path: Path) -> None:
    # Driving a path backwards visits the others' positions with the opposite velocity: states no one
    # else demonstrated (so no label conflicts with it), which novelty reports.
    s = scores_with_one_flawed(tmp_path, synthetic.Flaws(reverse=True))
    assert np.argmax(s["novelty"]) == 30
    assert s["novelty"][30] > 3 * np.median(s["novelty"][:30])


def test_every_episode_agrees_when_all_are_clean(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    episodes = [(synthetic.episode(rng), {}) for _ in range(40)]
    path = synthetic.write_store(tmp_path / "s.zarr", episodes)
    with EpisodeStore.open(path) as store:
        s = cons.compute(load_frames(store), cons.ConsistencyParams(seed=3))
    assert (s["consistency"] >= 0.7).mean() >= 0.9
    assert (s["novelty"] >= 0).all()


def brute_knn(z: np.ndarray, episode: np.ndarray, queries: np.ndarray, k: int) -> np.ndarray:
    """Distances to the closest frame of each of the k nearest other episodes, exactly."""
    d2 = ((z[queries][:, None, :] - z[None, :, :]) ** 2).sum(-1)
    d2[episode[queries][:, None] == episode[None, :]] = np.inf
    per_episode = np.minimum.reduceat(d2, np.flatnonzero(np.r_[True, episode[1:] != episode[:-1]]), axis=1)
    return np.sort(np.sqrt(per_episode), axis=1)[:, :k]


def test_grid_search_matches_brute_force() -> None:
    rng = np.random.default_rng(0)
    # 200 "episodes" of 40 frames on random smooth curves in 8-D: a manifold like real trajectories.
    t = np.linspace(0, 1, 40)[:, None]
    curves = [rng.normal(size=(1, 8)) + t * rng.normal(size=(1, 8)) + 0.3 * np.sin(6 * t * rng.normal(size=(1, 8))) for _ in range(200)]
    z = np.concatenate(curves).astype(np.float32)
    episode = np.repeat(np.arange(200), 40)
    queries = rng.choice(len(z), 400, replace=False)
    params = cons.ConsistencyParams(k=5)
    a = cons.grid_knn(z, episode, queries, params, 0.0, rng)
    dist, index = cons.merge_knn(a, cons.grid_knn(z, episode, queries, params, 0.5, rng), params.k, episode)
    assert (index >= 0).all()
    assert not (episode[index] == episode[queries][:, None]).any()  # never the query's own episode
    np.testing.assert_allclose(dist, np.sqrt(((z[index] - z[queries][:, None]) ** 2).sum(-1)), rtol=1e-3, atol=1e-3)
    truth = brute_knn(z, episode, queries, params.k)
    # Approximate search: the k-th neighbour found is close to the true k-th nearest episode.
    ratio = dist[:, -1] / truth[:, -1]
    assert np.all(ratio >= 1 - 1e-4)  # never closer than the truth: the distances are real
    assert np.median(ratio) < 1.2 and np.mean(ratio < 1.5) > 0.9
    # Each neighbour from a different episode.
    assert all(len(set(row)) == len(row) for row in episode[index].tolist())


def test_no_lowdim_observations_gives_nan(tmp_path: Path) -> None:
    meta = StoreMeta(fps=10.0, features={"obs.image_front": FeatureSpec((4, 4, 3), "uint8", "camera")},
                     action=ActionSpec("joint_pos", ("a", "b"), ("rad", "rad")))
    rng = np.random.default_rng(0)
    with EpisodeStore.create(tmp_path / "img.zarr", meta) as store:
        for _ in range(3):
            store.append_episode({"action": rng.normal(size=(12, 2)).astype(np.float32),
                                  "obs.image_front": rng.integers(0, 255, (12, 4, 4, 3)).astype(np.uint8)})
        fd = load_frames(store)
    assert fd.obs.shape == (36, 0) and fd.obs_keys == []
    assert np.isnan(cons.compute(fd)["consistency"]).all()
