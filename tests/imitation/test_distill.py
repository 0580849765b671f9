"""One-step diffusion by distillation (`demo train --algo diffusion --distil RUN`): the student's one
step approaches the teacher's DDIM sample from the same noise, it is saved as a one-step diffusion run
that `demo eval` and `demo bench infer` take, and wrong teachers and stores are refused in one line."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from demo.errors import DemoError

pytestmark = pytest.mark.usefixtures("torch_one_thread")

TINY = {"denoiser": "mlp", "width": 64, "depth": 1, "step_embed_dim": 16}


@pytest.fixture(scope="module")
def teacher(tmp_path_factory, torch_one_thread):
    """4 avoid demos and a diffusion teacher trained on them for seconds: (store, teacher run)."""
    from demo.collect.scripted import CollectConfig, collect_scripted
    from demo.imitation.bc import train
    from demo.training.config import TrainConfig

    root = tmp_path_factory.mktemp("distil")
    data = root / "avoid.zarr"
    collect_scripted(CollectConfig(task="avoid", episodes=4, seed=0), data, workers=0)
    run = root / "teacher"
    train(TrainConfig(algo="diffusion", data=str(data), out=str(run), steps=100, batch_size=32, warmup_steps=10, lr=3e-3,
                      val_fraction=0.25, log_every=50, policy={**TINY, "inference_steps": 4}))
    return data, run


@pytest.mark.slow
def test_student_approaches_the_teacher_and_is_a_one_step_run(teacher, tmp_path) -> None:
    from demo.policies import checkpoint as ckpt
    from demo.training.config import TrainConfig
    from demo.imitation.distill import student_step, teacher_sample, train

    data, teacher_run = teacher
    out = tmp_path / "student"
    summary = train(TrainConfig(data=str(data), out=str(out), steps=90, lr=3e-3, batch_size=64, val_every=30,
                                log_every=30), teacher_run)
    val = json.loads((out / ckpt.METRICS_FILE).read_text())["val_loss"]
    assert [s for s, _ in val] == [0, 30, 60, 90]
    # the distillation error on held-out windows and fixed noise: from the teacher's own one-step
    # output (its posterior mean from pure noise) to well below it
    assert val[-1][1] < 0.5 * val[0][1] and summary["distill_val_start"] == val[0][1]

    student, master = ckpt.load_bundle(out), ckpt.load_bundle(teacher_run)
    assert student.algo == "diffusion" and student.policy.config.inference_steps == 1
    assert student.policy.config.prediction == "sample" and student.execution == master.execution
    record = student.run["distilled_from"]
    assert record["run"] == str(teacher_run.resolve()) and record["inference_steps"] == 4 and len(record["policy_sha256"]) == 64
    # the teacher's normalisers: the student speaks its normalised action space
    for a, b in ((student.obs_norm, master.obs_norm), (student.action_norm, master.action_norm)):
        assert np.array_equal(a.low, b.low) and np.array_equal(a.high, b.high)
    # one step from the same noise lands nearer the teacher's DDIM sample than the teacher's one step does
    g = torch.Generator().manual_seed(5)
    obs = torch.rand(256, 2, student.policy.spec.obs_dim, generator=g) * 2 - 1
    x_T = torch.randn(256, 16, student.action.dim, generator=g)
    with torch.no_grad():
        target = teacher_sample(master.policy, obs, x_T)
        before = (student_step(master.policy, obs, x_T) - target).square().mean()
        after = (student_step(student.policy, obs, x_T) - target).square().mean()
        sampled = student.policy.sample(obs, x_T)  # the saved sampler: one DDIM step, clipped
    assert after < before
    assert torch.allclose(sampled, student_step(student.policy, obs, x_T).detach().clamp(-1, 1), atol=1e-5)


@pytest.mark.slow
def test_student_evaluates_and_times_through_the_cli(teacher, tmp_path, capfd) -> None:
    from demo.cli.main import main

    data, teacher_run = teacher
    out = tmp_path / "student"
    assert main(["train", str(data), "--algo", "diffusion", "--distil", str(teacher_run), "--out", str(out), "--steps", "10",
                 "--json", str(tmp_path / "train.json")]) == 0
    run = json.loads((out / "run.json").read_text())
    assert run["train"]["steps"] == 10 and run["train"]["lr"] == 1e-4 and run["command"].endswith("train.json")
    assert main(["eval", str(out), "--episodes", "2", "--json", str(tmp_path / "eval.json")]) == 0
    assert json.loads((tmp_path / "eval.json").read_text())["episodes"] == 2
    infer = ["bench", "infer", "--run", str(out), "--episodes", "0", "--seconds", "0.05", "--json", str(tmp_path / "i.json")]
    assert main(infer) == 0
    r = json.loads((tmp_path / "i.json").read_text())
    assert r["inference_steps"] == 1 and r["teacher_steps"] == 4 and r["distilled_from"]["run"] == str(teacher_run.resolve())
    assert r["one_step_speedup"] == pytest.approx(r["teacher_steps_ms_per_chunk"] / r["one_step_ms_per_chunk"])


def test_wrong_teachers_and_stores_are_refused_in_one_line(teacher, tmp_path, capfd, synthetic_store, tiny_bc_config) -> None:
    from demo.cli.main import main
    from demo.imitation.bc import train as train_bc
    from demo.training.config import TrainConfig
    from demo.imitation.distill import train

    data, teacher_run = teacher
    bc = tmp_path / "bc"
    train_bc(tiny_bc_config(data, bc, steps=5))
    with pytest.raises(DemoError, match="is a 'bc' run; --distil needs a diffusion teacher"):
        train(TrainConfig(data=str(data), out=str(tmp_path / "s1"), steps=2), bc)
    other = synthetic_store(tmp_path / "other.zarr", episodes=4)
    with pytest.raises(DemoError, match="other.zarr: observation obs.joint_pos has a different size"):
        train(TrainConfig(data=str(other), out=str(tmp_path / "s2"), steps=2), teacher_run)
    with pytest.raises(DemoError, match="--chunk"):
        train(TrainConfig(data=str(data), out=str(tmp_path / "s3"), steps=2, chunk=8), teacher_run)
    assert not (tmp_path / "s1").exists() and not (tmp_path / "s2").exists() and not (tmp_path / "s3").exists()
    capfd.readouterr()
    wrong = (["--distil", str(bc)], ["--distil", str(tmp_path / "missing")],
             ["--distil", str(teacher_run), "--policy-opt", "width=32"])
    for argv in wrong:
        assert main(["train", str(data), "--algo", "diffusion", "--out", str(tmp_path / "s4"), *argv]) == 1
        err = capfd.readouterr().err.strip()
        assert err.startswith("error: ") and "\n" not in err, err
    assert main(["train", str(data), "--out", str(tmp_path / "s5"), "--distil", str(teacher_run)]) == 1
    assert "use --algo diffusion" in capfd.readouterr().err
