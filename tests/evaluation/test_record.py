"""The flywheel: `demo eval --record STORE` stores every rollout as an episode to curate and train on;
HG-DAgger's stores mark its interventions per frame."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from demo.cli.main import main
from demo.collect.scripted import CollectConfig, collect_scripted
from demo.errors import DemoError
from demo.seeds import eval_seeds
from demo.store import EpisodeStore
from demo.imitation.bc import train
from demo.training.config import TrainConfig
from demo.imitation.dagger import INTERVENTION_KEY, DaggerConfig, train_dagger
from demo.training.data import LABEL_KEY
from demo.evaluation.evaluate import EvalConfig, evaluate

torch.set_num_threads(1)
REACH = {"pos_tol": 0.04, "rot_tol": 0.4}


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory, reach_demos) -> Path:
    tmp = tmp_path_factory.mktemp("record")
    train(TrainConfig(data=str(reach_demos(12)), out=str(tmp / "bc"), steps=300, batch_size=64, chunk=4,
                      ensemble=True, policy={"hidden": (64, 64)}))
    return tmp / "bc"


@pytest.mark.slow
def test_record_writes_every_rollout_in_order_whatever_the_workers(run: Path, tmp_path: Path) -> None:
    one = evaluate(EvalConfig(run=str(run), episodes=4, seed=3, record=str(tmp_path / "one.zarr")))
    evaluate(EvalConfig(run=str(run), episodes=4, seed=3, workers=2, record=str(tmp_path / "two.zarr")))
    assert one["record"] == {"store": str(tmp_path / "one.zarr"), "episodes": 4}
    with EpisodeStore.open(tmp_path / "one.zarr") as a, EpisodeStore.open(tmp_path / "two.zarr") as b:
        assert a.num_episodes == 4
        assert a.column("seed").tolist() == eval_seeds(3, 4)  # episode order, not completion order
        assert a.column("crc32").tolist() == b.column("crc32").tolist()  # the same bytes
        assert set(a.column("source")) == {"policy"} and set(a.column("run")) == {str(run)}
        detail = one["episodes_detail"]
        assert a.column("success").tolist() == [e["success"] for e in detail]
        assert a.column("outcome").tolist() == [e["outcome"] for e in detail]
        assert a.episode_lengths.tolist() == [e["length"] for e in detail]
        ep = a.read_episode(0)
        # What the policy executed is the episode's action; the states replay it.
        np.testing.assert_array_equal(ep["action"], ep["info.executed_action"])
        assert a.meta.task["name"] == "reach" and a.meta.task["options"] == REACH
        assert a.meta.provenance[-1]["op"] == "eval" and a.meta.provenance[-1]["run"] == str(run)


def test_recorded_successes_train_a_policy_and_more_rollouts_append(run: Path, tmp_path: Path) -> None:
    store = tmp_path / "flywheel.zarr"
    evaluate(EvalConfig(run=str(run), episodes=3, seed=0, record=str(store)))
    evaluate(EvalConfig(run=str(run), episodes=3, seed=1, record=str(store)))
    with EpisodeStore.open(store) as s:
        assert s.num_episodes == 6 and s.column("seed")[3:].tolist() == eval_seeds(1, 3)
        successes = int(s.column("success").sum())
    if successes >= 2:  # demo train keeps the successes (failures only with --include-failures)
        summary = train(TrainConfig(data=str(store), out=str(tmp_path / "again"), steps=5, batch_size=8,
                                    policy={"hidden": (8,)}, val_fraction=0.0))
        assert summary["train_episodes"] == successes


def test_record_refuses_a_store_of_another_task_before_any_rollout(run: Path, tmp_path: Path, capfd) -> None:
    other = tmp_path / "pick.zarr"
    collect_scripted(CollectConfig(task="pick", episodes=1, seed=0), other, workers=0)
    with pytest.raises(DemoError, match="cannot append: the store records a different task"):
        evaluate(EvalConfig(run=str(run), episodes=2, record=str(other)))
    with EpisodeStore.open(other) as s:
        assert s.num_episodes == 1
    capfd.readouterr()
    assert main(["eval", str(run), "--episodes", "2", "--record", str(other)]) != 0
    err = capfd.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and "pick.zarr" in err[0]
    # The CLI records and says so in its JSON.
    assert main(["eval", str(run), "--episodes", "2", "--record", str(tmp_path / "cli.zarr"), "--json", "-"]) == 0
    assert json.loads(capfd.readouterr().out)["record"]["episodes"] == 2


def test_a_rerun_that_records_the_same_seeds_again_warns(run: Path, tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    """Before, `eval --record` rerun with the same --seed appended the same rollouts without a word."""
    store = tmp_path / "again.zarr"
    argv = ["eval", str(run), "--episodes", "1", "--record", str(store)]
    capsys.readouterr()
    assert main([*argv, "--seed", "5"]) == 0
    assert "warning" not in capsys.readouterr().err  # a new store
    assert main([*argv, "--seed", "5"]) == 0
    warnings = [line for line in capsys.readouterr().err.splitlines() if line.startswith("warning:")]
    assert warnings == [f"warning: {store} already held 1 episode(s) of {run} with these seeds (--seed 5): they "
                        "were recorded again (another --seed gives new episodes)"]
    assert main([*argv, "--seed", "6"]) == 0
    assert "warning" not in capsys.readouterr().err  # other seeds: new episodes
    with EpisodeStore.open(store) as s:
        assert s.column("seed").tolist() == eval_seeds(5, 1) * 2 + eval_seeds(6, 1)


def test_hg_dagger_marks_its_interventions_per_frame(reach_demos, tmp_path: Path) -> None:
    tc = TrainConfig(data=str(reach_demos(8)), out=str(tmp_path / "hg"), steps=60, batch_size=32,
                     policy={"hidden": (32,)}, log_every=30, val_every=30)
    train_dagger(DaggerConfig(train=tc, rounds=1, episodes_per_round=2, round_steps=30, gate="deviation:0.05"))
    store = EpisodeStore.open(tmp_path / "hg" / "data.zarr")
    rounds = store.column("dagger_round")
    assert store.meta.features[INTERVENTION_KEY].dtype == "uint8"
    for i in range(store.num_episodes):
        ep = store.read_episode(i)
        flags = ep[INTERVENTION_KEY].astype(bool)
        if rounds[i] == 0:
            assert flags.all()  # a demonstration: the expert was in control throughout
            continue
        # The expert executed exactly at the marked frames, and those are HG-DAgger's labels.
        same = np.all(np.isclose(ep["info.executed_action"], ep["action"]), axis=1)
        assert np.array_equal(flags, same) and np.array_equal(flags, ep[LABEL_KEY].astype(bool))
        assert int(store.column("takeovers")[i]) == int((np.diff(np.r_[0, flags.astype(int)]) == 1).sum())
