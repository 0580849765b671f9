"""The compounding-errors experiment end to end on a miniature: every method, label budgets, fits, JSON, PNG."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from demo.experiments.compounding import METHODS, CompoundingConfig, fit_growth, format_table, meets_target, run
from demo.cli.main import main
from demo.errors import DemoError
from demo.sim import make_env
from demo.sim.rollout import run_expert
from demo.store import EpisodeStore
from demo.policies.checkpoint import load_bundle, read_run

torch.set_num_threads(1)


@pytest.mark.slow
def test_miniature_run_matches_label_budgets(tmp_path: Path, capfd) -> None:
    config = CompoundingConfig(out=str(tmp_path), values=(1,), demos=3, pool=6, rounds=1, episodes_per_round=1,
                               steps=30, round_steps=20, hidden=(16,), batch_size=32, chunk=4, eval_episodes=2,
                               candidates=1, val_fraction=0.34)
    result = run(config, log=lambda text: None)
    (row,) = result["rows"]
    assert row["repeat"] == 1 and row["horizon"] == 160 and row["expert_success"] == 1.0
    budget = row["expert_labels"]
    assert row["hg_dagger"]["expert_labels"] == budget
    # BC gets the fewest leading demonstrations whose frames reach HG-DAgger's label count.
    with EpisodeStore.open(tmp_path / "stack_repeat1" / "pool.zarr") as pool:
        cumulative = np.cumsum(pool.episode_lengths)
    k = row["bc_demos"]
    assert cumulative[k - 1] >= budget and (k == 1 or cumulative[k - 2] < budget)
    assert row["bc"]["expert_labels"] == row["bc_chunk"]["expert_labels"] == cumulative[k - 1]
    with EpisodeStore.open(tmp_path / "stack_repeat1" / "noisy_pool.zarr") as noisy:
        assert set(noisy.column("noise")) == {config.noise}
        assert noisy.episode_lengths[: row["dart_fixed_demos"]].sum() >= budget
    for method in METHODS:
        assert row[method]["episodes"] == 2 and 0.0 <= row[method]["success_rate"] <= 1.0, method
        assert result["fits"][method]["model"].startswith("success = s0")
    # The family's members started from the same demonstrations and report their rounds.
    for method in ("dagger", "dart", "perturb", "safedagger", "aggrevate"):
        assert row[method]["rounds"][0]["labels_total"] == row["demo_labels"], method
    assert "takeovers" in row["safedagger"]["rounds"][1] and "noise_std" in row["dart"]["rounds"][1]
    assert Path(result["png"]).stat().st_size > 5000
    # Every method executes the gripper as open/closed (the store's action "gripper" entry).
    for method in METHODS:
        assert load_bundle(row[method]["run"]).execution.binary == (7,)
    assert result["config"]["beta"] == "linear:4" and result["config"]["gate"] == "deviation:0.03"
    assert "hg_dagger" in format_table(result) and result["meets_target"] is False
    # A rerun (here the CLI's, its JSON alone on stdout) reuses every stage instead of repeating it.
    capfd.readouterr()
    assert main(["bench", "compounding", "--out", str(tmp_path), "--values", "1", "--demos", "3", "--pool", "6",
                 "--rounds", "1", "--episodes-per-round", "1", "--steps", "30", "--round-steps", "20",
                 "--hidden", "16", "--batch-size", "32", "--chunk", "4", "--eval-episodes", "2", "--val-fraction", "0.34",
                 "--candidates", "1", "--methods", "bc,hg_dagger,safedagger", "--json", "-"]) == 0
    again = json.loads(capfd.readouterr().out)
    assert again["rows"][0]["bc"] == json.loads(json.dumps(row["bc"])) and again["seconds"] < result["seconds"]
    assert set(again["fits"]) == {"bc", "hg_dagger", "safedagger"}
    # ... but not with a different configuration: that needs another --out.
    with pytest.raises(DemoError, match="other hidden"):
        run(dataclasses.replace(config, hidden=(32,)), log=lambda text: None)


@pytest.mark.slow
def test_a_fixed_label_budget_stops_hg_dagger_and_is_part_of_the_cache(tmp_path: Path) -> None:
    config = CompoundingConfig(out=str(tmp_path), values=(1,), demos=3, pool=6, rounds=4, episodes_per_round=2,
                               steps=30, round_steps=20, hidden=(16,), batch_size=32, eval_episodes=2, val_fraction=0.34,
                               methods=("bc", "hg_dagger"), warm_start=True, max_labels=250)
    (row,) = run(config, log=lambda text: None)["rows"]
    totals = [r["labels_total"] for r in row["hg_dagger"]["rounds"]]
    # Stopped by the budget (before its last round), by the end of the episode that reached it.
    assert len(totals) < 1 + config.rounds and totals[-2] < 250 <= totals[-1] == row["expert_labels"]
    assert row["bc"]["expert_labels"] >= row["expert_labels"]
    assert read_run(row["hg_dagger"]["run"])["dagger"]["warm_start"] is True
    with pytest.raises(DemoError, match="other max_labels"):
        run(dataclasses.replace(config, max_labels=300), log=lambda text: None)
    # A directory made before a key existed ran without it: no warm start, no fixed budget.
    saved = tmp_path / "stack_repeat1" / "configuration.json"
    old = json.loads(saved.read_text())
    del old["warm_start"], old["max_labels"]
    saved.write_text(json.dumps(old))
    with pytest.raises(DemoError, match="other max_labels, warm_start"):
        run(config, log=lambda text: None)
    with pytest.raises(DemoError, match="at least 1"):
        dataclasses.replace(config, max_labels=0).check()


@pytest.mark.slow
def test_chunked_learners_give_the_family_the_chunked_bc_learner(tmp_path: Path) -> None:
    config = CompoundingConfig(out=str(tmp_path), values=(1,), demos=3, pool=6, rounds=1, episodes_per_round=1,
                               steps=30, round_steps=20, hidden=(16,), batch_size=32, chunk=4, eval_episodes=2,
                               val_fraction=0.34, methods=("bc", "bc_chunk", "hg_dagger"), chunked_learners=True)
    result = run(config, log=lambda text: None)
    (row,) = result["rows"]
    hg, bc, chunked = (load_bundle(row[m]["run"]) for m in ("hg_dagger", "bc", "bc_chunk"))
    assert hg.policy.spec.horizon == chunked.policy.spec.horizon == 4 and bc.policy.spec.horizon == 1
    assert hg.execution.ensemble == chunked.execution.ensemble is not None
    assert result["config"]["chunked_learners"] is True
    with pytest.raises(DemoError, match="other chunked_learners"):
        run(dataclasses.replace(config, chunked_learners=False), log=lambda text: None)


def test_fit_recovers_the_failure_rate() -> None:
    horizons = [160, 260, 360, 460]
    rate, s0 = 0.004, 0.95
    points = [(h, int(round(1000 * s0 * np.exp(-rate * h))), 1000) for h in horizons]
    fit = fit_growth(points)
    assert abs(fit["rate_per_step"] - rate) < 3e-4 and abs(fit["s0"] - s0) < 0.05
    assert abs(fit["half_horizon"] - np.log(2) / fit["rate_per_step"]) < 1e-9
    flat = fit_growth([(h, 90, 100) for h in horizons])
    assert flat["rate_per_step"] < 1e-4


def test_target_needs_four_horizons_and_a_growing_gap() -> None:
    def row(h: int, hg: float, bc: float) -> dict:
        return {"horizon": h, "hg_dagger": {"success_rate": hg}, "bc": {"success_rate": bc}}

    assert meets_target([row(160, 0.95, 0.8), row(260, 0.9, 0.6), row(360, 0.85, 0.45), row(460, 0.82, 0.3)])
    assert not meets_target([row(160, 0.95, 0.8), row(260, 0.9, 0.6), row(460, 0.82, 0.3)])  # three horizons
    assert not meets_target([row(160, 0.95, 0.4), row(260, 0.9, 0.5), row(360, 0.85, 0.45), row(460, 0.82, 0.5)])


def test_stack_repeat_is_the_horizon_the_bench_climbs() -> None:
    """stack --repeat K: the same one-block stack built K times, the pad moving after each; K = 1 is stack."""
    plain, once = make_env("stack", blocks=1), make_env("stack", blocks=1, repeat=1)
    np.testing.assert_array_equal(plain.reset(5)["obs.object_pos"], once.reset(5)["obs.object_pos"])
    np.testing.assert_array_equal(plain.get_state(), once.get_state())
    env = make_env("stack", blocks=1, repeat=3)
    assert env.horizon == 360 and once.horizon == 160
    episode = run_expert(env, 1, record=True)
    assert episode.success
    pads = episode.data["obs.goal_pos"]
    moves = np.flatnonzero(np.abs(np.diff(pads[:, 0])) + np.abs(np.diff(pads[:, 1])) > 1e-6)
    assert len(moves) == 2 and int(env.data.userdata[0]) == 2  # two finished stacks moved the pad
    assert np.linalg.norm(pads[moves[0] + 1, :2] - pads[0, :2]) >= 0.18
    # Success only with the last stack: the frame before the first move held a finished stack.
    env.set_state(episode.data["sim.state"][moves[0]])
    assert not env.success()


def test_stack_respawn_puts_the_cube_back_on_the_table_each_cycle() -> None:
    """respawn = 1: after each finished stack but the last, the cube is put back on the table at a
    spot drawn at reset, away from both pads; the pad's spots are those of repeat alone."""
    plain, respawning = make_env("stack", blocks=1, repeat=3), make_env("stack", blocks=1, repeat=3, respawn=1)
    plain.reset(2)
    respawning.reset(2)
    np.testing.assert_array_equal(plain.data.userdata[:7], respawning.data.userdata[:7])
    episode = run_expert(respawning, 2, record=True)
    assert episode.success and int(respawning.data.userdata[0]) == 2
    cube, pads = episode.data["obs.object_pos"][:, 0], episode.data["obs.goal_pos"]
    moves = np.flatnonzero(np.abs(np.diff(pads[:, 0])) + np.abs(np.diff(pads[:, 1])) > 1e-6)
    assert len(moves) == 2
    for m in moves:  # the frame after a pad move: the cube rests on the table, away from both pads
        after = cube[m + 1]
        assert abs(after[2] - 0.02) < 0.002
        assert min(np.linalg.norm(after[:2] - pads[m, :2]), np.linalg.norm(after[:2] - pads[m + 1, :2])) >= 0.09
    assert episode.length > run_expert(make_env("stack", blocks=1, repeat=3), 2).length  # whole cycles take longer
    with pytest.raises(DemoError, match="respawn must be 0 or 1"):
        make_env("stack", blocks=1, repeat=2, respawn=2)
