"""DART as published: the injected noise is the learner's error covariance on the expert's data."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from demo.store import EpisodeStore
from demo.imitation.bc import train
from demo.policies.checkpoint import load_bundle
from demo.training.config import TrainConfig
from demo.imitation.dagger import DaggerConfig, learner_actions, train_dagger
from demo.imitation.dart import Dart, noise_covariance
from demo.training.data import frame_indices, prepare

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def demos(reach_demos) -> Path:
    return reach_demos(8)


def test_noise_is_the_learners_error_covariance_on_expert_data(demos: Path, tmp_path: Path) -> None:
    config = TrainConfig(data=str(demos), out=str(tmp_path / "bc"), steps=80, batch_size=64, chunk=1, ensemble=False,
                         policy={"hidden": (32,)}, val_fraction=0.25).resolved()
    train(config)
    bundle = load_bundle(tmp_path / "bc")
    with EpisodeStore.open(demos) as store:
        data = prepare(config, store)
        episodes = {int(i): store.read_episode(int(i)) for i in data.val_episodes}
    frames = frame_indices(data.ends, data.val_episodes)
    cov = noise_covariance(learner_actions(bundle, data, frames), data.action[frames], 7)
    # The same errors, from the policy acting frame by frame as it does in a rollout.
    actor = bundle.actor()
    errors = []
    for ep in episodes.values():
        actor.reset(0)
        for t in range(len(ep["action"])):
            errors.append(actor.policy_action({k: v[t] for k, v in ep.items()})[:7] - ep["action"][t, :7])
    e = np.asarray(errors, np.float64)
    np.testing.assert_allclose(cov, e.T @ e / len(e), rtol=1e-4, atol=1e-9)
    assert cov.shape == (7, 7) and np.all(np.linalg.eigvalsh(cov) >= -1e-12) and np.trace(cov) > 0


@pytest.mark.slow
def test_dart_collects_with_the_estimated_noise(demos: Path, tmp_path: Path) -> None:
    tc = TrainConfig(data=str(demos), out=str(tmp_path / "run"), steps=80, batch_size=64, policy={"hidden": (32,)},
                     val_fraction=0.25, log_every=40, val_every=40)
    summary = train_dagger(DaggerConfig(train=tc, rounds=1, episodes_per_round=3, round_steps=40), family=Dart())
    assert summary["algo"] == "dart"
    cov = np.asarray(summary["rounds"][1]["noise_cov"])
    store = EpisodeStore.open(tmp_path / "run" / "data.zarr")
    new = np.flatnonzero(store.column("dagger_round") == 1)
    assert store.column("source")[new].tolist() == ["dart"] * 3
    noise = []
    for i in new:
        ep = store.read_episode(int(i))
        assert ep["info.labelled"].all() and int(store.column("labels")[i]) == len(ep["action"])
        np.testing.assert_array_equal(ep["info.executed_action"][:, 7], ep["action"][:, 7])  # gripper undisturbed
        noise.append(ep["info.executed_action"][:, :7] - ep["action"][:, :7])
    n = np.concatenate(noise).astype(np.float64)
    # The executed noise has the estimated covariance (hundreds of draws: within 30% on the trace).
    assert abs(np.trace(n.T @ n / len(n)) / np.trace(cov) - 1) < 0.3
    # With alpha, the same direction rescaled to trace alpha / horizon.
    family = Dart(alpha=0.5)
    tc2 = TrainConfig(**{**tc.__dict__, "out": str(tmp_path / "alpha")})
    scaled = np.asarray(train_dagger(DaggerConfig(train=tc2, rounds=1, episodes_per_round=1, round_steps=40),
                                     family=family)["rounds"][1]["noise_cov"])
    np.testing.assert_allclose(np.trace(scaled), 0.5 / 100, rtol=1e-6)
    np.testing.assert_allclose(scaled / np.trace(scaled), cov / np.trace(cov), rtol=1e-5, atol=1e-9)


@pytest.mark.slow
def test_a_label_budget_stops_the_rollouts(demos: Path, tmp_path: Path) -> None:
    tc = TrainConfig(data=str(demos), out=str(tmp_path / "run"), steps=20, batch_size=32, policy={"hidden": (16,)},
                     val_fraction=0.25)
    with EpisodeStore.open(demos) as source:
        demo_labels = source.num_frames
    summary = train_dagger(DaggerConfig(train=tc, rounds=3, episodes_per_round=2, round_steps=10,
                                        max_labels=demo_labels + 1), family=Dart())
    # The first rollout passes the budget: no second rollout, no second round.
    assert [r["round"] for r in summary["rounds"]] == [0, 1] and summary["rounds"][1]["episodes"] == 1
    store = EpisodeStore.open(tmp_path / "run" / "data.zarr")
    assert (store.column("dagger_round") >= 1).sum() == 1
    assert summary["expert_labels"] == demo_labels + store.episode_lengths[-1]
