"""Behaviour cloning end to end on a synthetic store: it learns the mapping and records what it used."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from demo.policies import checkpoint as ckpt
from demo.imitation.bc import train
from demo.training.config import TrainConfig

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def data(tmp_path_factory: pytest.TempPathFactory, synthetic_store) -> Path:
    return synthetic_store(tmp_path_factory.mktemp("bc") / "data.zarr")


def test_bc_learns_the_mapping(data: Path, tmp_path: Path, tiny_bc_config) -> None:
    summary = train(tiny_bc_config(data, tmp_path / "run"))
    metrics = json.loads((tmp_path / "run" / ckpt.METRICS_FILE).read_text())
    first_val = metrics["val_loss"][0][1]
    assert metrics["val_loss"][0][0] == 0 and summary["val_loss"] < first_val / 5
    # Failed episodes (every 6th) are left out by default; a validation split was drawn.
    run = json.loads((tmp_path / "run" / ckpt.RUN_FILE).read_text())
    used = set(run["data"]["train_episodes"]) | set(run["data"]["val_episodes"])
    assert used == {i for i in range(24) if i % 6 != 5}
    assert len(run["data"]["val_episodes"]) == 2
    # Default observation (no cameras): low-dim keys without velocities; [1, 3] objects flattened.
    assert run["policy"]["obs"] == {"keys": ["obs.joint_pos", "obs.object_pos"], "dims": [2, 3], "transforms": ["", ""]}
    assert run["policy"]["relative_actions"] == {"obs_key": "obs.joint_pos", "obs_dims": [0, 1], "action_dims": [0, 1]}


def test_python_callers_get_the_policys_defaults(data: Path, tmp_path: Path) -> None:
    """A bare TrainConfig trains what `demo train` trains: BC's chunks with temporal ensembling."""
    train(TrainConfig(data=str(data), out=str(tmp_path / "run"), steps=5, policy={"hidden": (16,)}))
    run = json.loads((tmp_path / "run" / ckpt.RUN_FILE).read_text())
    assert run["train"]["chunk"] == 16 and run["train"]["ensemble"] is True
    assert run["policy"]["execution"]["ensemble"] == pytest.approx(0.01)
