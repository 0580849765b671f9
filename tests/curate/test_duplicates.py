"""Duplicates: exact copies, near copies and chains are found; distinct episodes are not."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from demo.curate import synthetic
from demo.curate.frames import load_frames
from demo.curate.signals import duplicates as dup
from demo.store import EpisodeStore


def signals_of(tmp_path: Path, datas: list[dict[str, np.ndarray]], params: dup.DuplicateParams = dup.DuplicateParams()):
    path = synthetic.write_store(tmp_path / "s.zarr", [(d, {}) for d in datas])
    with EpisodeStore.open(path) as store:
        return dup.compute(load_frames(store), params)


def test_exact_and_near_duplicates(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    eps = [synthetic.episode(rng) for _ in range(12)]
    eps.append({k: v.copy() for k, v in eps[3].items()})  # 12: exact copy of 3
    near = {k: v.copy() for k, v in eps[5].items()}
    near["action"] += rng.normal(0, 2e-4, near["action"].shape).astype(np.float32)  # 13: near copy of 5
    eps.append(near)
    s = signals_of(tmp_path, eps)
    assert s["dup_of"][12] == 3 and s["dup_of"][13] == 5
    assert s["dup_of"][3] == -1 and s["dup_of"][5] == -1  # the first of a group is the original
    assert (s["dup_of"][[i for i in range(12) if i not in (3, 5)]] == -1).all()
    assert s["dup_distance"][12] == 0.0 and s["dup_distance"][3] == 0.0
    assert 0 < s["dup_distance"][13] < dup.DuplicateParams().tol
    # Distinct episodes are far apart compared with the tolerance.
    assert np.min(s["dup_distance"][[0, 1, 2, 4, 6, 7]]) > 3 * dup.DuplicateParams().tol


def test_a_chain_is_one_group(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    base = synthetic.episode(rng)
    chain = [base]
    for _ in range(3):  # each a small step from the previous: a ~ b ~ c ~ d
        nxt = {k: v.copy() for k, v in chain[-1].items()}
        nxt["obs.joint_pos"] += np.float32(3e-4)
        chain.append(nxt)
    others = [synthetic.episode(rng) for _ in range(5)]
    s = signals_of(tmp_path, others[:2] + chain + others[2:])
    np.testing.assert_array_equal(s["dup_of"][3:6], [2, 2, 2])
    assert s["dup_of"][2] == -1


def test_different_lengths_are_not_duplicates(tmp_path: Path) -> None:
    rng = np.random.default_rng(2)
    base = synthetic.episode(rng)
    longer = {k: np.concatenate([v, np.repeat(v[-1:], 10, axis=0)]) for k, v in base.items()}
    s = signals_of(tmp_path, [base, longer, synthetic.episode(rng)])
    assert (s["dup_of"] == -1).all()
    s = signals_of(tmp_path / "loose", [base, longer, synthetic.episode(rng)], dup.DuplicateParams(tol=0.2, length_tol=0.5))
    assert s["dup_of"][1] == 0


def test_single_episode(tmp_path: Path) -> None:
    s = signals_of(tmp_path, [synthetic.episode(np.random.default_rng(0))])
    assert s["dup_of"][0] == -1 and np.isnan(s["dup_distance"][0])
