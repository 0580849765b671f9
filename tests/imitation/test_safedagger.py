"""SafeDAgger: the classifier learns where the learner deviates; the expert takes over exactly where it fires."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from demo.errors import DemoError
from demo.store import EpisodeStore
from demo.training.config import TrainConfig
from demo.imitation.dagger import INTERVENTION_KEY, ActionParts, DaggerConfig, deviation, train_dagger
from demo.training.data import LABEL_KEY
from demo.imitation.safedagger import SafeDagger, fit_classifier

torch.set_num_threads(1)


def test_classifier_learns_deviation_labels() -> None:
    rng = np.random.default_rng(0)
    x = rng.uniform(-1, 1, (3000, 5)).astype(np.float32)
    y = x[:, 0] + 0.5 * x[:, 1] > 0.9  # rare (about 1 in 8), as deviations are
    layers = fit_classifier(x, y, hidden=(32, 32), steps=600, seed=0)
    from demo.imitation.safedagger import DeviationClassifier
    from demo.policies.observation import ObsSpec

    clf = DeviationClassifier(layers, ObsSpec(("obs.x",), (5,)), -np.ones(5), np.ones(5))
    test = rng.uniform(-1, 1, (2000, 5)).astype(np.float32)
    truth = test[:, 0] + 0.5 * test[:, 1] > 0.9
    fired = clf.logits(test) > 0
    assert (fired == truth).mean() > 0.93 and fired[truth].mean() > 0.85
    # The gate reads the frame's observation through the learner's normaliser.
    assert clf({"obs.x": np.array([1.0, 1.0, 0, 0, 0], np.float32)}, None, None) is True
    assert clf({"obs.x": np.array([-1.0, -1.0, 0, 0, 0], np.float32)}, None, None) is False
    # One class only: a constant classifier of that class.
    never = DeviationClassifier(fit_classifier(x, np.zeros(len(x), bool), (8,), 10, 0), clf.obs_spec, clf.low, clf.high)
    assert not (never.logits(test) > 0).any()


def test_deviation_is_hg_daggers_rule() -> None:
    label = np.zeros((3, 8), np.float32)
    mine = label.copy()
    mine[1, 2] = 0.08  # an arm joint 0.08 rad off
    mine[2, 7] = 1.0  # the gripper the other way
    d = deviation(mine, label, ActionParts(tuple(range(7)), (7,)), 0.05)
    assert d[0] == 0 and np.isclose(d[1], 0.08) and d[2] >= 0.1


@pytest.fixture(scope="module")
def demos(reach_demos) -> Path:
    return reach_demos(10)


@pytest.mark.slow
def test_safedagger_takes_over_where_the_classifier_fires(demos: Path, tmp_path: Path) -> None:
    tc = TrainConfig(data=str(demos), out=str(tmp_path / "run"), steps=150, batch_size=64, policy={"hidden": (64, 64)},
                     val_fraction=0.3, log_every=50, val_every=50)
    family = SafeDagger(steps=200)
    summary = train_dagger(DaggerConfig(train=tc, rounds=1, episodes_per_round=2, round_steps=60, gate="deviation:0.05"),
                           family=family)
    assert summary["algo"] == "safedagger"
    entry = summary["rounds"][1]
    assert entry["classifier_frames"] > 0 and 0 <= entry["classifier_positive_rate"] <= 1
    store = EpisodeStore.open(tmp_path / "run" / "data.zarr")
    classifier = family.classifier
    labels = 0
    for i in np.flatnonzero(store.column("dagger_round") == 1):
        ep = store.read_episode(int(i))
        flags = ep[LABEL_KEY].astype(bool)
        assert np.array_equal(flags, ep[INTERVENTION_KEY].astype(bool))
        # The gate is the classifier on the frame's observation, nothing else.
        fired = [classifier({k: v[t] for k, v in ep.items()}, None, None) for t in range(len(flags))]
        assert np.array_equal(flags, fired)
        # The expert's action ran exactly where it was asked.
        np.testing.assert_array_equal(ep["info.executed_action"][flags], ep["action"][flags])
        assert int(store.column("labels")[i]) == int(flags.sum())
        assert int(store.column("takeovers")[i]) == int((np.diff(np.r_[0, flags.astype(int)]) == 1).sum())
        labels += int(flags.sum())
    assert entry["labels_round"] == labels and entry["takeovers"] == int(store.column("takeovers")[-2:].sum())


@pytest.mark.slow
def test_safedagger_needs_a_threshold_and_held_out_episodes(demos: Path, tmp_path: Path) -> None:
    tc = TrainConfig(data=str(demos), out=str(tmp_path / "a"), steps=20, batch_size=32, policy={"hidden": (16,)})
    with pytest.raises(DemoError, match="--gate"):
        train_dagger(DaggerConfig(train=tc, rounds=1, episodes_per_round=1, round_steps=10), family=SafeDagger(steps=5))
    tc = TrainConfig(data=str(demos), out=str(tmp_path / "b"), steps=20, batch_size=32, policy={"hidden": (16,)},
                     val_fraction=0.0)
    with pytest.raises(DemoError, match="--val-fraction"):
        train_dagger(DaggerConfig(train=tc, rounds=1, episodes_per_round=1, round_steps=10, gate="deviation:0.05"),
                     family=SafeDagger(steps=5))
