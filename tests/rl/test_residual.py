"""Residual RL on a frozen imitation run (demo.rl.residual): the run directory holds the base unchanged and a
bounded correction beside it, demo eval executes base + correction, and bad input fails in one line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors.torch import load_file, save_file

from demo import algorithms
from demo.errors import DemoError
from demo.gym.env import DemoEnv
from demo.policies import checkpoint as ckpt
from demo.policies.observation import ObsSpec
from demo.rl.config import PPOConfig, ResidualConfig
from demo.rl.residual import train

pytestmark = pytest.mark.usefixtures("torch_one_thread")


@pytest.fixture(scope="module")
def base_and_residual(reach_demos, tiny_bc_config, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Path]:
    """A chunked, ensembled BC run on reach, a residual trained on it for two short PPO iterations, and the
    demonstrations."""
    root = tmp_path_factory.mktemp("residual")
    base = root / "bc"
    algorithms.train("bc", tiny_bc_config(reach_demos(8), base, chunk=4, ensemble=0.01))
    out = root / "residual"
    train(ResidualConfig(rl=PPOConfig(out=str(out), total_steps=200, num_envs=2, num_steps=50, epochs=1, minibatches=2,
                                      hidden=(16,), eval_episodes=2, eval_every=1), init=str(base), scale=0.1))
    return base, out, reach_demos(8)


def test_the_run_keeps_the_base_and_records_the_starting_line(base_and_residual: tuple[Path, Path, Path]) -> None:
    base, out, _ = base_and_residual
    run, base_run = json.loads((out / "run.json").read_text()), json.loads((base / "run.json").read_text())
    assert run["algo"] == "residual" and run["policy"] == base_run["policy"]
    assert run["init"]["run"] == str(base.resolve()) and run["task"]["name"] == "reach"
    # the base's weights are saved unchanged beside the residual's
    saved, original = load_file(str(out / ckpt.POLICY_FILE)), load_file(str(base / ckpt.POLICY_FILE))
    for key, value in original.items():
        assert torch.equal(saved[key], value), key
    assert any(k.startswith("residual.") for k in saved)
    # the bound: 0.1 of each action entry's half-range in the base's data
    bundle = ckpt.load_bundle(base)
    expected = 0.1 * (bundle.action_norm.high - bundle.action_norm.low) / 2
    np.testing.assert_allclose(run["residual"]["bound"], expected, rtol=1e-6)
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["start"]["step"] == 0 and [e["step"] for e in metrics["eval"]] == [0, 100, 200]
    final = metrics["final"]
    assert final["start_success_rate"] == metrics["eval"][0]["success_rate"]
    assert final["min_success_rate"] == min(e["success_rate"] for e in metrics["eval"])
    assert (out / "curves.png").is_file()


def test_evaluation_executes_base_plus_a_bounded_correction(base_and_residual: tuple[Path, Path, Path],
                                                           reach_sweep: list[dict[str, np.ndarray]]) -> None:
    base_dir, out, _ = base_and_residual
    base, fine = ckpt.load_bundle(base_dir), ckpt.load_bundle(out)
    assert base.residual is None and fine.residual is not None
    frames = reach_sweep
    a, b = base.actor(), fine.actor()
    a.reset(0), b.reset(0)
    for frame in frames:
        plain, corrected = a.policy_action(frame), b.policy_action(frame)
        np.testing.assert_allclose(corrected, plain + fine.residual.correction(frame, plain), atol=1e-5)
    # a residual pushed as hard as it can go moves each entry by its bound, never further
    with torch.no_grad():
        fine.residual.policy.mean[-1].weight.mul_(1e4)
        fine.residual.policy.mean[-1].bias.fill_(50.0)
    a.reset(0), b.reset(0)
    for frame in frames:
        gap = b.policy_action(frame) - a.policy_action(frame)
        np.testing.assert_allclose(np.abs(gap), fine.residual.bound, rtol=1e-4)


def test_demo_eval_runs_it(base_and_residual: tuple[Path, Path], tmp_path: Path) -> None:
    from demo.cli.main import main

    js = tmp_path / "eval.json"
    assert main(["eval", str(base_and_residual[1]), "--episodes", "2", "--json", str(js)]) == 0
    assert json.loads(js.read_text())["episodes"] == 2


def test_a_damaged_residual_is_refused_in_one_line(base_and_residual: tuple[Path, Path], tmp_path: Path) -> None:
    import shutil

    bad = tmp_path / "bad"
    shutil.copytree(base_and_residual[1], bad)
    tensors = load_file(str(bad / ckpt.POLICY_FILE))
    tensors = {k: v for k, v in tensors.items() if not k.startswith("residual.mean.0.")}
    save_file(tensors, str(bad / ckpt.POLICY_FILE))
    with pytest.raises(DemoError, match="does not match the residual"):
        ckpt.load_bundle(bad)
    run = json.loads((bad / "run.json").read_text())
    run["residual"]["bound"] = [0.1]
    (bad / "run.json").write_text(json.dumps(run))
    with pytest.raises(DemoError, match="bound"):
        ckpt.load_bundle(bad)


def test_bad_options_fail_in_one_line(base_and_residual: tuple[Path, Path], one_line_error, tmp_path: Path) -> None:
    base = str(base_and_residual[0])
    out = str(tmp_path / "r")
    one_line_error(["irl", "train", "--algo", "residual", "--out", out], "--init")
    one_line_error(["irl", "train", "--algo", "ppo", "--init", base, "--out", out], "--init", "ppo")
    one_line_error(["irl", "train", str(base_and_residual[2]), "--algo", "gail", "--init", base, "--inputs", "sa",
                    "--out", out], "--init", "state-only")
    one_line_error(["irl", "train", "--algo", "residual", "--init", base, "--task", "pick", "--out", out], "imitation run")
    one_line_error(["irl", "train", "--algo", "residual", "--init", base, "--scale", "2", "--out", out], "--scale")
    one_line_error(["irl", "train", "--algo", "residual", "--init", str(tmp_path / "nothing"), "--out", out], "nothing")


def test_gail_starts_from_an_imitation_run(base_and_residual: tuple[Path, Path, Path], tmp_path: Path) -> None:
    from demo.rl.adversarial import train as train_adversarial
    from demo.rl.config import AdversarialConfig

    base, _, demos = base_and_residual
    out = tmp_path / "gail"
    summary = train_adversarial(AdversarialConfig(
        rl=PPOConfig(out=str(out), total_steps=100, num_envs=2, num_steps=50, epochs=1, minibatches=2, hidden=(16,),
                     eval_episodes=2), data=str(demos), kind="gail", init=str(base)))
    run = json.loads((out / "run.json").read_text())
    assert run["algo"] == "gail" and run["residual"]["scale"] == 0.1 and run["adversarial"]["init"] == str(base)
    assert summary["start_success_rate"] is not None and (out / "reward.safetensors").is_file()
    assert ckpt.load_bundle(out).residual is not None


def test_the_demonstrations_stay_in_a_bc_term(base_and_residual: tuple[Path, Path, Path], tmp_path: Path) -> None:
    from demo.rl.residual import demonstration_targets

    base_dir, _, demos = base_and_residual
    base = ckpt.load_bundle(base_dir)
    env = DemoEnv("reach", store_layout=True)
    spec = ObsSpec.from_features(env.features, None, where="reach")
    env.close()
    bound = np.full(base.action.dim, 0.05, np.float32)
    inputs, targets, episodes = demonstration_targets(str(demos), 2, base, spec, bound)
    assert episodes == 2 and inputs.shape == (len(targets), spec.dim + base.action.dim)
    assert np.abs(targets).max() <= 1.0 and (np.abs(targets) < 1.0).any()
    # where a target is not clipped, base + bound * target is the demonstrated action
    from demo.store import EpisodeStore

    with EpisodeStore.open(demos) as store:
        first = np.asarray(store.read_episode(0, ["action"])["action"], np.float32)
    b = inputs[: len(first), spec.dim:]
    free = np.abs(targets[: len(first)]) < 1.0
    np.testing.assert_allclose((b + bound * targets[: len(first)])[free], first[free], atol=1e-5)

    out = tmp_path / "bc_term"
    train(ResidualConfig(rl=PPOConfig(out=str(out), total_steps=100, num_envs=2, num_steps=50, epochs=1, minibatches=2,
                                      hidden=(16,), eval_episodes=1), init=str(base_dir), data=str(demos), demos=3))
    run, metrics = json.loads((out / "run.json").read_text()), json.loads((out / "metrics.json").read_text())
    assert run["demonstrations"]["episodes"] == 3 and run["demonstrations"]["bc_coef"] == 1.0
    assert all(e["loss_auxiliary"] > 0 for e in metrics["iterations"])


def test_same_seed_same_residual(base_and_residual: tuple[Path, Path, Path], tmp_path: Path) -> None:
    base, _, demos = base_and_residual
    weights = []
    for name in ("a", "b"):
        train(ResidualConfig(rl=PPOConfig(out=str(tmp_path / name), total_steps=100, num_envs=2, num_steps=50, epochs=1,
                                          minibatches=2, hidden=(16,), eval_episodes=1), init=str(base), data=str(demos)))
        weights.append((tmp_path / name / ckpt.POLICY_FILE).read_bytes())
    assert weights[0] == weights[1]


@pytest.mark.parametrize("algo", ["diffusion", "act"])
def test_a_residual_corrects_diffusion_and_act(algo: str, reach_demos, tiny_bc_config, tmp_path: Path) -> None:
    """Any imitation run is a base: a diffusion policy (its sampling seeded per episode) and ACT run under
    the residual as demo eval runs them, and the run evaluates."""
    from demo.training.config import for_policy

    base = tmp_path / algo
    algorithms.train(algo, for_policy(algo, data=str(reach_demos(8)), out=str(base), steps=20, batch_size=16, seed=0))
    out = tmp_path / "residual"
    train(ResidualConfig(rl=PPOConfig(out=str(out), total_steps=100, num_envs=2, num_steps=50, epochs=1, minibatches=2,
                                      hidden=(16,), eval_episodes=1), init=str(base), data=str(reach_demos(8)), demos=2))
    bundle = ckpt.load_bundle(out)
    assert bundle.algo == algo and bundle.residual is not None
    from demo.cli.main import main

    assert main(["eval", str(out), "--episodes", "1"]) == 0
