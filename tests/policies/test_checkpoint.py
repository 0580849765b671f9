"""Checkpoints: a saved run gives the same actions; pickles (bombs) and corrupt files are refused."""

from __future__ import annotations

import json
import os
import pickle
from pathlib import Path

import numpy as np
import pytest
import torch

from demo.bench.load import build_store
from demo.errors import DemoError
from demo.policies import checkpoint as ckpt
from demo.imitation.bc import train
from demo.training.config import TrainConfig

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    tmp = tmp_path_factory.mktemp("ckpt")
    build_store(tmp / "data.zarr", frames=2000, episode_length=50, obs_dim=6, seed=0).close()
    config = TrainConfig(data=str(tmp / "data.zarr"), out=str(tmp / "run"), steps=60, batch_size=32, chunk=4, n_obs=2,
                         ensemble=True, ema=0.9, policy={"hidden": (32, 32)}, include_failures=True, val_every=30)
    train(config)
    return tmp / "run"


def frames(n: int, seed: int = 1) -> list[dict[str, np.ndarray]]:
    rng = np.random.default_rng(seed)
    return [{"obs.state": rng.normal(size=6).astype(np.float32)} for _ in range(n)]


def test_round_trip_gives_the_same_actions(run_dir: Path) -> None:
    a, b = ckpt.load_bundle(run_dir), ckpt.load_bundle(run_dir)
    for key, value in a.policy.state_dict().items():
        assert torch.equal(value, b.policy.state_dict()[key])
    actor_a, actor_b = a.actor(), b.actor()
    actor_a.reset(3)
    actor_b.reset(3)
    for f in frames(12):
        assert np.array_equal(actor_a.act(f), actor_b.act(f))
    # The saved weights are the EMA weights, and they drive the actions.
    state = ckpt.load_train_state(run_dir)
    assert all(torch.equal(state["ema"][k], v) for k, v in a.policy.state_dict().items())
    assert not all(torch.equal(state["policy"][k], v) for k, v in a.policy.state_dict().items())


def test_run_records_what_eval_needs(run_dir: Path) -> None:
    run = json.loads((run_dir / ckpt.RUN_FILE).read_text())
    assert run["policy"]["spec"] == {"obs_dim": 6, "action_dim": 8, "n_obs": 2, "horizon": 4, "obs_layout": [[1, 6]]}
    assert run["policy"]["obs"]["keys"] == ["obs.state"]
    assert run["policy"]["action"]["name"] == "joint_pos"
    assert run["policy"]["execution"] == {"execute": 1, "ensemble": 0.01}
    assert run["task"]["name"] == "bench"
    assert run["data"]["expert_labels"] == 2000
    assert (run_dir / ckpt.CURVES_FILE).stat().st_size > 1000


class Bomb:
    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def test_pickle_bomb_train_state_is_refused(run_dir: Path, tmp_path: Path) -> None:
    marker = tmp_path / "pwned"
    bad = tmp_path / "run"
    bad.mkdir()
    torch.save({"step": 1, "policy": Bomb(marker)}, bad / ckpt.STATE_FILE)
    with pytest.raises(DemoError, match="refusing to load"):
        ckpt.load_train_state(bad)
    with open(bad / ckpt.STATE_FILE, "wb") as f:  # a plain pickle, not even torch's zip format
        pickle.dump({"step": Bomb(marker)}, f)
    with pytest.raises(DemoError, match="refusing to load"):
        ckpt.load_train_state(bad)
    assert not marker.exists()


def test_pickle_in_place_of_weights_is_refused(run_dir: Path, tmp_path: Path) -> None:
    marker = tmp_path / "pwned"
    bad = tmp_path / "run"
    bad.mkdir()
    (bad / ckpt.RUN_FILE).write_text((run_dir / ckpt.RUN_FILE).read_text())
    torch.save({"policy.net.0.weight": Bomb(marker)}, bad / ckpt.POLICY_FILE)
    with pytest.raises(DemoError, match="not a valid safetensors file"):
        ckpt.load_bundle(bad)
    assert not marker.exists()


def test_bad_run_directories_fail_clearly(run_dir: Path, tmp_path: Path) -> None:
    with pytest.raises(DemoError, match="no such run"):
        ckpt.load_bundle(tmp_path / "missing")
    (tmp_path / "x").mkdir()
    with pytest.raises(DemoError, match="not a training run"):
        ckpt.load_bundle(tmp_path / "x")
    (tmp_path / "x" / ckpt.RUN_FILE).write_text("{not json")
    with pytest.raises(DemoError, match="unreadable"):
        ckpt.load_bundle(tmp_path / "x")
    # Weights of another shape than run.json describes.
    bad = tmp_path / "y"
    bad.mkdir()
    run = json.loads((run_dir / ckpt.RUN_FILE).read_text())
    run["policy"]["config"]["hidden"] = [16]
    (bad / ckpt.RUN_FILE).write_text(json.dumps(run))
    (bad / ckpt.POLICY_FILE).write_bytes((run_dir / ckpt.POLICY_FILE).read_bytes())
    with pytest.raises(DemoError, match="does not match"):
        ckpt.load_bundle(bad)


@pytest.mark.parametrize("keys, value, needle", [
    (("train", "chunk"), 1e9, "'train.chunk' must be a whole number from 1 to 10_000, got 1000000000.0"),
    (("train", "chunk"), 2.5, "'train.chunk' must be a whole number from 1 to 10_000, got 2.5"),
    (("policy", "spec", "horizon"), 0, "'policy.spec.horizon' must be a whole number from 1 to 10_000, got 0"),
    (("policy", "spec", "n_obs"), True, "'policy.spec.n_obs' must be a whole number from 1 to 10_000, got True"),
    (("policy", "execution", "execute"), 5, "'policy.execution.execute' (5) exceeds the chunk 'policy.spec.horizon' (4)"),
], ids=["chunk-1e9", "chunk-2.5", "horizon-0", "n_obs-bool", "execute-past-chunk"])
def test_run_json_counts_out_of_range_are_refused_naming_the_key(run_dir: Path, tmp_path: Path, one_line_error,
                                                                 keys: tuple[str, ...], value: object,
                                                                 needle: str) -> None:
    """Before, a chunk of 1e9 (read with int(), or not read by eval at all) evaluated normally."""
    bad = tmp_path / "run"
    bad.mkdir()
    run = json.loads((run_dir / ckpt.RUN_FILE).read_text())
    section = run
    for key in keys[:-1]:
        section = section[key]
    section[keys[-1]] = value
    (bad / ckpt.RUN_FILE).write_text(json.dumps(run))
    (bad / ckpt.POLICY_FILE).write_bytes((run_dir / ckpt.POLICY_FILE).read_bytes())
    with pytest.raises(DemoError) as caught:
        ckpt.load_bundle(bad)
    assert caught.value.where == str(bad / ckpt.RUN_FILE) and caught.value.problem == needle
    one_line_error(["eval", str(bad), "--episodes", "1"], f"{bad / ckpt.RUN_FILE}: {needle}")
