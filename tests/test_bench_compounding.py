"""The compounding-errors experiment end to end on a miniature: equal label budgets, JSON, PNG."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

from demo.bench.compounding import CompoundingConfig, format_table, run
from demo.cli.main import main
from demo.store import EpisodeStore

torch.set_num_threads(1)


def test_miniature_run_matches_label_budgets(tmp_path: Path, capfd) -> None:
    config = CompoundingConfig(out=str(tmp_path), blocks=(1,), demos=3, pool=6, rounds=1, episodes_per_round=1,
                               steps=30, round_steps=20, hidden=(16,), batch_size=32, chunk=4, eval_episodes=2)
    result = run(config, log=lambda text: None)
    (row,) = result["rows"]
    assert row["blocks"] == 1 and row["horizon"] == 160
    budget = row["expert_labels"]
    assert row["dagger"]["expert_labels"] == budget
    # BC gets the fewest leading demonstrations whose frames reach DAgger's label count.
    with EpisodeStore.open(tmp_path / "stack1" / "pool.zarr") as pool:
        cumulative = np.cumsum(pool.episode_lengths)
    k = row["bc_demos"]
    assert cumulative[k - 1] >= budget and (k == 1 or cumulative[k - 2] < budget)
    assert row["bc"]["expert_labels"] == row["bc_chunk"]["expert_labels"] == cumulative[k - 1]
    for method in ("bc", "dagger", "bc_chunk"):
        assert row[method]["episodes"] == 2 and 0.0 <= row[method]["success_rate"] <= 1.0
    assert Path(result["png"]).stat().st_size > 5000
    # Every method executes the gripper as open/closed (the store's action "gripper" entry).
    from demo.train.checkpoint import load_bundle

    for method in ("bc", "dagger", "bc_chunk"):
        assert load_bundle(row[method]["run"]).execution.binary == (7,)
    assert result["config"]["beta"] == "linear:4" and result["config"]["gate"] == "deviation:0.05"
    assert "DAgger" in format_table(result)
    # A rerun (here the CLI's, its JSON alone on stdout) reuses every stage instead of repeating it.
    capfd.readouterr()
    assert main(["bench", "compounding", "--out", str(tmp_path), "--blocks", "1", "--demos", "3", "--pool", "6",
                 "--rounds", "1", "--episodes-per-round", "1", "--steps", "30", "--round-steps", "20", "--hidden", "16",
                 "--batch-size", "32", "--chunk", "4", "--eval-episodes", "2", "--json", "-"]) == 0
    again = json.loads(capfd.readouterr().out)
    assert again["rows"][0]["bc"] == json.loads(json.dumps(row["bc"])) and again["seconds"] < result["seconds"]
    # ... but not with a different configuration: that needs another --out.
    import dataclasses

    import pytest

    from demo.errors import DemoError

    with pytest.raises(DemoError, match="other hidden"):
        run(dataclasses.replace(config, hidden=(32,)), log=lambda text: None)
