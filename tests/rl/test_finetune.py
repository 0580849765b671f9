"""Full fine-tuning of a BC run by PPO (demo.rl.finetune): PPO's mean is the run's ensembled action exactly as
demo eval executes it, the run directory is the BC run with new weights, and what it cannot follow is refused
in one line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors.torch import load_file

from demo import algorithms
from demo.errors import DemoError
from demo.gym.env import DemoEnv
from demo.policies import checkpoint as ckpt
from demo.policies.observation import ObsSpec
from demo.rl.config import FinetuneConfig, PPOConfig
from demo.rl.finetune import EnsembledChunks, EnsembledWindows, slot_weights, train

pytestmark = pytest.mark.usefixtures("torch_one_thread")


def _ppo(out: Path, steps: int = 100, **changes) -> PPOConfig:
    return PPOConfig(out=str(out), total_steps=steps, num_envs=2, num_steps=50, epochs=1, minibatches=2, hidden=(16,),
                     eval_episodes=1, **changes)


@pytest.fixture(scope="module")
def base_and_finetuned(reach_demos, tiny_bc_config, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Path]:
    """A chunked, ensembled BC run on reach (relative joint targets), the same fine-tuned for two short PPO
    iterations with the demonstrations in its BC term, and the demonstrations."""
    root = tmp_path_factory.mktemp("finetune")
    base = root / "bc"
    algorithms.train("bc", tiny_bc_config(reach_demos(8), base, chunk=4, ensemble=0.01))
    out = root / "finetuned"
    train(FinetuneConfig(rl=_ppo(out, 200, eval_every=1), init=str(base), data=str(reach_demos(8)), demos=3))
    return base, out, reach_demos(8)


@pytest.mark.parametrize("ensemble", [0.01, 0.5, None])
def test_the_mean_is_the_action_demo_eval_executes(base_and_finetuned: tuple[Path, Path, Path], ensemble,
                                                   reach_sweep: list[dict[str, np.ndarray]]) -> None:
    """PPO's mean, recomputed from the kept windows, unnormalised and offset by the ensembled joints, is the
    action the run's actor executes at every step (chunks, ensembling and relative actions included)."""
    from demo.policies.actor import ExecConfig

    base = ckpt.load_bundle(base_and_finetuned[0])
    base.execution = ExecConfig(execute=1, ensemble=ensemble)
    spec = base.policy.spec
    assert spec.horizon == 4 and base.relative is not None
    env = DemoEnv("reach", store_layout=True)
    state = ObsSpec.from_features(env.features, None, where="reach")
    env.close()
    weights = slot_weights(spec.horizon, ensemble)
    windows = EnsembledWindows(base, state, weights)
    policy = EnsembledChunks(base.policy, state.dim, spec.horizon, spec.n_obs, base.obs_spec.dim, weights,
                             spec.action_dim, -3.0)
    actor = base.actor()
    actor.reset(0)
    for frame in reach_sweep:
        x = torch.from_numpy(windows.observe(frame)[None])
        with torch.no_grad():
            mean = policy.mean(x)[0].numpy()
        executed = base.action_norm.unnormalize(mean) + windows.offset()
        np.testing.assert_allclose(executed, actor.base_action(frame), atol=1e-5)


def test_the_run_is_the_bc_run_with_new_weights(base_and_finetuned: tuple[Path, Path, Path], tmp_path: Path) -> None:
    base, out, _ = base_and_finetuned
    run, base_run = json.loads((out / "run.json").read_text()), json.loads((base / "run.json").read_text())
    assert run["algo"] == "finetune" and run["policy"] == base_run["policy"] and "residual" not in run
    assert run["init"]["run"] == str(base.resolve()) and run["finetune"]["policy_lr"] == 1e-5 and FinetuneConfig().rl.target_kl == 0.02
    assert run["demonstrations"]["episodes"] == 3
    saved, original = load_file(str(out / ckpt.POLICY_FILE)), load_file(str(base / ckpt.POLICY_FILE))
    assert saved.keys() == original.keys()
    assert any(not torch.equal(saved[k], original[k]) for k in original if not k.startswith("normalizer"))
    for k in original:  # the normalisers are the run's: the windows reach the network as they were trained
        if k.startswith("normalizer"):
            assert torch.equal(saved[k], original[k]), k
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["start"]["step"] == 0 and [e["step"] for e in metrics["eval"]] == [0, 100, 200]
    assert all(e["loss_auxiliary"] > 0 for e in metrics["iterations"])
    bundle = ckpt.load_bundle(out)
    assert bundle.algo == "bc" and bundle.residual is None
    from demo.cli.main import main

    js = tmp_path / "eval.json"
    assert main(["eval", str(out), "--episodes", "2", "--json", str(js)]) == 0
    assert json.loads(js.read_text())["episodes"] == 2


def test_the_bc_term_targets_are_the_demonstrated_actions(base_and_finetuned: tuple[Path, Path, Path]) -> None:
    """Where a target is not clipped, unnormalising it and adding the ensembled offset gives the demonstrated
    action back: the BC term pulls the mean to what the demonstrator did, in PPO's own action units."""
    from demo.rl.finetune import FinetuneRun
    from demo.store import EpisodeStore

    base, _, demos = base_and_finetuned
    config = FinetuneConfig(rl=_ppo(base.parent / "unused"), init=str(base), data=str(demos), demos=1)
    with FinetuneRun(config) as run:
        inputs, targets, episodes = run.demonstration_targets(str(demos), 1)
        bundle, spec = run.base, run.pool.obs_spec
    assert episodes == 1 and inputs.shape[1] == EnsembledWindows(bundle, spec, run.weights).dim
    windows = EnsembledWindows(bundle, spec, run.weights)
    free = np.abs(targets) < 1.0
    assert free.mean() > 0.9
    with EpisodeStore.open(demos) as store:
        keys = [k for k in store.meta.features if k.startswith("obs.")]
        full = store.read_episode(0, [*keys, "action"])
    for t, action in enumerate(np.asarray(full["action"], np.float32)):
        windows.observe({k: full[k][t] for k in keys})
        back = bundle.action_norm.unnormalize(targets[t]) + windows.offset()
        np.testing.assert_allclose(back[free[t]], action[free[t]], atol=1e-4)


def test_same_seed_same_weights(base_and_finetuned: tuple[Path, Path, Path], tmp_path: Path) -> None:
    base, _, demos = base_and_finetuned
    weights = []
    for name in ("a", "b"):
        train(FinetuneConfig(rl=_ppo(tmp_path / name), init=str(base), data=str(demos), demos=2))
        weights.append((tmp_path / name / ckpt.POLICY_FILE).read_bytes())
    assert weights[0] == weights[1]


def test_what_it_cannot_follow_is_refused_in_one_line(base_and_finetuned: tuple[Path, Path, Path], reach_demos,
                                                      tiny_bc_config, one_line_error, tmp_path: Path) -> None:
    from demo.training.config import for_policy

    base, _, demos = base_and_finetuned
    diffusion = tmp_path / "diffusion"
    algorithms.train("diffusion", for_policy("diffusion", data=str(demos), out=str(diffusion), steps=5, batch_size=16))
    with pytest.raises(DemoError, match="MSE head"):
        train(FinetuneConfig(rl=_ppo(tmp_path / "f1"), init=str(diffusion)))
    executes = tmp_path / "executes"
    algorithms.train("bc", tiny_bc_config(demos, executes, chunk=4, execute=4, steps=5))
    with pytest.raises(DemoError, match="--execute 1"):
        train(FinetuneConfig(rl=_ppo(tmp_path / "f2"), init=str(executes)))
    out = str(tmp_path / "f3")
    one_line_error(["irl", "train", "--algo", "finetune", "--out", out], "--init")
    one_line_error(["irl", "train", "--algo", "finetune", "--init", str(base), "--policy-lr", "0", "--out", out],
                   "--policy-lr")
    one_line_error(["irl", "train", "--algo", "finetune", "--init", str(base), "--task", "pick", "--out", out],
                   "task and robot")
