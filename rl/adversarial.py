"""Adversarial imitation: GAIL (Ho & Ermon 2016) and AIRL (Fu, Luo & Levine 2018), with PPO inside.

``demo irl train --algo gail|airl STORE --out RUN`` runs :func:`train`. Both alternate, every PPO
iteration (:class:`demo.rl.ppo.RLRun`):

1. roll the policy out (``num_envs x num_steps`` transitions);
2. train a discriminator for ``disc_epochs`` passes over those transitions against as many drawn
   from the demonstrations (:mod:`demo.rl.expert_data`; each episode's settled last transition
   weighted for the rest of the horizon, as the expert would have held it), with binary
   cross-entropy (expert = 1) and a gradient penalty;
3. reward the rollout with the updated discriminator, then a PPO update on that reward.

They differ in the discriminator and the reward (``D`` the probability of "expert", ``l`` its logit):

- **GAIL**: ``l = D_net(s, a)`` (or ``D_net(s, s')`` with ``inputs="ss"``, ``D_net(s')`` with ``inputs="s"``); reward
  ``-log(1 - D) = softplus(l)``, positive, which is why RL episodes here run to the horizon
  instead of ending on success (:mod:`demo.rl.ppo`); or (``gail_reward="logit"``) ``log D -
  log(1 - D) = l`` as DAC (Kostrikov et al. 2019) uses it, which does not flatten to 0 where ``D``
  is near 0 (far from the demonstrations) as the softplus does. ``inputs="s"`` reads the state a
  transition arrives at alone (state-only imitation, as GAIfO without the action): the policy's
  exploration noise, visible in ``a`` and in ``s' - s``, then cannot tell it from the expert.
- **AIRL**: ``D = exp(f) / (exp(f) + pi(a|s))`` with ``f(s, a, s') = g(s) + gamma h(s') - h(s)``
  (the disentangled form: ``g`` a state-only reward approximator, ``h`` a shaping potential, both
  MLPs; ``h(s') = 0`` after a terminal step), so ``l = f - log pi(a|s)``, with ``log pi`` the
  policy's own log-likelihood of the action (recorded as drawn for its rollouts, evaluated under
  the current policy for the demonstrations); reward ``log D - log(1 - D) = f - log pi(a|s)``,
  the entropy-regularised reward of the paper (``airl_reward="logit"``), or (``airl_reward="f"``)
  ``f`` alone: PPO here has no entropy term of its own to balance ``- log pi``, which by itself
  rewards a wider policy (measured below). ``g`` is the reward kept for transfer.

Gradient penalty (Gulrajani et al. 2017, as DAC uses it for adversarial imitation): ``lambda *
(|grad_x l(x)| - 1)^2`` at random interpolations ``x`` of expert and policy inputs (GAIL: the
discriminator's input; AIRL: ``(s, s')`` through ``f``), ``lambda = grad_penalty``.

The discriminator reads the policy's observation vector, or its own (``disc_obs_keys``, e.g. the
goal relative to the hand, ``obs.goal_pos-obs.ee_pos,obs.goal_quat-obs.ee_quat``, on reach: a
state that leaves out the arm's joints, whose redundant posture tells expert from policy without
telling success from failure, and the goal's absolute pose, which tells the demonstrations' few goals
from the policy's new ones, and that another arm reports too, so that AIRL's ``g`` transfers across
robots). Its
inputs are standardised by the demonstrations' own mean and std (fixed, floored at
:data:`demo.rl.ppo.MIN_STD`) and clipped to +-OBS_CLIP; actions are in the policy's normalised
units. ``--init-bc`` first fits the policy's mean to the demonstrations (MSE, ``bc_steps`` Adam
steps) with the observation statistics of the demonstrations.

Logged per iteration: discriminator loss (cross-entropy, gradient penalty), accuracy on expert and
policy samples, and the Pearson correlation with the dense task reward over the rollout of the reward
PPO is trained on (``reward_corr``) and of AIRL's ``g(s')`` (``g_corr``). The run also writes
``reward.safetensors`` (the discriminator and its input standardisation), read back by
:func:`load_reward` for reward transfer.

Measured on ``reach`` (20 demonstrations, 240,000 environment steps each, ``--init-bc``): neither
reaches success in that budget (0/100), where PPO on the dense reward needs ~400,000 steps for
80-90%. GAIL's reward correlates weakly with the task's (r 0.1-0.2); reading the task-space state
``(s, s')`` with ``grad_penalty`` 1 and the horizon-weighted demonstrations brought the policy to
~12 cm of the goal (from 26 cm). There it stays whatever the reward's form or inputs, as long as
the discriminator reads the goal's absolute orientation: 20 values in 20 demonstrations, new ones in
every policy episode, so the goal alone tells them apart. Read relative to the hand instead
(``obs.goal_pos-obs.ee_pos,obs.goal_quat-obs.ee_quat`` with ``inputs="s"``), 480,000 steps bring
it to 5-7 cm and 0.06-0.10 rad (reward correlation 0.49), still short of success (1 cm), and
1,200,000 steps to 4-6 cm and 0.05-0.07 rad, 1/100; with DAC's reward (``gail_reward="logit"``)
480,000 steps reach 6/100 (5-6 cm, 0.06-0.09 rad at the end of training): these are the defaults. AIRL's ``- log pi``
term outweighed ``f``: the policy's std grew from 0.37 to 1.07 (normalised units) as PPO maximised
entropy; with the relative state, to 290 by 1,200,000 steps, while its ``g`` correlated 0.5-0.7 with
the task's reward on those rollouts, yet PPO trained on that ``g`` afterwards moved away from the
goal (50-80 cm at 300,000 steps): a reward fitted where a near-uniform policy goes. Rewarding ``f``
alone (``airl_reward="f"``) keeps the std in check (0.37 to 0.27 over 480,000 steps) but PPO then
climbs ``f``'s shaping away from the goal (45-90 cm, against 20-40 cm with ``f - log pi``): the
paper's reward stays the default.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file
import torch
from torch import nn
from torch.nn import functional as F

from demo.errors import DemoError
from demo.jsonio import replace_atomically
from demo.policies import checkpoint as ckpt
from demo.policies.gaussian import mlp
from demo.policies.normalizer import OBS_CLIP
from demo.policies.observation import ObsSpec
from demo.progress import Progress
from demo.rl.config import KINDS, AdversarialConfig, ResidualConfig
from demo.rl.expert_data import ExpertData
from demo.rl.ppo import MIN_STD, RLRun, Rollout
from demo.rl.residual import ResidualRun
from demo.rl.rewards import pearson
from demo.sim.tasks import TASKS

GAIL_INPUTS = {"sa": ("obs", "actions"), "ss": ("obs", "next_obs"), "s": ("next_obs",)}  # what D_net reads
REWARD_FILE = "reward.safetensors"


# ====================================================================================== the discriminator
class Standardizer(nn.Module):
    """``clip((x - mean) / std)`` with the demonstrations' statistics (buffers, saved with the weights)."""

    def __init__(self, x: np.ndarray):
        super().__init__()
        x = np.asarray(x, np.float64)
        self.register_buffer("mean", torch.tensor(x.mean(axis=0), dtype=torch.float32))
        self.register_buffer("std", torch.tensor(np.maximum(x.std(axis=0), MIN_STD), dtype=torch.float32))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return ((x - self.mean) / self.std).clamp(-OBS_CLIP, OBS_CLIP)


class Discriminator(nn.Module):
    """GAIL's ``D_net`` or AIRL's ``g`` and ``h`` (module docstring), on standardised observations."""

    def __init__(self, kind: str, inputs: str, obs: np.ndarray, action_dim: int, hidden: tuple[int, ...], gamma: float):
        super().__init__()
        self.kind, self.inputs, self.gamma = kind, inputs, gamma
        self.norm = Standardizer(obs)
        d = obs.shape[1]
        if kind == "gail":
            self.net = mlp([sum(action_dim if k == "actions" else d for k in GAIL_INPUTS[inputs]), *hidden, 1], out_gain=1.0)
        else:
            self.g = mlp([d, *hidden, 1], out_gain=1.0)
            self.h = mlp([d, *hidden, 1], out_gain=1.0)

    def gail_input(self, obs: torch.Tensor, actions: torch.Tensor, next_obs: torch.Tensor) -> torch.Tensor:
        given = {"obs": obs, "actions": actions, "next_obs": next_obs}
        return torch.cat([given[k] if k == "actions" else self.norm(given[k]) for k in GAIL_INPUTS[self.inputs]], dim=-1)

    def f(self, obs: torch.Tensor, next_obs: torch.Tensor, terminal: torch.Tensor) -> torch.Tensor:
        """AIRL's ``g(s) + gamma h(s') - h(s)`` (``h(s') = 0`` after a terminal step)."""
        s, s2 = self.norm(obs), self.norm(next_obs)
        return self.g(s)[:, 0] + self.gamma * (1.0 - terminal) * self.h(s2)[:, 0] - self.h(s)[:, 0]

    def reward_g(self, obs: torch.Tensor) -> torch.Tensor:
        """AIRL's state-only reward approximator ``g(s)``."""
        return self.g(self.norm(obs))[:, 0]

    def logits(self, b: dict[str, torch.Tensor]) -> torch.Tensor:
        """The logit of "expert" for a batch ``b`` (obs, actions, next_obs, terminal, logpi)."""
        if self.kind == "gail":
            return self.net(self.gail_input(b["obs"], b["actions"], b["next_obs"]))[:, 0]
        return self.f(b["obs"], b["next_obs"], b["terminal"]) - b["logpi"]


def reward_of_logits(logits: torch.Tensor, form: str) -> torch.Tensor:
    """The reward of transitions whose discriminator logits (of "expert") are ``logits``: ``softplus``
    ``-log(1 - D)``, or ``logit`` ``log D - log(1 - D)``, the logit itself (module docstring)."""
    return F.softplus(logits) if form == "softplus" else logits


def transition_reward(disc: Discriminator, b: dict[str, torch.Tensor], form: str) -> torch.Tensor:
    """The reward PPO is given for the transitions ``b``: ``softplus`` or ``logit`` of the discriminator's
    logit (:func:`reward_of_logits`; AIRL's logit is ``f - log pi``), or ``f``, AIRL's ``f(s, a, s')`` alone."""
    if form == "f":
        return disc.f(b["obs"], b["next_obs"], b["terminal"])
    return reward_of_logits(disc.logits(b), form)


def gradient_penalty(disc: Discriminator, expert: dict[str, torch.Tensor], policy: dict[str, torch.Tensor]) -> torch.Tensor:
    """``(|grad_x l(x)| - 1)^2`` at random interpolations of expert and policy inputs (module docstring)."""
    eps = torch.rand(len(expert["obs"]), 1)
    mix = {k: (eps * expert[k] + (1 - eps) * policy[k]).requires_grad_(True) for k in ("obs", "actions", "next_obs")}
    if disc.kind == "gail":
        inputs = [mix[k] for k in GAIL_INPUTS[disc.inputs]]
        out = disc.net(disc.gail_input(mix["obs"], mix["actions"], mix["next_obs"]))[:, 0]
    else:
        inputs = [mix["obs"], mix["next_obs"]]
        out = disc.f(mix["obs"], mix["next_obs"], torch.zeros(len(eps)))
    grads = torch.autograd.grad(out.sum(), inputs, create_graph=True)
    norm = torch.cat([g.reshape(len(eps), -1) for g in grads], dim=1).norm(dim=1)
    return ((norm - 1.0) ** 2).mean()


def discriminator_loss(disc: Discriminator, expert: dict[str, torch.Tensor], policy: dict[str, torch.Tensor],
                       grad_penalty: float) -> dict[str, torch.Tensor]:
    """Binary cross-entropy (expert 1, policy 0) plus the gradient penalty, and accuracies."""
    le, lp = disc.logits(expert), disc.logits(policy)
    bce = F.binary_cross_entropy_with_logits(le, torch.ones_like(le)) + \
        F.binary_cross_entropy_with_logits(lp, torch.zeros_like(lp))
    gp = gradient_penalty(disc, expert, policy) if grad_penalty > 0 else torch.zeros(())
    return {"loss": bce + grad_penalty * gp, "bce": bce, "gp": gp,
            "expert_acc": (le > 0).float().mean(), "policy_acc": (lp < 0).float().mean()}


# ====================================================================================== the algorithm
class Adversary:
    """The discriminator, its optimiser and the demonstrations; trains on and rewards rollouts.

    ``spec``: the observation vector the discriminator reads (``disc_obs_keys``, default the policy's)."""

    def __init__(self, config: AdversarialConfig, rl: RLRun, expert: ExpertData, spec: ObsSpec):
        self.config, self.rl, self.expert, self.spec = config, rl, expert, spec
        self.obs, self.next_obs = spec.concat(expert.frames), spec.concat(expert.next_frames)
        self.occupancy = expert.weights / expert.weights.sum()  # the expert's state occupancy over the horizon
        torch.manual_seed(config.rl.seed + 1)
        self.disc = Discriminator(config.kind, config.inputs, self.obs, expert.actions.shape[1],
                                  config.disc_hidden, config.rl.gamma)
        self.optimizer = torch.optim.Adam(self.disc.parameters(), lr=config.disc_lr)
        self.rng = np.random.default_rng([config.rl.seed, 0xD15C])

    def _expert_batch(self, idx: np.ndarray) -> dict[str, torch.Tensor]:
        e, agent = self.expert, self.rl.agent
        b = {"obs": self.obs[idx], "actions": e.actions[idx], "next_obs": self.next_obs[idx],
             "terminal": np.zeros(len(idx)),
             # AIRL: log pi(a_E|s_E) under the current policy, on the observations as the policy normalises them
             "logpi": agent.logprob(np.clip(agent.obs_norm.normalize(e.obs[idx]), -OBS_CLIP, OBS_CLIP), e.actions[idx])
             if self.config.kind == "airl" else np.zeros(len(idx))}
        return {k: torch.as_tensor(np.asarray(v), dtype=torch.float32) for k, v in b.items()}

    def policy_batch(self, roll: Rollout) -> dict[str, torch.Tensor]:
        """The rollout's transitions as discriminator inputs (flattened; actions clipped as executed)."""
        flat = {k: np.asarray(v).reshape(-1, *np.shape(v)[2:]) for k, v in (
            ("actions", np.clip(roll.actions, -1.0, 1.0)), ("terminal", roll.terminated.astype(np.float64)),
            ("logpi", roll.logprobs))}
        b = {"obs": roll.vectors(self.spec), "next_obs": roll.vectors(self.spec, after=True), **flat}
        return {k: torch.as_tensor(v, dtype=torch.float32) for k, v in b.items()}

    def train(self, roll: Rollout) -> dict[str, float]:
        """``disc_epochs`` passes over the rollout against as many expert transitions, drawn with replacement
        in proportion to their share of the expert's occupancy (:mod:`demo.rl.expert_data`)."""
        c = self.config
        policy = self.policy_batch(roll)
        n = len(policy["obs"])
        stats: dict[str, torch.Tensor] = {}
        for _ in range(c.disc_epochs):
            order = self.rng.permutation(n)
            for start in range(0, n, c.disc_batch):
                idx = order[start:start + c.disc_batch]
                expert = self._expert_batch(self.rng.choice(len(self.obs), size=len(idx), p=self.occupancy))
                stats = discriminator_loss(self.disc, expert, {k: v[idx] for k, v in policy.items()}, c.grad_penalty)
                self.optimizer.zero_grad()
                stats["loss"].backward()
                self.optimizer.step()
        out = {f"disc_{k}": float(v.detach()) for k, v in stats.items()}
        if self.config.kind == "airl":  # the reward kept for transfer, against the task's
            with torch.no_grad():
                g = self.disc.reward_g(policy["next_obs"]).numpy()
            out["g_corr"] = pearson(g, roll.task_reward)
        return out

    def reward(self, roll: Rollout) -> np.ndarray:
        """``[T, N]`` rewards of the rollout: GAIL ``softplus(l)`` (or ``l``), AIRL ``l = f - log pi`` (or ``f``)."""
        form = self.config.gail_reward if self.config.kind == "gail" else self.config.airl_reward
        with torch.no_grad():
            reward = transition_reward(self.disc, self.policy_batch(roll), form)
        return reward.numpy().reshape(roll.task_reward.shape)

    def tensors(self) -> dict[str, torch.Tensor]:
        return {f"discriminator.{k}": v.detach().clone() for k, v in self.disc.state_dict().items()}


def pretrain_bc(rl: RLRun, expert: ExpertData, steps: int, seed: int) -> float:
    """Fit the policy's mean to the demonstrations (``--init-bc``): MSE on normalised actions, with the
    demonstrations' observation statistics; returns the last loss."""
    agent = rl.agent
    agent.obs_rms.update(expert.obs)
    agent.obs_norm = agent.obs_rms.normalizer()
    obs = torch.from_numpy(np.clip(agent.obs_norm.normalize(expert.obs), -OBS_CLIP, OBS_CLIP))
    act = torch.from_numpy(expert.actions.astype(np.float32))
    optimizer = torch.optim.Adam(agent.policy.mean.parameters(), lr=1e-3)
    rng = np.random.default_rng([seed, 0xBC])
    loss = torch.zeros(())
    for _ in range(steps):
        idx = torch.from_numpy(rng.integers(len(obs), size=min(256, len(obs))))
        loss = ((agent.policy.mean(obs[idx]) - act[idx]) ** 2).mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    return float(loss.detach())


def save_reward(out: Path, adversary: Adversary) -> None:
    """``reward.safetensors``: the discriminator's weights and standardisation (read by :func:`load_reward`)."""
    tensors = {k: v.contiguous() for k, v in adversary.disc.state_dict().items()}
    replace_atomically(out / REWARD_FILE, lambda tmp: save_file(tensors, str(tmp), metadata={"format": "demo-reward"}))


def load_reward(run: str | Path) -> tuple[Discriminator, dict[str, Any]]:
    """The discriminator of an adversarial run and its run record (never unpickles)."""

    run = Path(run)
    record = ckpt.read_run(run)
    spec = record.get("adversarial")
    if not isinstance(spec, dict) or spec.get("kind") not in KINDS:
        raise DemoError(run, "is not a GAIL or AIRL run (no 'adversarial' record)")
    try:
        tensors = load_file(str(run / REWARD_FILE))
        obs_dim = int(tensors["norm.mean"].shape[0])
        action_dim = int(record["policy"]["spec"]["action_dim"])
        disc = Discriminator(spec["kind"], str(spec.get("inputs", "sa")), np.zeros((2, obs_dim)), action_dim,
                             tuple(int(h) for h in spec["disc_hidden"]), float(spec["rl"]["gamma"]))
        disc.load_state_dict(tensors, strict=True)
    except (SafetensorError, OSError, KeyError, ValueError, TypeError, RuntimeError) as exc:
        raise DemoError(run / REWARD_FILE, f"not a reward this run can load ({str(exc).splitlines()[0][:160]})") from None
    return disc.eval(), record


def train(config: AdversarialConfig, *, progress: Progress | None = None, overwrite: bool = False,
          command: str | None = None) -> dict[str, Any]:
    """GAIL or AIRL on the demonstrations ``config.data`` into ``config.rl.out``; returns the summary."""
    config.check()
    if config.init:  # the policy is a residual over an imitation run (demo.rl.residual)
        residual = ResidualConfig(rl=config.rl, init=config.init, scale=config.scale, data=config.data,
                                  demos=config.demos, bc_coef=config.bc_coef)
        run: RLRun = ResidualRun(residual, name=config.kind, progress=progress, overwrite=overwrite, command=command)
    else:
        run = RLRun(config.rl, name=config.kind, progress=progress, overwrite=overwrite, command=command)
    rl_config = run.config
    with run as rl:
        expert = rl.demonstrations(config.data, config.demos)
        keys = config.disc_obs_keys or TASKS[rl_config.task].relative_goal_keys
        spec = ObsSpec.from_features(rl.pool.envs[0].features, keys, where="--disc-obs-keys") if keys else rl.pool.obs_spec
        rl.record["adversarial"] = {**config.to_json(), "disc_obs": spec.to_json()}
        rl.open()
        adversary = Adversary(config, rl, expert, spec)
        bc_loss = pretrain_bc(rl, expert, config.bc_steps, rl_config.seed) if config.init_bc and not config.init else None
        if config.init_bc or config.init:
            rl.evaluate()  # the starting line

        while rl.iteration < rl_config.iterations:
            rl.iterate(adversary.reward, adversary.train)
            if rl.metrics["eval"] and rl.metrics["eval"][-1]["step"] == rl.steps:
                save_reward(Path(rl_config.out), adversary)  # beside each checkpoint's policy
        save_reward(Path(rl_config.out), adversary)
        return rl.finish(adversary.tensors(), demos=expert.episodes, expert_transitions=int(len(expert.obs)),
                         bc_loss=bc_loss)
