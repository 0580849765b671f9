"""PPO (Schulman et al. 2017) on the tasks' Gymnasium environments, CleanRL style, top to bottom.

``demo irl train --algo ppo --task reach --out RUN`` runs :func:`train` on the dense task reward, or
with ``--reward IRL_RUN`` on the reward an IRL run learned (reward transfer, :func:`learned_reward`);
GAIL, AIRL and linear IRL (:mod:`demo.rl.adversarial`, :mod:`demo.rl.irl_linear`) run the same
loop (:class:`RLRun`) with their learned reward in place of the task's. Measured on ``reach`` with the
defaults: 92/100 in ``demo eval`` after 480,000 environment steps (28 min of a shared 2-core CPU).

One file of ~600 lines on purpose: the algorithm reads top to bottom (environments, rollouts, GAE,
the clipped update, the run), as CleanRL's do; its configuration is :class:`demo.rl.config.PPOConfig`
and its network :mod:`demo.policies.gaussian`.

**Action space.** The policy is a Gaussian over *normalised* actions in [-1, 1] (clipped when
executed), mapped linearly onto per-step bounds. The default, ``joint_pos``, is joint position
targets *relative to the measured joints* (+-``max_joint_step`` = 0.1 rad per control step; the
gripper closedness 0..1 absolute), the parameterisation BC's runs use (:mod:`demo.policies.relative`):
zero is "hold still", and a step's effect is local wherever the arm is. ``ee7`` (end-effector
deltas through the env's IK, +-2 cm and +-0.1 rad per step) makes the action that reduces the
Cartesian errors nearly linear in the observed offsets, but measured on ``reach`` (same settings,
shared 2-core machine) it learned no faster per sample (dense return -296 vs -204 after 40,000
steps: random rotation deltas integrate into a 1-1.7 rad orientation walk) and stepped 3-4x slower
(74 vs ~300 steps/s: a converged IK solve per step), so joint deltas are the default.

**The loop** (one *iteration*): ``num_envs`` environments (a list stepped in turn) each run
``num_steps`` control steps with the current policy; rewards (the dense task reward of
:mod:`demo.rl.rewards`, or a learned one) are scaled by a running std of the discounted return;
advantages by GAE(gamma, lambda), bootstrapping on time-limit truncation (only a task's failure,
e.g. avoid's collision, is terminal); then ``epochs`` passes of minibatch updates of the clipped
surrogate, a value loss and an entropy bonus, with Adam, the learning rate annealed linearly.

**What an action means** is a :class:`Controller`'s call: here the whole command in the bounds above, from
the observation vector; a residual run (:mod:`demo.rl.residual`) adds the agent's action to a frozen
imitation policy's instead, reading that policy's action beside the state.

**Observations** are the vector a BC policy of the same task reads (:class:`ObsSpec` defaults:
state without velocities, positions relative to the EE), standardised by a running mean and std
(floored at :data:`MIN_STD`) and clipped to +-:data:`~demo.policies.normalizer.OBS_CLIP`. The
normaliser is frozen during an iteration and updated after it; it is saved as the run's
``MinMaxNormalizer`` with ``low = mean - std``, ``high = mean + std`` (the same affine map), so
``demo eval RUN`` executes the policy's mean action exactly as training computed it.

**Episodes** never end on success during training (``hold_success_s=None``): a learned reward of
one sign would otherwise teach the policy to end episodes early or to avoid ending them (the
survival bias of Kostrikov et al. 2019); they run to the task's horizon. Their reset seeds are
``episode_seed(seed + RL_OFFSET, i)``, disjoint from collection, ``demo eval`` and monitoring
(:mod:`demo.seeds`). ``eval_every`` iterations the policy's mean is rolled out as ``demo eval``
does (success held 0.5 s ends an episode) on the monitoring seeds.

The run directory is a ``demo eval`` run (:mod:`demo.policies.checkpoint`): the policy is registered as
``ppo`` (:class:`GaussianPolicy`, whose ``predict`` is the clipped mean), ``train_state.pt`` holds the
critic, the optimiser and the running statistics (tensors only).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
import math
from pathlib import Path
import time
from typing import Any

import numpy as np
import torch
from torch import nn

from demo.errors import DemoError
from demo.figures import pyplot, save_figure
from demo.gym.env import DemoEnv
from demo.policies import checkpoint as ckpt
from demo.policies.actor import ExecConfig
from demo.policies.gaussian import GaussianConfig, GaussianPolicy, mlp
from demo.policies.normalizer import OBS_CLIP, MinMaxNormalizer
from demo.policies.observation import ObsSpec, image_keys
from demo.policies.policy import PolicySpec
from demo.policies.relative import RelativeActions
from demo.progress import Progress
from demo.rl.config import PPOConfig
from demo.rl.expert_data import load_expert
from demo.rl.rewards import TaskReward, pearson, task_reward
from demo.seeds import RL_OFFSET, episode_seed
from demo.sim.robot_record import robot_record
from demo.store import ActionSpec
from demo.training.run import Run

MIN_STD = 0.01  # floor of the observation std (data units: m, rad, 1), so a constant input stays near 0


# ====================================================================================== running statistics
class RunningMeanStd:
    """Mean and variance of every vector seen (parallel Welford update), float64. ``standardized``: only the
    first so many entries are tracked, the rest stay at mean 0 and variance 1 (inputs already normalised)."""

    def __init__(self, dim: int, standardized: int | None = None):
        self.mean, self.var, self.count = np.zeros(dim), np.ones(dim), 1e-4
        self.standardized = dim if standardized is None else standardized

    def update(self, x: np.ndarray) -> None:
        x = np.asarray(x, np.float64).reshape(-1, self.mean.shape[0])
        n, mean, var = len(x), x.mean(axis=0), x.var(axis=0)
        delta, total = mean - self.mean, self.count + len(x)
        self.mean = self.mean + delta * n / total
        self.var = (self.var * self.count + var * n + delta**2 * self.count * n / total) / total
        self.count = total
        self.mean[self.standardized:], self.var[self.standardized:] = 0.0, 1.0

    def normalizer(self) -> MinMaxNormalizer:
        """``(x - mean) / std`` as a :class:`MinMaxNormalizer` (std floored at :data:`MIN_STD`)."""
        std = np.maximum(np.sqrt(self.var), MIN_STD)
        return MinMaxNormalizer(self.mean - std, self.mean + std)

    def state(self, prefix: str) -> dict[str, torch.Tensor]:
        return {f"{prefix}.mean": torch.from_numpy(self.mean), f"{prefix}.var": torch.from_numpy(self.var),
                f"{prefix}.count": torch.tensor(self.count, dtype=torch.float64)}


class RewardScaler:
    """Rewards divided by the running std of each environment's discounted return (CleanRL's
    ``NormalizeReward``), so one learning rate fits rewards of any scale; clipped to +-10."""

    def __init__(self, num_envs: int, gamma: float):
        self.ret, self.gamma, self.rms = np.zeros(num_envs), gamma, RunningMeanStd(1)

    def __call__(self, rewards: np.ndarray, dones: np.ndarray) -> np.ndarray:
        """``[T, N]`` rewards (and episode ends) of one iteration, scaled."""
        out = np.empty_like(rewards, dtype=np.float64)
        for t in range(len(rewards)):
            self.ret = self.ret * self.gamma + rewards[t]
            self.rms.update(self.ret[:, None])
            out[t] = rewards[t] / math.sqrt(float(self.rms.var[0]) + 1e-8)
            self.ret[dones[t]] = 0.0
        return np.clip(out, -10.0, 10.0)


# ====================================================================================== environments
def action_bounds(config: PPOConfig, n_arm: int) -> MinMaxNormalizer:
    """What [-1, 1] maps onto, per action entry (gripper closedness always 0..1)."""
    if config.action == "ee7":
        high = np.r_[np.full(3, config.max_ee_step), np.full(3, config.max_rot_step)]
    else:
        high = np.full(n_arm, config.max_joint_step)
    return MinMaxNormalizer(np.r_[-high, 0.0], np.r_[high, 1.0])


class EnvPool:
    """``n`` task environments (:class:`demo.gym.env.DemoEnv`) stepped in turn, each reset as its
    episode ends, from the RL seed stream (module docstring)."""

    def __init__(self, config: PPOConfig, n: int, robot: Any = None, cameras: Sequence[Any] = ()):
        """``robot``: a ``RobotConfig`` in place of ``config.robot``; ``cameras``: rendered into every frame (a
        residual run's, for its base run's pixel policy; the agent itself reads state)."""
        self.config = config
        self.envs: list[DemoEnv] = []
        try:
            for _ in range(n):
                self.envs.append(DemoEnv(config.task, robot=robot or config.robot, cameras=list(cameras),
                                         action=config.action, hold_success_s=None,
                                         store_layout=True,  # the store's names and shapes: the observation spec and rewards read them
                                         **config.task_options))
        except BaseException:
            self.close()
            raise
        first = self.envs[0]
        # the state keys by default, also where the frames carry the cameras a residual's base reads
        state = {k: v for k, v in first.features.items() if k not in image_keys(first.features)}
        self.obs_spec = ObsSpec.from_features(first.features if config.obs_keys else state, config.obs_keys or None,
                                              where=f"{config.task} environment")
        if self.obs_spec.images:
            raise DemoError("--obs-keys", "RL here reads state observations only, not camera images")
        self.action_spec: ActionSpec = first.action_spec
        self.n_arm = first.sim.robot.n_arm
        self.horizon = first.horizon
        self.relative = RelativeActions("obs.joint_pos", tuple(range(self.n_arm)), tuple(range(self.n_arm))) \
            if config.action == "joint_pos" else None
        self.episodes = 0
        self.frames: list[dict[str, np.ndarray]] = []
        self.seeds = [0] * n  # each environment's current episode seed
        self.obs: np.ndarray | None = None  # [N, D] the policy's input at :attr:`frames` (set by :func:`collect`)

    def _reset(self, i: int) -> dict[str, np.ndarray]:
        self.seeds[i] = episode_seed(self.config.seed + RL_OFFSET, self.episodes)
        self.episodes += 1
        return self.envs[i].reset(seed=self.seeds[i])[0]

    def reset(self) -> list[dict[str, np.ndarray]]:
        self.frames = [self._reset(i) for i in range(len(self.envs))]
        self.obs = None
        return self.frames

    def step(self, actions: np.ndarray) -> tuple[list[dict[str, np.ndarray]], np.ndarray, np.ndarray, np.ndarray,
                                                 np.ndarray]:
        """Execute one action per environment (its representation, e.g. ee7) from the current frames.

        Returns the frames after the step (before any reset), and per environment ``terminated``
        (failed for good), ``truncated`` (horizon), ``success`` and ``failed``; finished episodes are
        reset and :attr:`frames` holds the frames the next step starts from."""
        n = len(self.envs)
        after, term, trunc, success, failed = [], np.zeros(n, bool), np.zeros(n, bool), np.zeros(n, bool), np.zeros(n, bool)
        for i, env in enumerate(self.envs):
            frame, _, term[i], trunc[i], info = env.step(actions[i])
            after.append(frame)
            success[i], failed[i] = info["success"], info["failure"] is not None
            self.frames[i] = self._reset(i) if term[i] or trunc[i] else frame
        return after, term, trunc, success, failed

    def close(self) -> None:
        for env in self.envs:
            env.close()


def stack(frames: Sequence[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """Frames (dicts of arrays) -> one dict of arrays with a leading axis."""
    return {k: np.stack([f[k] for f in frames]) for k in frames[0]}


# ====================================================================================== rollouts
@dataclass
class Rollout:
    """One iteration's transitions, ``[T, N, ...]`` (steps x environments)."""

    obs: np.ndarray  # raw observation vectors before each step
    next_obs: np.ndarray  # raw observation vectors after it (before any reset)
    actions: np.ndarray  # normalised actions drawn (not clipped)
    logprobs: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray
    success: np.ndarray  # the task's success predicate after the step
    features: np.ndarray  # [T, N, F] the dense reward's features after the step
    task_reward: np.ndarray  # [T, N] the dense task reward
    starts: np.ndarray  # [T, N] whether the step is an episode's first
    obs_norm: MinMaxNormalizer  # the observation normaliser the policy acted with
    frames: dict[str, np.ndarray]  # every observation key of the env before each step, [T, N, ...]
    next_frames: dict[str, np.ndarray]  # ... and after it (before any reset)

    @property
    def dones(self) -> np.ndarray:
        return self.terminated | self.truncated

    def vectors(self, spec: ObsSpec, after: bool = False) -> np.ndarray:
        """``[T * N, spec.dim]``: another observation vector (e.g. a discriminator's) of every transition's
        state before (``after``: after) its step."""
        frames = self.next_frames if after else self.frames
        return spec.concat({k: v.reshape(-1, *v.shape[2:]) for k, v in frames.items()})

    def normalized(self, raw: np.ndarray) -> np.ndarray:
        return np.clip(self.obs_norm.normalize(raw), -OBS_CLIP, OBS_CLIP)


class Agent:
    """The policy, the critic, their optimiser and the observation statistics.

    By default PPO's Gaussian and critic MLPs, one learning rate; an algorithm may bring its own modules
    (``policy`` with ``distribution``, ``mean`` and ``log_std`` as :class:`GaussianPolicy` has them), the
    parameter ``groups`` and their learning rates, and how many leading entries of the observation are
    standardised (``standardized``; the rest arrive normalised)."""

    def __init__(self, config: PPOConfig, obs_dim: int, action_dim: int, policy: nn.Module | None = None,
                 critic: nn.Module | None = None, groups: Sequence[tuple[list[nn.Parameter], float]] | None = None,
                 standardized: int | None = None):
        self.config = config
        self.policy = policy if policy is not None else GaussianPolicy(PolicySpec(obs_dim, action_dim),
                                                                        GaussianConfig(config.hidden, config.init_log_std))
        self.critic = critic if critic is not None else mlp([obs_dim, *config.hidden, 1], out_gain=1.0)
        if groups is None:
            groups = [([*self.policy.parameters(), *self.critic.parameters()], config.lr)]
        else:
            groups = [*groups, (list(self.critic.parameters()), config.lr)]
        self.optimizer = torch.optim.Adam([{"params": p, "lr": lr} for p, lr in groups], eps=1e-5)
        self.lrs = [lr for _, lr in groups]  # each group's rate before annealing
        self.obs_rms = RunningMeanStd(obs_dim, standardized)
        self.obs_norm = self.obs_rms.normalizer()

    def act(self, obs_n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Draw normalised actions for normalised observations ``[N, D]``: ``(actions, logprobs)``."""
        with torch.no_grad():
            dist = self.policy.distribution(torch.from_numpy(obs_n.astype(np.float32)))
            a = dist.sample()
            return a.numpy(), dist.log_prob(a).sum(-1).numpy()

    def values(self, obs_n: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return self.critic(torch.from_numpy(obs_n.astype(np.float32)))[..., 0].numpy()

    def logprob(self, obs_n: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """log pi(a|s) under the current policy (``[..., D]``, ``[..., A]`` -> ``[...]``)."""
        with torch.no_grad():
            dist = self.policy.distribution(torch.from_numpy(obs_n.astype(np.float32)))
            return dist.log_prob(torch.from_numpy(actions.astype(np.float32))).sum(-1).numpy()


class Controller:
    """What the Gaussian policy's actions mean: PPO's own are the whole command, normalised to [-1, 1]
    (:func:`action_bounds`; relative to the measured joints for ``joint_pos``), read from the state vector.
    A residual run puts a frozen policy underneath (:class:`demo.rl.residual.ResidualController`)."""

    def __init__(self, pool: EnvPool, action_norm: MinMaxNormalizer):
        self.pool, self.action_norm = pool, action_norm

    @property
    def obs_dim(self) -> int:
        return self.pool.obs_spec.dim

    def reset(self, i: int) -> None:
        """Environment ``i`` has started a new episode (from ``pool.seeds[i]``)."""

    def observe(self, i: int, frame: dict[str, np.ndarray]) -> np.ndarray:
        """The policy's raw input for environment ``i``'s frame (called once per frame, in order)."""
        return self.pool.obs_spec.vector(frame)

    def command(self, actions: np.ndarray, frames: dict[str, np.ndarray]) -> np.ndarray:
        """``[N, A]`` commands to execute for clipped normalised actions ``[N, A]`` drawn at ``frames`` (stacked)."""
        executed = self.action_norm.unnormalize(actions)
        if self.pool.relative is not None:
            executed = executed + self.pool.relative.base(frames, executed.shape[1])
        return executed


def collect(agent: Agent, pool: EnvPool, controller: Controller, reward: TaskReward, steps: int) -> Rollout:
    """``steps`` control steps of every environment with the agent's stochastic policy."""
    options = pool.config.task_options
    norm = agent.obs_norm
    out: dict[str, list[np.ndarray]] = {k: [] for k in ("obs", "next_obs", "actions", "logprobs", "terminated",
                                                        "truncated", "success", "features", "starts")}
    before_all: list[dict[str, np.ndarray]] = []
    after_all: list[dict[str, np.ndarray]] = []
    if pool.obs is None:  # fresh episodes: the controller starts them too
        for i in range(len(pool.envs)):
            controller.reset(i)
        pool.obs = np.stack([controller.observe(i, f) for i, f in enumerate(pool.frames)])
    obs = pool.obs
    for _ in range(steps):
        out["starts"].append(np.array([env.sim.steps == 0 for env in pool.envs]))
        before_all.append(stack(pool.frames))
        a, logp = agent.act(np.clip(norm.normalize(obs), -OBS_CLIP, OBS_CLIP))
        after, term, trunc, success, failed = pool.step(controller.command(np.clip(a, -1.0, 1.0), before_all[-1]))
        frames = stack(after)
        after_all.append(frames)
        next_obs = np.stack([controller.observe(i, f) for i, f in enumerate(after)])
        out["obs"].append(obs)
        out["next_obs"].append(next_obs)
        obs = next_obs.copy()
        for i in np.flatnonzero(term | trunc):  # reset: the next step starts from the new episode's frame
            controller.reset(i)
            obs[i] = controller.observe(i, pool.frames[i])
        out["actions"].append(a)
        out["logprobs"].append(logp)
        out["terminated"].append(term)
        out["truncated"].append(trunc)
        out["success"].append(success)
        out["features"].append(reward.features(frames, failed, options))
    pool.obs = obs
    arrays = {k: np.stack(v) for k, v in out.items()}
    frames_before, frames_after = stack(before_all), stack(after_all)
    task = arrays["features"] @ np.asarray(reward.weights) + reward.events(frames_before, frames_after, options)
    return Rollout(**arrays, task_reward=task, obs_norm=norm, frames=frames_before, next_frames=frames_after)


def gae(rewards: np.ndarray, values: np.ndarray, next_values: np.ndarray, terminated: np.ndarray,
        dones: np.ndarray, gamma: float, lam: float) -> tuple[np.ndarray, np.ndarray]:
    """Generalised advantage estimation over ``[T, N]`` arrays: ``(advantages, returns)``.

    ``next_values`` are the critic's values of the states after each step (before any reset): a
    truncated episode bootstraps from them, a terminated one does not, and no advantage flows across
    an episode's end (``dones``)."""
    adv = np.zeros_like(rewards, dtype=np.float64)
    last = np.zeros(rewards.shape[1])
    for t in reversed(range(len(rewards))):
        delta = rewards[t] + gamma * next_values[t] * (1.0 - terminated[t]) - values[t]
        last = delta + gamma * lam * (1.0 - dones[t]) * last
        adv[t] = last
    return adv, adv + values


def ppo_losses(policy: GaussianPolicy, critic: nn.Module, obs: torch.Tensor, actions: torch.Tensor,
               old_logprobs: torch.Tensor, advantages: torch.Tensor, returns: torch.Tensor,
               clip: float) -> dict[str, torch.Tensor]:
    """The clipped surrogate (to minimise), the value loss, the entropy and the approximate KL of one minibatch."""
    dist = policy.distribution(obs)
    logratio = dist.log_prob(actions).sum(-1) - old_logprobs
    ratio = logratio.exp()
    adv = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
    surrogate = torch.max(-adv * ratio, -adv * ratio.clamp(1 - clip, 1 + clip)).mean()
    value = 0.5 * ((critic(obs)[:, 0] - returns) ** 2).mean()
    with torch.no_grad():
        kl = ((ratio - 1) - logratio).mean()  # Schulman's low-variance estimator
        clipped = ((ratio - 1).abs() > clip).float().mean()
    return {"policy": surrogate, "value": value, "entropy": dist.entropy().sum(-1).mean(), "kl": kl,
            "clip_fraction": clipped}


def ppo_update(agent: Agent, obs_n: np.ndarray, actions: np.ndarray, logprobs: np.ndarray, advantages: np.ndarray,
               returns: np.ndarray, rng: np.random.Generator,
               auxiliary: Callable[[], torch.Tensor] | None = None) -> dict[str, float]:
    """``epochs`` passes of minibatch steps on one iteration's flattened transitions; the last stats.
    ``auxiliary``: a loss added at every minibatch step (a residual's BC term on the demonstrations)."""
    c = agent.config
    t = {k: torch.from_numpy(np.asarray(v, np.float32).reshape(-1, *v.shape[2:]))
         for k, v in (("obs", obs_n), ("actions", actions), ("logprobs", logprobs), ("adv", advantages),
                      ("ret", returns))}
    n = len(t["obs"])
    size = n // c.minibatches
    params = [p for group in agent.optimizer.param_groups for p in group["params"]]
    stats: dict[str, float] = {}
    for _ in range(c.epochs):
        order = torch.from_numpy(rng.permutation(n))
        for start in range(0, size * c.minibatches, size):
            idx = order[start:start + size]
            losses = ppo_losses(agent.policy, agent.critic, t["obs"][idx], t["actions"][idx], t["logprobs"][idx],
                                t["adv"][idx], t["ret"][idx], c.clip)
            loss = losses["policy"] + c.vf_coef * losses["value"] - c.ent_coef * losses["entropy"]
            if auxiliary is not None:
                losses["auxiliary"] = auxiliary()
                loss = loss + losses["auxiliary"]
            agent.optimizer.zero_grad()
            loss.backward()
            nn.utils.clip_grad_norm_(params, c.max_grad_norm)
            agent.optimizer.step()
            stats = {k: float(v.detach()) for k, v in losses.items()}
        if c.target_kl is not None and stats["kl"] > c.target_kl:
            break
    return stats


# ====================================================================================== a run
RewardFn = Callable[[Rollout], np.ndarray]


class RLRun(Run):
    """A run directory trained by RL: a :class:`Run` (directory, record, checkpoints, monitoring, summary)
    over environments, an agent and the PPO loop (module docstring).

    ``name``: the algorithm recorded (``ppo``, ``gail``, ...); an algorithm adds what else the run
    records (e.g. the demonstrations its reward was learned from) to :attr:`record` before :meth:`open`.
    Ctrl-C saves a checkpoint of the last finished iteration."""

    EVAL_LABEL = " (eval)"  # the progress field shows the training rollouts' success between evaluations

    def __init__(self, config: PPOConfig, *, name: str = "ppo", progress: Progress | None = None,
                 overwrite: bool = False, command: str | None = None, robot: Any = None, cameras: Sequence[Any] = ()):
        config.check()
        super().__init__(config.out, seed=config.seed, threads=config.threads, stage=f"train {name}",
                         title=f"{name} on {config.task}", total_steps=config.iterations * config.batch,
                         monitor_episodes=config.eval_episodes, progress=progress, overwrite=overwrite, command=command)
        self.config, self.name = config, name
        self.pool = EnvPool(config, config.num_envs, robot, cameras)
        self.reward = task_reward(config.task, "--task")
        self.action_norm = action_bounds(config, self.pool.n_arm)
        self.controller = self.make_controller()
        self.agent = self.make_agent()
        self.rng = np.random.default_rng([config.seed, 0x990])
        self.scaler = RewardScaler(config.num_envs, config.gamma)
        self.steps = self.iteration = 0
        self.metrics = {"iterations": [], "eval": []}
        env = self.pool.envs[0]
        self.record = {
            "algo": name,
            "created": ckpt.now(),
            "command": command,
            "policy": self.policy_record(),
            "task": {"name": config.task, "options": dict(env.sim.task_options), "horizon": int(env.horizon)},
            "robot": robot_record(env.sim.robot),
            "fps": env.sim.fps,
            "data": None,
            "train": config.to_json(),
            "task_reward": self.reward.to_json(),
            "versions": {"torch": torch.__version__, "numpy": np.__version__},
        }

    def make_controller(self) -> Controller:
        """What the agent's actions mean (PPO's own: the whole command)."""
        return Controller(self.pool, self.action_norm)

    def policy_record(self) -> dict[str, Any]:
        """``run.json``'s policy section: what ``demo eval`` rebuilds the policy from."""
        return ckpt.policy_record("ppo", self.agent.policy, self.pool.obs_spec, self.pool.action_spec, ExecConfig(),
                                  self.pool.relative)

    def make_agent(self) -> Agent:
        """The networks PPO trains (its own Gaussian and critic)."""
        return Agent(self.config, self.controller.obs_dim, self.pool.action_spec.dim)

    def auxiliary_loss(self) -> Callable[[], torch.Tensor] | None:
        """A loss added to PPO's at every minibatch step (none here; a residual's BC term)."""
        return None

    def close(self) -> None:
        try:
            self.pool.close()
        finally:
            super().close()

    def can_checkpoint(self) -> bool:
        return self.iteration > 0 and (self.out / ckpt.RUN_FILE).is_file()

    def demonstrations(self, path: str, demos: int | None = None) -> Any:
        """The first ``demos`` successful episodes of the store at ``path`` as transitions in this run's
        units (:func:`demo.rl.expert_data.load_expert`), recorded as the run's data."""

        pool = self.pool
        expert = load_expert(path, self.config.task, pool.config.task_options, pool.obs_spec, pool.action_spec,
                             self.action_norm, pool.relative, self.reward, demos, pool.horizon)
        self.record["data"] = expert.record(str(Path(path).resolve()))
        return expert

    def open(self) -> None:
        """Create the run directory and record the run (refusing one that holds something else)."""
        self.open_directory()
        if self.record["robot"].get("files"):
            ckpt.save_robot(self.out, self.record["robot"], self.record["robot"].get("source") or self.out)
        self.write_record()

    # ---------------------------------------------------------------------------- the loop
    def learn(self, reward: RewardFn | None = None, before_update: Callable[[Rollout], dict[str, float]] | None = None
              ) -> None:
        """Every remaining iteration (:meth:`iterate`), evaluating and saving on schedule."""
        while self.iteration < self.config.iterations:
            self.iterate(reward, before_update)

    def iterate(self, reward: RewardFn | None = None, before_update: Callable[[Rollout], dict[str, float]] | None = None
                ) -> Rollout:
        """One iteration: collect, ``before_update`` (e.g. train a discriminator; returns figures to log),
        rewards (``reward``, default the dense task reward), GAE, PPO update, statistics; evaluation
        and a checkpoint every ``eval_every`` iterations and at the last."""
        c, agent, pool = self.config, self.agent, self.pool
        if not pool.frames:
            pool.reset()
        self.iteration += 1
        it, t0 = self.iteration, time.perf_counter()
        if c.anneal_lr:
            for group, lr in zip(agent.optimizer.param_groups, agent.lrs):
                group["lr"] = lr * (1.0 - (it - 1) / c.iterations)
        roll = collect(agent, pool, self.controller, self.reward, c.num_steps)
        collect_s = time.perf_counter() - t0
        self.steps += c.batch
        extra = before_update(roll) if before_update is not None else {}
        rewards = roll.task_reward if reward is None else reward(roll)
        scaled = self.scaler(rewards, roll.dones) if c.norm_reward else rewards
        obs_n, next_n = roll.normalized(roll.obs), roll.normalized(roll.next_obs)
        adv, ret = gae(scaled, agent.values(obs_n), agent.values(next_n), roll.terminated, roll.dones,
                       c.gamma, c.gae_lambda)
        stats = ppo_update(agent, obs_n, roll.actions, roll.logprobs, adv, ret, self.rng, self.auxiliary_loss())
        agent.obs_rms.update(roll.obs.reshape(-1, roll.obs.shape[-1]))
        agent.obs_norm = agent.obs_rms.normalizer()
        entry = self._log(it, roll, rewards, stats, extra, collect_s, time.perf_counter() - t0)
        if (c.eval_every and it % c.eval_every == 0) or it == c.iterations:
            self.evaluate()
            self.checkpoint()
        self.tick(done=self.steps, loss=entry["loss_policy"], val="", success=f"{entry['success']:.0%}",
                      info=f"return {'-' if entry['task_return'] is None else format(entry['task_return'], '.4g')}, "
                           f"{entry['steps_per_s']:,.0f} steps/s")
        return roll

    def _log(self, it: int, roll: Rollout, rewards: np.ndarray, stats: dict[str, float], extra: dict[str, float],
             collect_s: float, seconds: float) -> dict[str, Any]:
        ends = roll.dones
        per_episode = episode_sums(roll.task_reward, ends)
        entry = {
            "iteration": it,
            "env_steps": self.steps,
            "task_return": float(np.mean(per_episode)) if len(per_episode) else None,
            "reward_return": float(np.mean(episode_sums(rewards, ends))) if ends.any() else None,
            "success": float(roll.success[ends].mean()) if ends.any() else float(roll.success[-1].mean()),
            # the task features at the episodes' ends (reach: position error m, rotation error rad, success)
            "final_features": (roll.features[ends] if ends.any() else roll.features[-1]).mean(axis=0).tolist(),
            # how well a learned reward follows the dense task reward over this rollout (Pearson)
            "reward_corr": None if rewards is roll.task_reward else pearson(rewards, roll.task_reward),
            "std": float(self.agent.policy.log_std.detach().exp().mean()),
            "seconds": self.seconds,
            "steps_per_s": self.config.batch / max(collect_s, 1e-9),
            "update_s": seconds - collect_s,
            **{f"loss_{k}": v for k, v in stats.items()},
            **extra,
        }
        self.metrics["iterations"].append(entry)
        return entry

    # ---------------------------------------------------------------------------- what the run saves
    @property
    def step(self) -> int:
        return self.steps

    def bundle(self) -> ckpt.PolicyBundle:
        """The current policy (its mean), runnable as ``demo eval`` runs a saved one."""
        a = self.agent
        return ckpt.PolicyBundle("ppo", a.policy.eval(), self.pool.obs_spec, a.obs_norm, self.action_norm,
                                 self.pool.action_spec, ExecConfig(), self.record, self.out, self.pool.relative)

    def after_evaluation(self) -> None:
        self.agent.policy.train()

    def policy_weights(self) -> tuple[dict[str, torch.Tensor], MinMaxNormalizer, MinMaxNormalizer]:
        return self.agent.policy.state_dict(), self.agent.obs_norm, self.action_norm

    def train_state(self, extra: dict[str, torch.Tensor] | None) -> dict[str, Any]:
        """The critic, optimiser and observation statistics besides the policy (and an algorithm's ``extra``)."""
        a = self.agent
        return {"step": self.steps, "policy": a.policy.state_dict(), "critic": a.critic.state_dict(),
                "optimizer": a.optimizer.state_dict(), **a.obs_rms.state("obs_rms"), **(extra or {})}

    def plot(self, path: Path) -> None:
        plot_rl(self.metrics, path, title=f"{self.name} on {self.config.task}")

    def final_metrics(self) -> dict[str, Any]:
        last = self.metrics["eval"][-1] if self.metrics["eval"] else {}
        tail = self.metrics["iterations"][-5:]
        corr = {f"{k}_last5": float(np.mean([e[k] for e in tail])) for k in ("reward_corr", "g_corr")
                if tail and all(e.get(k) is not None for e in tail)}
        return {"env_steps": self.steps, "seconds": self.seconds, "success_rate": last.get("success_rate"),
                "eval_episodes": last.get("episodes"), **corr}

    def summary(self) -> dict[str, Any]:
        return {"out": self.config.out, "algo": self.name, **self.metrics["final"]}


def episode_sums(values: np.ndarray, dones: np.ndarray) -> np.ndarray:
    """Sums of ``values [T, N]`` over the episodes that end within the iteration (partial starts included)."""
    sums, running = [], np.zeros(values.shape[1])
    for t in range(len(values)):
        running += values[t]
        for i in np.flatnonzero(dones[t]):
            sums.append(running[i])
            running[i] = 0.0
    return np.asarray(sums)


def plot_rl(metrics: dict[str, Any], path: str | Path, title: str = "") -> Path:
    """Episode return of the dense task reward, evaluation success (95% interval; a fine-tuning run's starting
    line) and, for a learned reward, its correlation with the dense one, against environment steps."""

    plt = pyplot()
    its = [e for e in metrics.get("iterations", []) if e.get("task_return") is not None]
    evals = metrics.get("eval") or []
    corr = [k for k in ("reward_corr", "g_corr") if any(e.get(k) is not None for e in metrics.get("iterations", []))]
    fig, axes = plt.subplots(1, 3 if corr else 2, figsize=(15 if corr else 10, 3.8))
    ax, ax2 = axes[0], axes[1]
    for k in corr:
        pts = [(e["env_steps"], e[k]) for e in metrics["iterations"] if e.get(k) is not None]
        axes[2].plot(*zip(*pts), lw=1.2, label={"reward_corr": "reward trained on", "g_corr": "AIRL g(s')"}[k])
    if corr:
        axes[2].set_xlabel("environment steps")
        axes[2].set_ylabel("Pearson r with the dense task reward")
        axes[2].set_ylim(-1.02, 1.02)
        axes[2].grid(alpha=0.3)
        axes[2].legend(fontsize=8)
    if its:
        ax.plot([e["env_steps"] for e in its], [e["task_return"] for e in its], lw=1.4)
    ax.set_xlabel("environment steps")
    ax.set_ylabel("episode return (dense task reward)")
    ax.grid(alpha=0.3)
    if evals:
        x = [e["step"] for e in evals]
        ax2.fill_between(x, [e["ci95"][0] for e in evals], [e["ci95"][1] for e in evals], alpha=0.2)
        ax2.plot(x, [e["success_rate"] for e in evals], "o-", lw=1.4)
    if metrics.get("start"):  # a fine-tuning run's starting line: its base policy's success
        ax2.axhline(metrics["start"]["success_rate"], ls="--", lw=1.0, color="grey", label="start (the base policy)")
        ax2.legend(fontsize=8, loc="lower right")
    ax2.set_ylim(-0.02, 1.02)
    ax2.set_xlabel("environment steps")
    ax2.set_ylabel(f"eval success ({evals[-1]['episodes'] if evals else '?'} episodes)")
    ax2.grid(alpha=0.3)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return save_figure(fig, path)


# ====================================================================================== PPO on the task reward
def learned_reward(run: str, rl: RLRun) -> tuple[RewardFn, dict[str, Any]]:
    """The reward an IRL run learned, for RL in this run's setting (reward transfer): a linear reward
    (``maxent``, ``apprenticeship``) over the same task features, or AIRL's ``g(s')`` on the same
    observation vector; what the run records of it."""
    record = ckpt.read_run(run)
    linear = record.get("reward_weights")
    if isinstance(linear, dict):
        names = list(linear.get("features") or [])
        if names != list(rl.reward.names):
            raise DemoError(run, f"learned a reward over {names}; {rl.config.task}'s features are {list(rl.reward.names)}")
        w = np.asarray(linear["weights"], np.float64)
        return (lambda roll: roll.features @ w), {"run": str(run), "kind": record.get("algo"), "weights": w.tolist()}
    adversarial = record.get("adversarial") or {}
    if adversarial.get("kind") == "airl":
        from demo.rl.adversarial import load_reward  # deferred: demo.rl.adversarial imports this module

        disc, _ = load_reward(run)
        try:
            spec = ObsSpec.from_json(adversarial.get("disc_obs") or record["policy"]["obs"])
        except (KeyError, TypeError, ValueError) as exc:
            raise DemoError(run, f"malformed discriminator observation record ({exc})") from None
        spec.check_against(rl.pool.envs[0].features, f"{rl.config.task} environment (AIRL's g(s) of {run})")

        def g(roll: Rollout) -> np.ndarray:
            with torch.no_grad():
                x = torch.from_numpy(roll.vectors(spec, after=True).astype(np.float32))
                return disc.reward_g(x).numpy().reshape(roll.task_reward.shape)

        return g, {"run": str(run), "kind": "airl", "reward": "g(s')", "obs_keys": list(spec.keys)}
    raise DemoError(run, "holds no learned reward (a maxent, apprenticeship or airl run does)")


def train(config: PPOConfig, *, progress: Progress | None = None, overwrite: bool = False,
          command: str | None = None) -> dict[str, Any]:
    """PPO into the run directory ``config.out`` on the dense task reward (``reward="task"``) or on the
    reward learned by the IRL run ``config.reward`` (:func:`learned_reward`); returns the summary."""
    with RLRun(config, name="ppo", progress=progress, overwrite=overwrite, command=command) as rl:
        reward, learned = None, None
        if config.reward != "task":
            reward, learned = learned_reward(config.reward, rl)
            rl.record["learned_reward"] = learned
        rl.open()
        rl.learn(reward)
        return rl.finish()
