"""The training run: resume is bit-exact, run directories are protected, bad input fails before any write."""

from __future__ import annotations

import functools
from pathlib import Path

import pytest
import torch

from demo.errors import DemoError
from demo.progress import Tick
from demo.policies import checkpoint as ckpt
from demo.imitation.bc import train

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def data(tmp_path_factory: pytest.TempPathFactory, synthetic_store) -> Path:
    return synthetic_store(tmp_path_factory.mktemp("trainer") / "data.zarr")


def test_resume_continues_bit_exactly(data: Path, tmp_path: Path, tiny_bc_config) -> None:
    config = functools.partial(tiny_bc_config, steps=80, log_every=20, val_every=40)
    straight = config(data, tmp_path / "straight", steps=80, ema=0.9, obs_noise=0.01)
    train(straight)
    split = config(data, tmp_path / "split", steps=80, ema=0.9, obs_noise=0.01)
    train(split, stop_at=30)
    assert ckpt.load_train_state(tmp_path / "split")["step"] == 30
    train(split, resume=True)
    a = ckpt.load_train_state(tmp_path / "straight")
    b = ckpt.load_train_state(tmp_path / "split")
    assert b["step"] == 80
    for key in a["policy"]:
        assert torch.equal(a["policy"][key], b["policy"][key]), key
        assert torch.equal(a["ema"][key], b["ema"][key]), key


def test_run_directory_is_protected(data: Path, tmp_path: Path, tiny_bc_config) -> None:
    config = functools.partial(tiny_bc_config, steps=80, log_every=20, val_every=40)
    train(config(data, tmp_path / "run", steps=5))
    with pytest.raises(DemoError, match="already exists"):
        train(config(data, tmp_path / "run", steps=5))
    with pytest.raises(DemoError, match="cannot resume with a different chunk"):
        train(config(data, tmp_path / "run", steps=10, chunk=2), resume=True)
    with pytest.raises(DemoError, match="nothing to resume"):
        train(config(data, tmp_path / "fresh", steps=5), resume=True)
    (tmp_path / "notarun").mkdir()
    (tmp_path / "notarun" / "precious.txt").write_text("keep me")
    with pytest.raises(DemoError, match="not a training run"):
        train(config(data, tmp_path / "notarun", steps=5), overwrite=True)
    assert (tmp_path / "notarun" / "precious.txt").exists()


def test_bad_options_fail_before_training(data: Path, tmp_path: Path, tiny_bc_config) -> None:
    config = functools.partial(tiny_bc_config, steps=80, log_every=20, val_every=40)
    with pytest.raises(DemoError, match="--execute"):
        train(config(data, tmp_path / "r", chunk=2, execute=3))
    with pytest.raises(DemoError, match="has no observation 'obs.nope'"):
        train(config(data, tmp_path / "r", obs_keys=("obs.nope",)))
    with pytest.raises(DemoError, match="has no camera image 'obs.image_front'"):
        train(config(data, tmp_path / "r", obs_keys=("obs.image_front",)))
    with pytest.raises(DemoError, match="not a low-dimensional"):
        train(config(data, tmp_path / "r", obs_keys=("obs.joint_pos", "action")))
    with pytest.raises(DemoError, match="unknown policy"):
        train(config(data, tmp_path / "r", algo="perceiver"))
    assert not (tmp_path / "r").exists()


def test_progress_reports_steps_and_losses(data: Path, tmp_path: Path, tiny_bc_config) -> None:
    config = functools.partial(tiny_bc_config, steps=80, log_every=20, val_every=40)
    ticks: list[Tick] = []
    train(config(data, tmp_path / "run", steps=40), progress=ticks.append)
    assert {t.stage for t in ticks} == {"train bc"} and all(t.total == 40 for t in ticks)
    done = [t.done for t in ticks if t.done is not None]
    assert done == sorted(done) and done[-1] == 40
    assert ticks[-1].fields["loss"] != "-" and ticks[-1].fields["val"] != "-"


def test_a_killed_run_resumes_to_the_same_weights(data: Path, tmp_path: Path) -> None:
    """SIGKILL between periodic train-state saves: --resume continues from the last one, bit-exactly."""
    import os
    import signal
    import subprocess
    import sys
    import time

    from demo.cli.main import main

    flags = ["--steps", "400", "--chunk", "1", "--no-ensemble", "--batch-size", "64", "--seed", "3"]
    killed = tmp_path / "killed"
    process = subprocess.Popen([sys.executable, "-m", "demo", "train", str(data), *flags, "--checkpoint-every", "0.05",
                                "--out", str(killed)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                               env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    state, seen, deadline = killed / ckpt.STATE_FILE, set(), time.monotonic() + 120
    while len(seen) < 3 and process.poll() is None and time.monotonic() < deadline:  # the save at step 0, then two more
        if state.is_file():
            seen.add(state.stat().st_mtime_ns)
        time.sleep(0.01)
    process.send_signal(signal.SIGKILL)
    process.wait()
    assert process.returncode == -signal.SIGKILL, "training finished before it could be killed: raise --steps"
    assert not (killed / ckpt.POLICY_FILE).exists()  # not complete: resumable
    assert main(["eval", str(killed), "--episodes", "1"]) != 0  # says to resume (no half-made policy to evaluate)
    assert main(["train", str(data), *flags, "--out", str(killed), "--resume"]) == 0
    assert main(["train", str(data), *flags, "--out", str(tmp_path / "straight")]) == 0
    a, b = ckpt.load_train_state(tmp_path / "straight"), ckpt.load_train_state(killed)
    assert a["step"] == b["step"] == 400
    for key in a["policy"]:
        assert torch.equal(a["policy"][key], b["policy"][key]), key


def test_a_run_killed_before_its_first_save_is_started_again(data: Path, tmp_path: Path, tiny_bc_config) -> None:
    """run.json but no train state nor policy: no training to keep, so no --resume/--overwrite loop."""
    config = functools.partial(tiny_bc_config, steps=20, log_every=10, val_every=10)
    train(config(data, tmp_path / "run"))
    (tmp_path / "run" / ckpt.STATE_FILE).unlink()
    (tmp_path / "run" / ckpt.POLICY_FILE).unlink()
    with pytest.raises(DemoError, match="stopped before its first save: start it again without --resume"):
        train(config(data, tmp_path / "run"), resume=True)
    assert train(config(data, tmp_path / "run"))["step"] == 20


@pytest.mark.slow  # ~40 s: real processes killed and resumed
def test_bench_resume_kills_and_resumes(tmp_path: Path) -> None:
    import json

    from demo.cli.main import main

    out = tmp_path / "r.json"
    assert main(["bench", "resume", "--kinds", "bc", "--kills", "2", "--steps", "200", "--checkpoint-every", "0.2",
                 "--out", str(tmp_path / "b"), "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    assert result["identical"] == 2 and len(result["trials"]) == 2


def test_resume_refuses_data_replaced_under_the_run(tmp_path: Path, synthetic_store, tiny_bc_config) -> None:
    data = synthetic_store(tmp_path / "d.zarr")
    config = functools.partial(tiny_bc_config, steps=40, log_every=10, val_every=20)
    train(config(data, tmp_path / "run"), stop_at=10)
    first = ckpt.read_run(tmp_path / "run")["data"]["content"]
    synthetic_store(tmp_path / "other.zarr", seed=1)
    import shutil

    shutil.rmtree(data)
    shutil.move(tmp_path / "other.zarr", data)  # the same path, other episodes
    with pytest.raises(DemoError, match="its data changed since the run started"):
        train(config(data, tmp_path / "run"), resume=True)
    assert len(first) == 1 and len(first[0]) == 16
