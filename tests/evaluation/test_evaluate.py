"""Evaluation in the simulator (reach): BC beats an untrained policy, results are deterministic and
worker-independent, seeds are disjoint from the data's, wrong tasks are refused, videos are written."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from demo.cli.main import main
from demo.collect.scripted import CollectConfig, collect_scripted
from demo.errors import DemoError
from demo.sim.robot import BUILTIN_CONFIG
from demo.imitation.bc import train
from demo.training.config import TrainConfig
from demo.evaluation.evaluate import EvalConfig, evaluate, wilson_interval

torch.set_num_threads(1)
# A looser reach than the default (1 cm, 0.1 rad), so that a seconds-long run on 30 demos shows.
REACH = {"pos_tol": 0.04, "rot_tol": 0.4}


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    tmp = tmp_path_factory.mktemp("eval")
    collect_scripted(CollectConfig(task="reach", episodes=30, seed=0, task_options=REACH), tmp / "reach.zarr", workers=0)
    base = dict(data=str(tmp / "reach.zarr"), batch_size=64, chunk=8, ensemble=True, policy={"hidden": (256, 256)})
    train(TrainConfig(out=str(tmp / "bc"), steps=1500, **base))
    train(TrainConfig(out=str(tmp / "untrained"), steps=1, lr=1e-9, **base))
    return {"data": tmp / "reach.zarr", "bc": tmp / "bc", "untrained": tmp / "untrained", "tmp": tmp}


@pytest.mark.slow
def test_short_bc_run_beats_an_untrained_policy_on_reach(runs: dict[str, Path]) -> None:
    trained = evaluate(EvalConfig(run=str(runs["bc"]), episodes=12, seed=0))
    untrained = evaluate(EvalConfig(run=str(runs["untrained"]), episodes=12, seed=0))
    assert trained["successes"] >= untrained["successes"] + 3, (trained["successes"], untrained["successes"])
    assert trained["task"] == "reach" and trained["task_options"] == REACH
    assert untrained["failures"].get("timeout", 0) >= 1


@pytest.mark.slow
def test_eval_is_deterministic_and_independent_of_workers(runs: dict[str, Path]) -> None:
    one = evaluate(EvalConfig(run=str(runs["bc"]), episodes=4, seed=5))
    again = evaluate(EvalConfig(run=str(runs["bc"]), episodes=4, seed=5))
    two = evaluate(EvalConfig(run=str(runs["bc"]), episodes=4, seed=5, workers=2))
    assert one["episodes_detail"] == again["episodes_detail"] == two["episodes_detail"]
    other = evaluate(EvalConfig(run=str(runs["bc"]), episodes=4, seed=6))
    assert [e["seed"] for e in other["episodes_detail"]] != [e["seed"] for e in one["episodes_detail"]]


@pytest.mark.slow
def test_eval_reports_no_seeds_shared_with_the_training_data(runs: dict[str, Path]) -> None:
    # The streams themselves are disjoint (tests/core/test_seeds.py); eval also checks the run's own data.
    result = evaluate(EvalConfig(run=str(runs["bc"]), episodes=3, seed=0))
    assert result["seeds_shared_with_training_data"] == 0


@pytest.mark.slow
def test_other_task_or_options_are_refused(runs: dict[str, Path]) -> None:
    with pytest.raises(DemoError, match="trained on task 'reach'; it cannot be evaluated on 'pick'"):
        evaluate(EvalConfig(run=str(runs["bc"]), task="pick", episodes=1))
    with pytest.raises(DemoError, match="options"):
        evaluate(EvalConfig(run=str(runs["bc"]), task_options={"pos_tol": 0.01}, episodes=1))
    # The run names its robot; another arm under that name is refused before any rollout (identity is the
    # content: the config and its files), the same arm under another name is the arm it was trained on.
    run = json.loads((runs["bc"] / "run.json").read_text())
    run["robot"]["name"] = "another_arm"
    other = runs["tmp"] / "other_robot"
    other.mkdir(exist_ok=True)
    (other / "run.json").write_text(json.dumps(run))
    (other / "policy.safetensors").write_bytes((runs["bc"] / "policy.safetensors").read_bytes())
    assert evaluate(EvalConfig(run=str(other), episodes=1))["robot_trained_on"] is True
    config = runs["tmp"] / "moved.toml"
    config.write_text(BUILTIN_CONFIG.read_text().replace('mjcf = "panda.xml"', f'mjcf = "{BUILTIN_CONFIG.parent / "panda.xml"}"')
                      + "base_pos = [0.02, 0.0, 0.0]\n")
    with pytest.raises(DemoError, match="another arm of the same name.*it cannot be evaluated on 'panda_prim'"):
        evaluate(EvalConfig(run=str(runs["bc"]), robot=str(config), episodes=1))


@pytest.mark.slow
def test_cli_eval_json_and_video(runs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "eval.json"
    rc = main(["eval", str(runs["bc"]), "--episodes", "2", "--seed", "1", "--json", str(out),
               "--video", str(tmp_path / "v.gif"), "--video-episodes", "2", "--video-size", "64"])
    assert rc == 0
    result = json.loads(out.read_text())
    lo, hi = result["ci95"]
    assert result["episodes"] == 2 and lo <= result["success_rate"] <= hi
    assert result["video"]["episodes"] == 2 and (tmp_path / "v.gif").stat().st_size > 1000
    from PIL import Image

    with Image.open(tmp_path / "v.gif") as gif:
        assert gif.n_frames == result["video"]["frames"] > 5
    rc = main(["eval", str(runs["bc"]), "--task", "pick", "--episodes", "1"])
    err = capsys.readouterr().err
    assert rc == 1 and "error:" in err and "cannot be evaluated on 'pick'" in err and "Traceback" not in err


def test_wilson_interval() -> None:
    assert wilson_interval(50, 100) == pytest.approx((0.4038, 0.5962), abs=1e-4)
    lo, hi = wilson_interval(0, 10)
    assert lo == 0.0 and hi == pytest.approx(0.2775, abs=1e-4)
    lo, hi = wilson_interval(100, 100)
    assert hi == 1.0 and lo == pytest.approx(0.9630, abs=1e-4)
    assert np.isclose(sum(wilson_interval(3, 7)), 2 * (3 + 1.96**2 / 2) / (7 + 1.96**2), atol=1e-3)


class _RamsObstacle:
    """An actor that holds the arm still after putting the avoid obstacle against the hand."""

    told = ""  # the episode's instruction (none)

    def reset(self, seed: int, env: object = None) -> None:
        from demo.sim.avoid import OBSTACLE_HALF

        ee = env.ee_pose()[0]
        env.set_mocap_pose(env.task.obstacle_mocap, np.array([ee[0] + 0.09, ee[1], OBSTACLE_HALF[2]]))

    def act(self, frame: dict[str, np.ndarray]) -> np.ndarray:
        return np.append(frame["obs.joint_pos"], 0.0)


def test_a_task_failure_is_its_own_outcome() -> None:
    from demo.sim import make_env
    from demo.evaluation.evaluate import run_episode

    env = make_env("avoid")
    try:
        outcome = run_episode(env, _RamsObstacle(), 0, 7, max_steps=5)
    finally:
        env.close()
    assert not outcome.success and outcome.outcome == "collision"


@pytest.mark.slow
def test_video_on_a_full_disk_names_the_file_and_leaves_none(runs: dict[str, Path], tmp_path: Path) -> None:
    """A file-size limit (RLIMIT_FSIZE) stands in for a full disk: the GIF is staged, so none is left behind."""
    import os
    import resource
    import signal
    import subprocess
    import sys

    def limit() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails (EFBIG) instead of killing
        resource.setrlimit(resource.RLIMIT_FSIZE, (20_000, 20_000))

    video = tmp_path / "v.gif"
    done = subprocess.run([sys.executable, "-m", "demo", "eval", str(runs["bc"]), "--episodes", "2", "--video", str(video),
                           "--video-size", "128"], capture_output=True, text=True, preexec_fn=limit,
                          env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    lines = done.stderr.strip().splitlines()
    assert done.returncode != 0 and lines[-1].startswith(f"error: {video}"), done.stderr
    assert "Traceback" not in done.stderr
    assert list(tmp_path.iterdir()) == []  # no truncated GIF, no staging file
