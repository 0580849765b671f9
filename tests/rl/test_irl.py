"""Inverse RL: GAIL/AIRL discriminators and their gradient penalty (demo.rl.adversarial), MaxEnt IRL and
apprenticeship learning on a small MDP solved exactly (demo.rl.irl_linear), and `demo irl train` runs."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from demo.rl.adversarial import Discriminator, discriminator_loss, gradient_penalty
from demo.rl.irl_linear import apprenticeship, discounted_sums, maxent_irl, unit

pytestmark = pytest.mark.usefixtures("torch_one_thread")


def _batches(n: int, seed: int) -> tuple[dict[str, torch.Tensor], dict[str, torch.Tensor]]:
    """Expert transitions whose action and next state follow the state; random ones that do not."""
    rng = np.random.default_rng(seed)
    s = rng.normal(size=(2, n, 4)).astype(np.float32)
    a_expert = np.tanh(s[0, :, :2])
    a_random = rng.uniform(-1, 1, (n, 2)).astype(np.float32)
    expert = {"obs": s[0], "actions": a_expert, "next_obs": s[0] + 0.3, "terminal": np.zeros(n), "logpi": np.zeros(n)}
    policy = {"obs": s[1], "actions": a_random, "next_obs": s[1] - 0.3, "terminal": np.zeros(n), "logpi": np.zeros(n)}
    return tuple({k: torch.as_tensor(v, dtype=torch.float32) for k, v in b.items()} for b in (expert, policy))


@pytest.mark.parametrize("kind, inputs", [("gail", "sa"), ("gail", "ss"), ("airl", "ss")])
def test_discriminator_separates_expert_from_random(kind: str, inputs: str) -> None:
    torch.manual_seed(0)
    expert, policy = _batches(256, 0)
    disc = Discriminator(kind, inputs, expert["obs"].numpy(), 2, (32, 32), gamma=0.99)
    optimizer = torch.optim.Adam(disc.parameters(), lr=1e-2)
    first = None
    for _ in range(100):
        stats = discriminator_loss(disc, expert, policy, grad_penalty=0.1)
        first = float(stats["bce"].detach()) if first is None else first
        optimizer.zero_grad()
        stats["loss"].backward()
        optimizer.step()
    test_expert, test_policy = _batches(256, 1)  # held-out transitions
    stats = discriminator_loss(disc, test_expert, test_policy, grad_penalty=0.1)
    assert float(stats["bce"].detach()) < 0.7 * first
    assert (float(stats["expert_acc"]) + float(stats["policy_acc"])) / 2 > 0.85


def test_state_only_discriminator_reads_where_a_transition_arrives() -> None:
    """GAIL on s' alone: expert transitions arrive near the origin (a goal), the policy's 2 units away;
    the logit, the reward with ``gail_reward="logit"``, is higher at the expert's states."""
    torch.manual_seed(0)
    expert, policy = _batches(256, 0)
    expert["next_obs"], policy["next_obs"] = 0.1 * expert["next_obs"], policy["next_obs"] + 2.0
    disc = Discriminator("gail", "s", expert["next_obs"].numpy(), 2, (32, 32), gamma=0.99)
    assert disc.net[0].in_features == 4  # s' only: neither s nor a
    optimizer = torch.optim.Adam(disc.parameters(), lr=1e-2)
    for _ in range(100):
        stats = discriminator_loss(disc, expert, policy, grad_penalty=0.1)
        optimizer.zero_grad()
        stats["loss"].backward()
        optimizer.step()
    with torch.no_grad():
        shuffled = {**policy, "actions": expert["actions"], "obs": expert["obs"]}  # s and a cannot matter
        assert torch.equal(disc.logits(shuffled), disc.logits(policy))
        assert disc.logits(expert).mean() > disc.logits(policy).mean() + 2.0


@pytest.mark.parametrize("field, value, flag", [("gail_reward", "exp", "--gail-reward"), ("inputs", "a", "--inputs"),
                                               ("airl_reward", "softplus", "--airl-reward")])
def test_bad_adversarial_settings_are_refused(field: str, value: str, flag: str) -> None:
    from demo.errors import DemoError
    from demo.rl.adversarial import AdversarialConfig

    with pytest.raises(DemoError) as err:
        AdversarialConfig(**{field: value}).check()
    assert err.value.where == flag and repr(value) in err.value.problem


def test_gail_rewards_of_the_discriminator() -> None:
    from demo.rl.adversarial import reward_of_logits

    d = torch.tensor([0.01, 0.5, 0.99])  # D, the probability of "expert"
    logits = torch.log(d) - torch.log1p(-d)
    assert torch.allclose(reward_of_logits(logits, "softplus"), -torch.log1p(-d), atol=1e-5)
    assert torch.allclose(reward_of_logits(logits, "logit"), torch.log(d) - torch.log1p(-d), atol=1e-5)


def test_airl_reward_with_and_without_the_entropy_term() -> None:
    from demo.rl.adversarial import transition_reward

    torch.manual_seed(0)
    _, policy = _batches(16, 0)
    policy["terminal"] = (torch.arange(16) % 5 == 0).float()
    policy["logpi"] = torch.randn(16) - 2.0
    disc = Discriminator("airl", "ss", policy["obs"].numpy(), 2, (8,), gamma=0.9)
    f = disc.f(policy["obs"], policy["next_obs"], policy["terminal"])
    assert torch.allclose(transition_reward(disc, policy, "f"), f)  # no log pi: a wider policy earns nothing
    assert torch.allclose(transition_reward(disc, policy, "logit"), f - policy["logpi"])


def test_gradient_penalty_of_a_linear_discriminator() -> None:
    obs = np.array([[1.0, -1.0, 1.0], [-1.0, 1.0, -1.0]])  # mean 0, std 1: the standardiser is the identity
    disc = Discriminator("gail", "sa", obs, 2, (8,), gamma=0.99)
    linear = torch.nn.Linear(5, 1)
    with torch.no_grad():
        linear.weight.copy_(torch.tensor([[0.5, -1.0, 2.0, 0.0, 1.5]]))
    disc.net = torch.nn.Sequential(linear)
    expert, policy = _batches(32, 0)
    for b in (expert, policy):
        b["obs"] = b["obs"][:, :3].clamp(-4, 4)
        b["next_obs"] = b["next_obs"][:, :3]
    gp = gradient_penalty(disc, expert, policy)
    assert float(gp.detach()) == pytest.approx((np.sqrt(0.25 + 1 + 4 + 2.25) - 1) ** 2, rel=1e-5)
    # A unit-gradient discriminator is not penalised.
    with torch.no_grad():
        linear.weight.copy_(torch.tensor([[0.6, 0.0, 0.0, 0.8, 0.0]]))
    assert float(gradient_penalty(disc, expert, policy).detach()) == pytest.approx(0.0, abs=1e-10)


# ---------------------------------------------------------------------------------- linear IRL, exactly solved
N, H, GAMMA = 6, 12, 0.9  # a chain of N states, episodes of H steps from state 0; actions left, stay, right
TRUE_W = np.array([-1.0, 2.0])  # features: distance to the last state (in states / N), at the last state


def _features() -> np.ndarray:
    s = np.arange(N)
    return np.stack([(N - 1 - s) / N, (s == N - 1).astype(float)], axis=1)


def _next(s: int, a: int) -> int:
    return min(N - 1, max(0, s + a - 1))


def _feature_expectations(policy: np.ndarray) -> np.ndarray:
    """``sum_t gamma^t phi(s_{t+1})`` under a time-varying stochastic policy ``[H, N, 3]``, from state 0."""
    phi, d, mu = _features(), np.eye(N)[0], np.zeros(2)
    for t in range(H):
        nd = np.zeros(N)
        for s in range(N):
            for a in range(3):
                nd[_next(s, a)] += d[s] * policy[t, s, a]
        mu += GAMMA**t * nd @ phi
        d = nd
    return mu


def _solve(w: np.ndarray, soft: bool) -> np.ndarray:
    """Soft (MaxEnt) or greedy value iteration for the reward ``w . phi(s')``; the policy's feature expectations."""
    r = _features() @ w
    v, policy = np.zeros(N), np.zeros((H, N, 3))
    for t in reversed(range(H)):
        q = np.array([[r[_next(s, a)] + GAMMA * v[_next(s, a)] for a in range(3)] for s in range(N)])
        if soft:
            v = np.log(np.exp(q).sum(axis=1))
            policy[t] = np.exp(q - v[:, None])
        else:
            v = q.max(axis=1)
            policy[t] = np.eye(3)[q.argmax(axis=1)]
    return _feature_expectations(policy)


def test_maxent_recovers_the_reward_direction() -> None:
    mu_expert = _solve(TRUE_W * 5, soft=False)  # a near-deterministic expert of the true reward
    history = maxent_irl(mu_expert, lambda w: _solve(w, soft=True), rounds=300, lr=0.1)
    w = np.array(history[-1]["w_next"])
    assert w[0] < 0 < w[1]
    assert history[-1]["gap"] < 0.2 * history[0]["gap"]


def test_apprenticeship_matches_feature_expectations() -> None:
    mu_expert = _solve(TRUE_W, soft=False)
    history = apprenticeship(mu_expert, lambda w: _solve(w, soft=False), rounds=10)
    w = np.array(history[-1]["w_next"])
    assert history[1]["w"][0] < 0 < history[1]["w"][1]  # the first reward learned already points the right way
    assert history[-1]["t"] < 0.05 * history[0]["t"]  # and the margin closes
    assert unit(w) @ unit(TRUE_W) > 0


def test_discounted_sums_pad_with_the_last_state() -> None:
    mu = discounted_sums([np.array([[1.0], [2.0]]), np.array([[0.0]])], horizon=3, gamma=0.5)
    assert mu == pytest.approx([((1 + 0.5 * 2 + 0.25 * 2) + 0.0) / 2])


# ---------------------------------------------------------------------------------- from the command line
TS = "obs.ee_quat,obs.goal_quat,obs.goal_pos-obs.ee_pos"  # a task-space state, which a 6-DOF arm reports too
TINY = ["--steps", "100", "--envs", "1", "--rollout", "100", "--eval-episodes", "1"]  # one episode of reach


@pytest.fixture(scope="module")
def reach_store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from demo.cli.main import main

    path = tmp_path_factory.mktemp("irl") / "reach.zarr"
    assert main(["collect", "--task", "reach", "--episodes", "2", "--seed", "0", "--out", str(path)]) == 0
    return path


@pytest.fixture(scope="module")
def airl_run(reach_store: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    from demo.cli.main import main

    out = tmp_path_factory.mktemp("airl") / "run"
    assert main(["irl", "train", str(reach_store), "--algo", "airl", "--disc-obs-keys", TS, "--out", str(out), *TINY,
                 "--json", str(out.parent / "train.json")]) == 0
    return out, json.loads((out.parent / "train.json").read_text())


@pytest.fixture(scope="module")
def maxent_run(reach_store: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    from demo.cli.main import main

    out = tmp_path_factory.mktemp("maxent") / "run"
    assert main(["irl", "train", str(reach_store), "--algo", "maxent", "--inner-iterations", "1", "--out", str(out),
                 *TINY, "--json", str(out.parent / "train.json")]) == 0
    return out, json.loads((out.parent / "train.json").read_text())


def test_demonstrations_weigh_the_held_goal_for_the_rest_of_the_horizon(reach_store: Path, tmp_path: Path) -> None:
    from demo.rl.ppo import PPOConfig, RLRun

    with RLRun(PPOConfig(out=str(tmp_path / "run"), num_envs=1)) as rl:
        expert = rl.demonstrations(str(reach_store))
    assert expert.episodes == 2 and rl.record["data"]["episodes"] == 2
    for e in range(2):
        w = expert.weights[expert.episode == e]
        assert w.sum() == rl.pool.horizon and (w[:-1] == 1).all()  # the last transition holds to the horizon
    assert np.abs(expert.actions).max() <= 1.0 and expert.features.shape[1] == 3
    assert expert.features[expert.episode == 0][-1, 2] == 1.0  # the demonstration ends in success


@pytest.mark.slow
def test_airl_run_evaluates(airl_run: tuple[Path, dict]) -> None:
    from demo.cli.main import main

    out, summary = airl_run
    assert summary["env_steps"] == 100 and summary["demos"] == 2
    assert summary["reward_corr_last5"] is not None and summary["g_corr_last5"] is not None
    run = json.loads((out / "run.json").read_text())
    assert run["algo"] == "airl" and len(run["data"]["seeds"]) == 2
    assert run["adversarial"]["disc_obs"]["keys"] == TS.split(",") and (out / "reward.safetensors").is_file()
    assert main(["eval", str(out), "--episodes", "2"]) == 0


@pytest.mark.slow
def test_maxent_run_reports_weights(maxent_run: tuple[Path, dict]) -> None:
    out, summary = maxent_run
    assert summary["features"] == ["pos_err", "rot_err", "success"] and summary["env_steps"] == 100
    # one Adam step from w = 0 goes along sign(mu_E - mu_pi): errors cost, success pays
    assert summary["weights_unit"][0] < 0 < summary["weights_unit"][2]
    assert json.loads((out / "run.json").read_text())["reward_weights"]["weights"] == summary["weights"]
    assert (out / "weights.png").is_file()


@pytest.mark.parametrize("inputs, reward", [("sa", "softplus"), ("s", "logit")])
def test_gail_from_bc(inputs: str, reward: str, reach_store: Path, tmp_path: Path) -> None:
    from demo.rl.adversarial import AdversarialConfig, load_reward, train
    from demo.rl.ppo import PPOConfig

    rl = PPOConfig(task="reach", out=str(tmp_path / "gail"), total_steps=100, num_envs=2, num_steps=50, hidden=(32,),
                   eval_episodes=1)
    summary = train(AdversarialConfig(rl=rl, data=str(reach_store), kind="gail", bc_steps=300,
                                      disc_hidden=(32,), inputs=inputs, gail_reward=reward))
    assert summary["bc_loss"] < 0.05  # --init-bc, the default: the policy's mean fits the two demonstrations' actions
    disc, record = load_reward(rl.out)
    assert record["adversarial"]["kind"] == "gail" and disc.kind == "gail" and disc.inputs == inputs
    assert record["adversarial"]["gail_reward"] == reward
    # By default the discriminator reads reach's goal relative to the hand, not the policy's observation.
    assert record["adversarial"]["disc_obs"]["keys"] == ["obs.goal_pos-obs.ee_pos", "obs.goal_quat-obs.ee_quat"]
    assert disc.norm.mean.shape == (3 + 6,)  # a position difference and a relative rotation in 6D


@pytest.mark.slow
@pytest.mark.parametrize("source, robot", [
    ("maxent", None),
    pytest.param("airl", "robosuite_ur5e.toml", marks=pytest.mark.skipif(
        importlib.util.find_spec("robosuite") is None,
        reason="robosuite is not installed (pip install --no-deps robosuite runs this arm)")),
])
def test_ppo_on_a_learned_reward(source: str, robot: str | None, maxent_run: tuple[Path, dict],
                                 airl_run: tuple[Path, dict], tmp_path: Path) -> None:
    """Reward transfer: PPO on the reward of an IRL run, AIRL's g(s) on another arm (6 joints, not 7)."""
    from demo.cli.main import main

    run = (maxent_run if source == "maxent" else airl_run)[0]
    where = ["--robot", str(Path(__file__).resolve().parents[2] / "sim" / "assets" / "robots" / robot)] if robot else []
    js = tmp_path / "ppo.json"
    assert main(["irl", "train", "--reward", str(run), *where, "--out", str(tmp_path / "ppo"), *TINY, "--json", str(js)]) == 0
    assert json.loads(js.read_text())["reward_corr_last5"] is not None
    assert json.loads((tmp_path / "ppo" / "run.json").read_text())["learned_reward"]["kind"] == source


@pytest.mark.parametrize("args, message", [
    (["--algo", "gail"], "learns from demonstrations: name a STORE"),
    (["--algo", "ppo", "--reward", "nowhere"], "no such run directory"),
    (["--algo", "ppo", "--action", "ee_abs"], "RL acts in ee7 or joint_pos"),
    (["--algo", "dqn"], "unknown algorithm 'dqn'"),
])
def test_bad_requests_are_one_line_errors(args: list[str], message: str, tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    from demo.cli.main import main

    assert main(["irl", "train", "--out", str(tmp_path / "run"), *args]) == 1
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_a_store_in_another_action_representation_is_refused(reach_store: Path, tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    from demo.cli.main import main

    assert main(["irl", "train", str(reach_store), "--algo", "gail", "--action", "ee7", "--out", str(tmp_path / "r"),
                 "--steps", "10"]) == 1
    err = capsys.readouterr().err
    assert "holds joint_pos actions" in err and "demo convert" in err and not (tmp_path / "r").exists()
