"""PPO (demo.rl.ppo): GAE, the clipped objective, observation statistics, a learning step, and a run
directory that `demo eval` runs."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from demo.rl.ppo import (Agent, GaussianConfig, GaussianPolicy, PPOConfig, RunningMeanStd, gae, ppo_losses,
                            ppo_update, train)
from demo.policies.policy import PolicySpec
from demo.rl.rewards import CYCLE_BONUS, STAGE_WEIGHT, TASK_REWARDS, pad_moved, stack_potential, quat_angles

pytestmark = pytest.mark.usefixtures("torch_one_thread")


def test_gae_bootstraps_truncation_not_termination() -> None:
    gamma, lam = 0.9, 0.8
    rewards = np.array([[1.0], [2.0], [3.0]])
    values = np.array([[0.5], [0.4], [0.3]])
    next_values = np.array([[0.4], [10.0], [7.0]])  # 10: the state after a truncation (not the next reset state)
    terminated = np.array([[0.0], [0.0], [1.0]])
    dones = np.array([[0.0], [1.0], [1.0]])  # truncated after step 1, terminated after step 2
    adv, ret = gae(rewards, values, next_values, terminated, dones, gamma, lam)
    d2 = 3.0 - 0.3  # terminal: no bootstrap
    d1 = 2.0 + gamma * 10.0 - 0.4  # truncated: bootstrap from the true next state, nothing flows from step 2
    d0 = 1.0 + gamma * 0.4 - 0.5
    assert adv[:, 0] == pytest.approx([d0 + gamma * lam * d1, d1, d2])
    assert ret == pytest.approx(adv + values)


def _policy(obs_dim: int = 3, action_dim: int = 2) -> GaussianPolicy:
    torch.manual_seed(0)
    return GaussianPolicy(PolicySpec(obs_dim, action_dim), GaussianConfig((16,), init_log_std=0.0))


def test_clipped_surrogate_on_a_fixed_batch() -> None:
    policy = _policy()
    critic = torch.nn.Linear(3, 1)
    obs = torch.randn(64, 3)
    actions = torch.randn(64, 2)
    with torch.no_grad():
        new = policy.distribution(obs).log_prob(actions).sum(-1)
    adv = torch.randn(64)
    norm = (adv - adv.mean()) / (adv.std() + 1e-8)
    for ratio, clip in ((1.5, 0.2), (0.5, 0.2), (1.1, 0.2)):
        losses = ppo_losses(policy, critic, obs, actions, new - math.log(ratio), adv, torch.zeros(64), clip)
        clipped = min(max(ratio, 1 - clip), 1 + clip)
        expected = torch.max(-norm * ratio, -norm * clipped).mean()
        assert float(losses["policy"].detach()) == pytest.approx(float(expected), rel=1e-5)
        assert float(losses["clip_fraction"]) == (1.0 if abs(ratio - 1) > clip else 0.0)
    # The unclipped side wins where it is the worse one: positive advantages never gain past 1 + clip.
    pos = torch.ones(64) + torch.linspace(0, 1, 64)
    losses = ppo_losses(policy, critic, obs, actions, new - math.log(3.0), pos, torch.zeros(64), 0.2)
    pos_n = (pos - pos.mean()) / (pos.std() + 1e-8)
    assert float(losses["policy"].detach()) == pytest.approx(float(torch.max(-pos_n * 3.0, -pos_n * 1.2).mean()), rel=1e-5)


def test_running_statistics_are_the_data_mean_and_std() -> None:
    rng = np.random.default_rng(0)
    x = rng.normal([1.0, -2.0, 0.0], [0.5, 3.0, 1e-6], size=(1000, 3))
    rms = RunningMeanStd(3)
    for chunk in np.array_split(x, 7):
        rms.update(chunk)
    assert rms.mean == pytest.approx(x.mean(axis=0), abs=1e-6)
    assert np.sqrt(rms.var[:2]) == pytest.approx(x.std(axis=0)[:2], rel=1e-4)
    norm = rms.normalizer()
    z = norm.normalize(x)
    assert z[:, :2].mean(axis=0) == pytest.approx([0, 0], abs=1e-4) and z[:, :2].std(axis=0) == pytest.approx([1, 1], rel=1e-3)
    assert np.abs(z[:, 2]).max() < 1e-3  # a constant input is floored (MIN_STD), not blown up


def test_an_update_makes_advantaged_actions_likelier() -> None:
    config = PPOConfig(num_envs=4, num_steps=32, epochs=4, minibatches=2, lr=1e-3, hidden=(32,))
    agent = Agent(config, obs_dim=3, action_dim=2)
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(32, 4, 3)).astype(np.float32)
    actions, logp = agent.act(obs.reshape(-1, 3))
    actions, logp = actions.reshape(32, 4, 2), logp.reshape(32, 4)
    adv = np.where(actions[..., 0] > 0, 1.0, -1.0)  # reward pushing the first action dimension up
    before = agent.logprob(obs, actions)
    ppo_update(agent, obs, actions, logp, adv, np.zeros_like(adv), rng)
    after = agent.logprob(obs, actions)
    good = adv > 0
    assert (after - before)[good].mean() > 0 > (after - before)[~good].mean()
    with torch.no_grad():
        assert float(agent.policy.mean(torch.from_numpy(obs.reshape(-1, 3)))[:, 0].mean()) > 0


def test_reach_features_and_reward() -> None:
    reward = TASK_REWARDS["reach"]
    down = np.array([0.0, 1.0, 0.0, 0.0])
    tilted = np.array([math.cos(0.1), math.sin(0.1), 0.0, 0.0])  # 0.2 rad from identity
    obs = {"obs.ee_pos": np.array([[0.5, 0.0, 0.2], [0.5, 0.0, 0.2]]), "obs.goal_pos": np.array([[0.5, 0.0, 0.2], [0.5, 0.3, 0.2]]),
           "obs.ee_quat": np.array([down, [1.0, 0, 0, 0]]), "obs.goal_quat": np.array([-down, tilted])}
    phi = reward.features(obs, None, {"pos_tol": 0.01, "rot_tol": 0.1})
    assert phi == pytest.approx(np.array([[0.0, 0.0, 1.0], [0.3, 0.2, 0.0]]), abs=1e-9)
    assert reward(obs) == pytest.approx([2.0, -3.2])
    assert quat_angles(down[None], -down[None]) == pytest.approx([0.0])  # q and -q are one rotation


def test_pick_features_follow_the_staged_lift() -> None:
    reward = TASK_REWARDS["pick"]
    obs = {"obs.ee_pos": np.array([[0.5, 0.0, 0.12], [0.5, 0.0, 0.07], [0.5, 0.0, 0.2]]),
           "obs.object_pos": np.array([[[0.5, 0.0, 0.02]], [[0.5, 0.0, 0.07]], [[0.5, 0.0, 0.2]]])}
    phi = reward.features(obs, None, {"cube_size": 0.04, "lift_height": 0.10})
    # resting 10 cm below the hand; held 5 cm up; held 18 cm up (lift clipped at 10 cm, success)
    assert phi == pytest.approx(np.array([[0.1, 0.0, 0.0], [0.0, 0.05, 0.0], [0.0, 0.10, 1.0]]), abs=1e-9)
    assert reward(obs, None, {"cube_size": 0.04, "lift_height": 0.10}) == pytest.approx([-1.0, 1.0, 4.0])


def test_stack_pays_each_finished_cycle_and_the_last_stack(tmp_path: Path) -> None:
    """The scripted expert's episodes of stack with two respawned cycles: one cycle event (the pad moves
    between two frames), paid the cycle's bonus; shaping that pays each approach and carry; success on the
    settled last stack, nowhere else."""
    from demo.collect.scripted import CollectConfig, collect_scripted
    from demo.store import EpisodeStore

    options = {"blocks": 1, "repeat": 2, "respawn": 1}
    collect_scripted(CollectConfig(task="stack", episodes=2, seed=0, task_options=options), tmp_path / "s.zarr", workers=0)
    reward = TASK_REWARDS["stack"]
    with EpisodeStore.open(tmp_path / "s.zarr") as store:
        for i in range(2):
            ep = store.read_episode(i, ["obs.object_pos", "obs.goal_pos", "obs.gripper", "obs.ee_pos"])
            before, after = ({k: v[:-1] for k, v in ep.items()}, {k: v[1:] for k, v in ep.items()})
            cycles = pad_moved(before, after)
            assert cycles.sum() == 1  # the first stack's end, not the last's
            events = reward.events(before, after, options)
            assert events[cycles > 0] == CYCLE_BONUS  # finishing a cycle pays, though the distances jump back up
            # The shaping between cycles is the potential's change: it pays the expert for each approach and
            # carry (the potential rises from a start to 0 at the stack) and sums over the episode to its rise.
            first = int(np.flatnonzero(cycles)[0])
            phi = stack_potential(ep, options)
            assert phi[0] < -STAGE_WEIGHT and phi[-1] == 0.0
            assert events[:first].sum() == pytest.approx(phi[first] - phi[0])
            assert events[first + 1:].sum() == pytest.approx(phi[-1] - phi[first + 1])
            success = reward.features(ep, None, options)[:, 0]
            assert success[-1] == 1 and success[: len(success) // 2].sum() == 0


def test_ppo_run_directory_evaluates(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from demo.cli.main import main

    out = tmp_path / "ppo"
    summary = train(PPOConfig(task="reach", action="joint_pos", out=str(out), total_steps=200, num_envs=2, num_steps=50,
                              epochs=1, minibatches=2, hidden=(16,), eval_episodes=1))
    assert summary["env_steps"] == 200 and summary["eval_episodes"] == 1
    run = json.loads((out / "run.json").read_text())
    assert run["algo"] == "ppo" and run["policy"]["algo"] == "ppo" and run["task_reward"]["features"][0] == "pos_err"
    assert run["policy"]["relative_actions"]["obs_key"] == "obs.joint_pos"
    metrics = json.loads((out / "metrics.json").read_text())
    assert [e["env_steps"] for e in metrics["iterations"]] == [100, 200] and (out / "curves.png").is_file()
    js = tmp_path / "eval.json"
    assert main(["eval", str(out), "--episodes", "2", "--json", str(js)]) == 0
    result = json.loads(js.read_text())
    assert result["episodes"] == 2 and result["algo"] == "ppo" and result["seeds_shared_with_training_data"] == 0
