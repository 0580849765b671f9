"""Meta-World through the generic environment path and `demo bench suite` in miniature; they skip, saying why,
where the optional metaworld package is not installed."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

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


def test_a_task_set_is_not_one_environment(tmp_path: Path, one_line_error) -> None:
    one_line_error(["collect", "--env", "metaworld:MT10", "--expert", "metaworld", "--episodes", "1",
                    "--out", str(tmp_path / "x.zarr")], "names a set of tasks")
    one_line_error(["collect", "--env", "metaworld:no-such-task-v3", "--expert", "metaworld", "--episodes", "1",
                    "--out", str(tmp_path / "y.zarr")], "is no Meta-World task")


@pytest.mark.slow  # ~30 s: one task collected, trained and evaluated in miniature
def test_suite_in_miniature(tmp_path: Path) -> None:
    out = tmp_path / "suite.json"
    assert main(["bench", "suite", "metaworld-mt10", "--tasks", "reach-v3", "--demos", "4", "--episodes", "3",
                 "--steps", "100", "--out", str(tmp_path / "runs"), "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    (task,) = result["tasks"]
    assert task["task"] == "reach-v3" and task["expert"]["episodes"] == 4 and task["bc"]["episodes"] == 3
    assert task["seeds_shared_with_training_data"] == 0
    assert Path(result["figure"]).is_file()
    # A rerun with the same configuration reuses the finished task.
    stamp = (tmp_path / "runs" / "reach-v3" / "result.json").stat().st_mtime_ns
    assert main(["bench", "suite", "metaworld-mt10", "--tasks", "reach-v3", "--demos", "4", "--episodes", "3",
                 "--steps", "100", "--out", str(tmp_path / "runs"), "--json", str(out)]) == 0
    assert (tmp_path / "runs" / "reach-v3" / "result.json").stat().st_mtime_ns == stamp
