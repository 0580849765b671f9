"""Data-parallel training (torchrun, DDP on gloo): the same tiny BC run with 1 and 2 processes."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from demo.cli.main import main
from demo.collect.scripted import CollectConfig, collect_scripted

pytestmark = pytest.mark.slow  # torchrun processes: ~60 s in all

ARGS = ["--steps", "300", "--batch-size", "32", "--chunk", "2", "--policy-opt", "hidden=32,32"]  # loss every 100 steps


@pytest.fixture(scope="module")
def reach(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("ddp") / "reach.zarr"
    collect_scripted(CollectConfig(task="reach", episodes=4, seed=0, task_options={"pos_tol": 0.04, "rot_tol": 0.4}),
                     path, workers=0)
    return path


def files(run: Path) -> set[str]:
    return {str(p.relative_to(run)) for p in run.rglob("*")}


def test_two_gloo_processes_train_one_run_written_by_rank_0(reach: Path, tmp_path: Path) -> None:
    one, two = tmp_path / "one", tmp_path / "two"
    assert main(["train", str(reach), "--out", str(one), *ARGS]) == 0
    env = {**os.environ, "MUJOCO_GL": "egl"}
    done = subprocess.run([sys.executable, "-m", "demo", "train", str(reach), "--out", str(two), *ARGS, "--nproc", "2",
                           "--json", "-"], capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    summary = json.loads(done.stdout)  # one summary: rank 1 prints nothing
    assert summary["step"] == 300 and summary["out"] == str(two)
    # Rank 0 alone wrote the directory: the same files as the 1-process run, nothing stray (tmp files).
    assert files(two) == files(one)
    record = json.loads((two / "run.json").read_text())
    assert record["data_parallel"] == {"processes": 2, "backend": "gloo", "global_batch_size": 64}
    assert "data_parallel" not in json.loads((one / "run.json").read_text())
    losses = [loss for _, loss in json.loads((two / "metrics.json").read_text())["train_loss"]]
    assert len(losses) == 3 and losses[-1] < 0.8 * losses[0]
    rates = json.loads((two / "metrics.json").read_text())["samples_per_s"]  # what bench train --nproc reads
    assert [step for step, _ in rates] == [100, 200, 300] and min(r for _, r in rates) > 0
    # Another number of processes continues it (one process here), and the result evaluates.
    assert main(["train", str(reach), "--out", str(two), *ARGS[2:], "--steps", "400", "--resume"]) == 0
    assert json.loads((two / "metrics.json").read_text())["final"]["step"] == 400
    out = tmp_path / "eval.json"
    assert main(["eval", str(two), "--episodes", "2", "--json", str(out)]) == 0
    assert json.loads(out.read_text())["episodes"] == 2


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA GPU on this machine")
def test_one_gpu_under_torchrun_trains_over_nccl_and_evaluates_on_the_cpu(reach: Path, tmp_path: Path) -> None:
    run = tmp_path / "gpu"
    done = subprocess.run([sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node=1",
                           "-m", "demo", "train", str(reach), "--out", str(run), *ARGS, "--device", "cuda", "--json", "-"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    record = json.loads((run / "run.json").read_text())
    assert record["data_parallel"] == {"processes": 1, "backend": "nccl", "global_batch_size": 32}
    losses = [loss for _, loss in json.loads((run / "metrics.json").read_text())["train_loss"]]
    assert losses[-1] < 0.8 * losses[0]
    assert main(["eval", str(run), "--episodes", "2", "--device", "cpu", "--json", str(tmp_path / "eval.json")]) == 0


def test_nproc_is_checked(reach: Path, tmp_path: Path) -> None:
    assert main(["train", str(reach), "--out", str(tmp_path / "r"), "--nproc", "0"]) != 0
    assert main(["train", str(reach), "--out", str(tmp_path / "r"), "--algo", "dagger", "--nproc", "2"]) != 0
    assert not (tmp_path / "r").exists()


def test_bench_train_nproc_compares_with_one_process(reach: Path) -> None:
    from demo.bench.train_parallel import run_parallel

    result = run_parallel(2, data=reach, steps=300, batch_size=32, rounds=1)
    assert result["samples_per_s"] > 0 and result["reference_samples_per_s"] > 0
    assert result["ratio_to_reference"] == pytest.approx(result["samples_per_s"] / result["reference_samples_per_s"])
    assert len(result["intervals"]["parallel"]) == 2  # 3 intervals, the warm-up one left out
    assert main(["bench", "train", "--nproc", "2", "--steps", "10"]) != 0  # too few steps to measure
