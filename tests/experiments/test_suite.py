"""Meta-World through the generic environment path and `demo bench suite` in miniature; they skip, saying why,
where the optional metaworld package is not installed."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from demo.cli.main import main
from demo.store import EpisodeStore

pytestmark = pytest.mark.skipif(importlib.util.find_spec("metaworld") is None,
                                reason="metaworld is not installed (pip install --no-deps metaworld==3.1.1 runs these)")


def test_metaworld_experts_succeed_in_their_own_environment(tmp_path: Path) -> None:
    assert main(["collect", "--env", "metaworld:reach-v3", "--expert", "metaworld", "--episodes", "3", "--seed", "0",
                 "--out", str(tmp_path / "r.zarr")]) == 0
    with EpisodeStore.open(tmp_path / "r.zarr") as store:
        assert store.meta.features["obs.state"].shape == (39,)
        assert store.meta.action.dim == 4
        assert store.meta.task["env"]["packages"]["metaworld"] == "3.1.1"
        assert all(store.column("success").tolist())
        assert max(store.episode_lengths) < 500  # episodes end at the environment's first success


def test_a_task_set_collects_every_task_into_one_store_and_is_judged_per_task(tmp_path: Path, one_line_error) -> None:
    store_path, run = tmp_path / "mt10.zarr", tmp_path / "run"
    assert main(["collect", "--env", "metaworld:MT10", "--expert", "metaworld", "--episodes", "1", "--seed", "0",
                 "--workers", "2", "--out", str(store_path)]) == 0
    with EpisodeStore.open(store_path) as store:
        tasks = store.column("task").tolist()
        assert store.meta.task["name"] == "env:metaworld:MT10" and len(store.meta.task["env"]["tasks"]) == 10
        assert store.num_episodes == 10 and len(set(tasks)) == 10  # --episodes is per task
        assert tasks[0] == "env:metaworld:reach-v3"  # the set's order, interleaved
    assert main(["train", str(store_path), "--steps", "20", "--out", str(run)]) == 0
    result_path = tmp_path / "eval.json"
    assert main(["eval", str(run), "--episodes", "1", "--json", str(result_path)]) == 0
    result = json.loads(result_path.read_text())
    assert result["episodes"] == 10 and len(result["per_task"]) == 10
    assert [e["task"] for e in result["episodes_detail"]] == tasks
    assert sum(r["successes"] for r in result["per_task"].values()) == result["successes"]
    one_line_error(["collect", "--env", "metaworld:no-such-task-v3", "--expert", "metaworld", "--episodes", "1",
                    "--out", str(tmp_path / "y.zarr")], "is no Meta-World task")


def test_a_task_set_keeps_at_most_the_members_asked_built() -> None:
    from demo.sim.foreign_set import ForeignEnvSet, set_members

    env = ForeignEnvSet("metaworld:MT10", set_members("metaworld:MT10"))
    try:
        for index in range(4):  # interleaved, every member stays built by default
            env.select(index)
        assert env.built() == [0, 1, 2, 3]
        env.keep_at_most(2)
        assert env.built() == [2, 3]  # the least recently selected closed
        env.select(1)
        assert env.built() == [3, 1] and env.active.name == "env:metaworld:push-v3"
        first = env.select(0)  # rebuilt after being closed, and it still runs
        first.reset(0)
        assert env.built() == [1, 0] and np.isfinite(first.observe()["obs.state"]).all()
        assert env.record()["tasks"][0] == "metaworld:reach-v3"  # read once, whether or not member 0 is built
    finally:
        env.close()


@pytest.mark.slow  # ~30 s: one task collected, trained and evaluated in miniature
def test_suite_in_miniature(tmp_path: Path) -> None:
    out = tmp_path / "suite.json"
    assert main(["bench", "suite", "metaworld-mt10", "--tasks", "reach-v3", "--demos", "4", "--episodes", "3",
                 "--steps", "100", "--out", str(tmp_path / "runs"), "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    (task,) = result["tasks"]
    assert task["task"] == "reach-v3" and task["expert"]["episodes"] == 4 and task["policy"]["episodes"] == 3
    assert task["seeds_shared_with_training_data"] == 0
    assert Path(result["figure"]).is_file()
    # A rerun with the same configuration reuses the finished task.
    stamp = (tmp_path / "runs" / "reach-v3" / "result.json").stat().st_mtime_ns
    assert main(["bench", "suite", "metaworld-mt10", "--tasks", "reach-v3", "--demos", "4", "--episodes", "3",
                 "--steps", "100", "--out", str(tmp_path / "runs"), "--json", str(out)]) == 0
    assert (tmp_path / "runs" / "reach-v3" / "result.json").stat().st_mtime_ns == stamp


@pytest.mark.slow  # ~30 s: rendering and an image policy in miniature
def test_suite_from_the_corner_camera_in_miniature(tmp_path: Path, one_line_error) -> None:
    out = tmp_path / "suite.json"
    assert main(["bench", "suite", "metaworld-mt10", "--tasks", "reach-v3", "--camera", "corner@32x32", "--demos", "3",
                 "--episodes", "2", "--steps", "20", "--out", str(tmp_path / "runs"), "--json", str(out)]) == 0
    (task,) = json.loads(out.read_text())["tasks"]
    assert task["expert"]["successes"] == 3 and task["policy"]["episodes"] == 2
    with EpisodeStore.open(tmp_path / "runs" / "reach-v3" / "demos.zarr") as store:
        assert store.meta.features["obs.image_corner"].shape == (32, 32, 3)
        assert store.meta.features["obs.state"].shape == (4,)  # the end effector and gripper: no object, no goal
        image = store.read_episode(0, ["obs.image_corner"])["obs.image_corner"]
        assert image.std() > 10  # a rendered scene, not a blank frame
    one_line_error(["collect", "--env", "metaworld:reach-v3", "--env-opt", "camera=nowhere@32x32", "--expert",
                    "metaworld", "--episodes", "1", "--out", str(tmp_path / "x.zarr")], "no camera 'nowhere'")


def test_the_benchmarks_state_recorded_beside_the_camera_trains_the_encoders_only(tmp_path: Path, one_line_error) -> None:
    store_path, run = tmp_path / "cam.zarr", tmp_path / "run"
    assert main(["collect", "--env", "metaworld:reach-v3", "--env-opt", "camera=corner@32x32", "--env-opt",
                 "env_state=true", "--expert", "metaworld", "--episodes", "2", "--seed", "0", "--out", str(store_path)]) == 0
    with EpisodeStore.open(store_path) as store:
        assert store.meta.features["obs.env_state"].shape == (39,)
        episode = store.read_episode(0, ["obs.state", "obs.env_state"])
        np.testing.assert_array_equal(episode["obs.state"], episode["obs.env_state"][:, :4])  # the same state
    assert main(["train", str(store_path), "--steps", "10", "--aux-target", "obs.env_state", "--out", str(run)]) == 0
    policy = json.loads((run / "run.json").read_text())["policy"]
    assert policy["obs"]["keys"] == ["obs.state"] and policy["spec"]["aux_dim"] == 39  # a target, not an input
    assert main(["eval", str(run), "--episodes", "1"]) == 0
    one_line_error(["collect", "--env", "metaworld:reach-v3", "--env-opt", "env_state=true", "--expert", "metaworld",
                    "--episodes", "1", "--out", str(tmp_path / "x.zarr")], "without --env-opt camera")


@pytest.mark.slow  # ~40 s: the whole set collected, one instruction-conditioned policy trained and evaluated
def test_one_policy_for_the_whole_suite_in_miniature(tmp_path: Path, one_line_error) -> None:
    out = tmp_path / "suite.json"
    assert main(["bench", "suite", "metaworld-mt10", "--one-policy", "--demos", "2", "--episodes", "1", "--steps", "30",
                 "--out", str(tmp_path / "runs"), "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    assert len(result["tasks"]) == 10 and all(r["policy"]["episodes"] == 1 and r["expert"]["episodes"] == 2
                                              for r in result["tasks"])
    assert result["tasks"][0]["task"] == "reach-v3" and result["one_policy"]["seconds"]["train"] > 0
    with EpisodeStore.open(tmp_path / "runs" / "one-policy" / "demos.zarr") as store:
        told = store.column("instruction").tolist()
        assert told[:2] == ["reach the goal", "push the puck to the goal"] and len(set(told)) == 10
    run = json.loads((tmp_path / "runs" / "one-policy" / "bc" / "run.json").read_text())
    assert run["policy"]["spec"]["vocab"] > 10 and "instruction" in run["policy"]
    one_line_error(["bench", "suite", "metaworld-mt10", "--one-policy", "--tasks", "reach-v3"], "--tasks",
                   "whole suite")
    one_line_error(["bench", "suite", "metaworld-mt10", "--no-instructions"], "--one-policy")


def test_one_policy_from_the_camera_records_the_state_it_is_trained_to_predict() -> None:
    from demo.experiments.suite import SuiteConfig, collect_config, one_policy_bc

    camera = SuiteConfig(one_policy=True, camera="corner@64x64")
    assert collect_config(camera, "MT10").task_options == {"camera": "corner@64x64", "env_state": True}
    assert one_policy_bc(camera)["aux_target"] == "obs.env_state" and one_policy_bc(camera)["steps"] == 20000
    # From state, or one policy per task from the camera: no state beside it, no auxiliary target.
    assert "env_state" not in collect_config(SuiteConfig(camera="corner@64x64"), "reach-v3").task_options
    assert "aux_target" not in one_policy_bc(SuiteConfig(one_policy=True))
    mt50 = one_policy_bc(SuiteConfig(suite="metaworld-mt50", one_policy=True, camera="corner@64x64"))
    assert mt50["steps"] == 40000 and mt50["aux_target"] == "obs.env_state"  # MT50's own steps kept
