"""Full fine-tuning of an imitation policy by PPO on its own weights (DAPG: Rajeswaran et al. 2018), top to bottom.

``demo irl train STORE --algo finetune --init RUN --out RUN2`` starts from the BC run ``RUN`` (an MLP over
action chunks with the MSE head, from state) and lets PPO (:mod:`demo.rl.ppo`) change its weights on the
task reward, with the demonstrations in ``STORE`` kept in a BC term. Where residual RL
(:mod:`demo.rl.residual`, the default way to improve an imitation run) keeps the run frozen and bounds
what RL may add, this changes the policy itself: nothing bounds how far it moves but the small learning
rate of its weights and the BC term.

**The policy PPO updates is the run as ``demo eval`` executes it**: a query every control step, the chunks
temporally ensembled (:class:`demo.policies.actor.PolicyActor`). At step ``t`` the chunk queried ``i``
steps ago (``i < H``, the chunk length) says ``f(x_{t-i})[i]`` for this step, ``f`` the network (normalised
observation window -> normalised chunk) and ``x_s`` the window at step ``s``; ACT's oldest-first weights
``exp(-m k)`` over the ``n`` chunks that cover ``t`` (``k = n - 1 - i``) are ``exp(m i)`` once normalised, so
the mean action, in the normaliser's units, is::

    mu_t = sum_i w_i f(x_{t-i})[i] / sum_i w_i,     w_i = exp(m i) for the chunks that exist (t - i >= 0)

(``w`` = 1 for the newest alone without ensembling). PPO's Gaussian is ``N(mu_t, sigma^2)`` with a learned,
state-independent ``sigma``; its ratio needs ``mu_t`` under the current weights, so every transition keeps
the ``H`` windows it was computed from (:class:`EnsembledWindows`) and ``mu_t`` is recomputed from them in
every minibatch. The executed command is the draw unnormalised plus, for relative actions, the ensembled
measured joints the chunks were relative to (the normaliser is affine, so both ensemble alike), the binary
gripper rounded as the run rounds it.

**The critic** reads the state vector (running mean and std, as PPO's) and has its own MLP; the windows
reach the network exactly as the run's normaliser made them.

**Demonstrations** (``STORE``): each demonstrated episode replayed through the same windows, the target at
each of its states the demonstrated action in the same units (relative to the same ensembled joints);
every PPO minibatch step adds ``bc_coef`` times the squared error of ``mu`` there.

**Learning rates**: the network's weights at ``policy_lr`` (1e-5), ``sigma`` and the critic at PPO's
``lr``, both annealed; an iteration's epochs stop once the approximate KL passes ``target_kl`` (0.02): every
weight of the network moves the mean, and PPO's clip alone did not hold it (a KL of 1.2 in one iteration).
The monitor, the starting line and the curves are the residual's.

The run directory is an ordinary run of the base policy with new weights: ``demo eval RUN2`` executes it
like the BC run it came from.
"""

from __future__ import annotations

from collections import deque
import dataclasses
from typing import Any

import numpy as np
import torch
from torch import nn
from torch.distributions import Normal

from demo.errors import DemoError
from demo.policies import checkpoint as ckpt
from demo.policies.gaussian import mlp
from demo.policies.heads import MSEHead
from demo.policies.normalizer import OBS_CLIP, MinMaxNormalizer
from demo.policies.observation import ObsSpec
from demo.rl.config import FinetuneConfig
from demo.rl.expert_data import demonstrations
from demo.rl.ppo import Agent, Controller, EnvPool
from demo.rl.residual import ResidualRun, frame_keys
from demo.store import EpisodeStore


def check_base(base: ckpt.PolicyBundle, where: str) -> None:
    """Refuse a run whose execution PPO's Gaussian cannot follow (one line naming ``where``)."""
    head = getattr(base.policy, "head", None)
    if not isinstance(head, MSEHead) or getattr(base.policy, "film", None) is not None:
        raise DemoError(where, f"is a {base.algo} run; full fine-tuning takes a BC run with the MSE head "
                               "(--algo residual corrects any imitation run)")
    if base.obs_spec.images:
        raise DemoError(where, "reads cameras; full fine-tuning takes a policy from state (--algo residual corrects "
                               "pixel policies)")
    if base.execution.execute != 1 or base.execution.candidates != 1:
        raise DemoError(where, "executes several steps of each chunk; full fine-tuning follows a query every step "
                               "(train it with --execute 1, or use --algo residual)")


def slot_weights(horizon: int, ensemble: float | None) -> np.ndarray:
    """``[H]``: the weight of the chunk queried ``i`` steps ago in the executed action (module docstring)."""
    if ensemble is None:
        return np.eye(1, horizon, dtype=np.float32)[0]
    return np.exp(ensemble * np.arange(horizon)).astype(np.float32)


class EnsembledWindows:
    """One episode's last ``H`` observation windows (normalised as the run's) and the relative-action offsets of
    the chunks queried at them, newest first: the input of :class:`EnsembledChunks` and the command's offset."""

    def __init__(self, base: ckpt.PolicyBundle, state_spec: ObsSpec, weights: np.ndarray):
        self.base, self.state_spec, self.weights = base, state_spec, weights
        self.horizon, self.n_obs = base.policy.spec.horizon, base.policy.spec.n_obs
        self.history: deque[np.ndarray] = deque(maxlen=self.n_obs)
        self.windows: deque[np.ndarray] = deque(maxlen=self.horizon)
        self.offsets: deque[np.ndarray] = deque(maxlen=self.horizon)
        self.window_size = self.n_obs * base.obs_spec.dim

    @property
    def dim(self) -> int:
        """The length of :meth:`observe`'s vector: ``[state, H windows, H slot masks]``."""
        return self.state_spec.dim + self.horizon * self.window_size + self.horizon

    def observe(self, frame: dict[str, np.ndarray]) -> np.ndarray:
        """Add the frame (a chunk is queried at every step) and return the vector for it."""
        obs = self.base.obs_spec.vector(frame)
        self.history.extend([obs] * (self.n_obs if not self.history else 1))
        window = np.clip(self.base.obs_norm.normalize(np.stack(self.history)), -OBS_CLIP, OBS_CLIP)
        self.windows.appendleft(window.reshape(-1).astype(np.float32))
        action_dim = self.base.action.dim
        relative = self.base.relative
        self.offsets.appendleft(relative.base_frame(frame, action_dim) if relative is not None
                                else np.zeros(action_dim, np.float32))
        windows = np.zeros((self.horizon, self.window_size), np.float32)
        windows[: len(self.windows)] = np.stack(self.windows)
        mask = np.zeros(self.horizon, np.float32)
        mask[: len(self.windows)] = 1.0
        return np.concatenate([self.state_spec.vector(frame), windows.reshape(-1), mask]).astype(np.float32)

    def offset(self) -> np.ndarray:
        """``[A]``: the ensembled offset the normalised mean is relative to (zeros for absolute actions)."""
        w = self.weights[: len(self.offsets)]
        return (w[:, None] * np.stack(self.offsets)).sum(axis=0) / w.sum()


class EnsembledChunks(nn.Module):
    """PPO's Gaussian over the run's network: the mean is the ensembled action (module docstring)."""

    def __init__(self, network: nn.Module, state_dim: int, horizon: int, n_obs: int, obs_dim: int,
                 weights: np.ndarray, action_dim: int, init_log_std: float):
        super().__init__()
        self.network = network
        self.state_dim, self.horizon, self.n_obs, self.obs_dim = state_dim, horizon, n_obs, obs_dim
        self.register_buffer("weights", torch.from_numpy(weights))
        self.log_std = nn.Parameter(torch.full((action_dim,), float(init_log_std)))
        self.train()

    def train(self, mode: bool = True) -> "EnsembledChunks":
        super().train(mode)
        self.network.eval()  # a dropout layer would make the mean a draw: PPO's ratio needs it exact
        return self

    def mean(self, x: torch.Tensor) -> torch.Tensor:
        """``[..., A]`` ensembled normalised actions for :class:`EnsembledWindows` vectors ``[..., D]``."""
        lead, x = x.shape[:-1], x.reshape(-1, x.shape[-1])
        b, h = x.shape[0], self.horizon
        size = self.n_obs * self.obs_dim
        windows = x[:, self.state_dim: self.state_dim + h * size].reshape(b * h, self.n_obs, self.obs_dim)
        mask = x[:, self.state_dim + h * size:]
        chunks = self.network(windows).reshape(b, h, h, -1)  # [B, slot i, step, A]
        steps = torch.arange(h, device=x.device)
        own = chunks[:, steps, steps]  # [B, H, A]: slot i's action for this step, its step i
        w = mask * self.weights
        return ((w[..., None] * own).sum(dim=1) / w.sum(dim=1, keepdim=True)).reshape(*lead, -1)

    def distribution(self, x: torch.Tensor) -> Normal:
        mean = self.mean(x)
        return Normal(mean, self.log_std.exp().expand_as(mean))


class StateCritic(nn.Module):
    """The value of the state part of an :class:`EnsembledWindows` vector."""

    def __init__(self, state_dim: int, hidden: tuple[int, ...]):
        super().__init__()
        self.state_dim = state_dim
        self.net = mlp([state_dim, *hidden, 1], out_gain=1.0)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x[..., : self.state_dim])


class FinetuneController(Controller):
    """The agent's actions as the run's own, ensembled over its chunks (module docstring)."""

    def __init__(self, pool: EnvPool, base: ckpt.PolicyBundle, weights: np.ndarray):
        super().__init__(pool, base.action_norm)
        self.base, self.weights = base, weights
        self.episodes = [self.new_episode() for _ in pool.envs]
        self.actor = base.actor()  # for its binary rounding

    def new_episode(self) -> EnsembledWindows:
        return EnsembledWindows(self.base, self.pool.obs_spec, self.weights)

    @property
    def obs_dim(self) -> int:
        return self.episodes[0].dim

    def reset(self, i: int) -> None:
        self.episodes[i] = self.new_episode()

    def observe(self, i: int, frame: dict[str, np.ndarray]) -> np.ndarray:
        return self.episodes[i].observe(frame)

    def command(self, actions: np.ndarray, frames: dict[str, np.ndarray]) -> np.ndarray:
        raw = self.base.action_norm.unnormalize(actions)
        return np.stack([self.actor.finish(a + episode.offset()) for a, episode in zip(raw, self.episodes)])


class FinetuneRun(ResidualRun):
    """PPO on the weights of the BC run ``config.init`` (module docstring); the monitor, starting line, BC term
    and curves are the residual run's."""

    def __init__(self, config: FinetuneConfig, **kwargs: Any):
        super().__init__(config, name="finetune", **kwargs)

    def check_base(self, config: FinetuneConfig) -> None:
        check_base(self.base, config.init)
        self.base.policy.requires_grad_(True)
        self.weights = slot_weights(self.base.policy.spec.horizon, self.base.execution.ensemble)

    def make_controller(self) -> FinetuneController:
        return FinetuneController(self.pool, self.base, self.weights)

    def make_agent(self) -> Agent:
        c, spec = self.config, self.base.policy.spec
        state_dim = self.pool.obs_spec.dim
        policy = EnsembledChunks(self.base.policy, state_dim, spec.horizon, spec.n_obs, self.base.obs_spec.dim,
                                 self.weights, spec.action_dim, c.init_log_std)
        groups = [(list(self.base.policy.parameters()), self.from_imitation.policy_lr),
                  ([policy.log_std], c.lr)]
        return Agent(c, self.controller.obs_dim, spec.action_dim, policy=policy,
                     critic=StateCritic(state_dim, c.hidden), groups=groups, standardized=state_dim)

    def change_record(self) -> dict[str, Any]:
        return {"finetune": {"policy_lr": self.from_imitation.policy_lr, "slot_weights": self.weights.tolist()}}

    def bundle(self) -> ckpt.PolicyBundle:
        return dataclasses.replace(self.base, run=self.record, path=self.out)

    def policy_weights(self) -> tuple[dict[str, torch.Tensor], MinMaxNormalizer, MinMaxNormalizer]:
        return self.base.policy.state_dict(), self.base.obs_norm, self.base.action_norm

    def extra_tensors(self) -> dict[str, torch.Tensor]:
        return {}

    def demonstration_targets(self, path: str, demos: int | None) -> tuple[np.ndarray, np.ndarray, int]:
        """The agent's inputs ``[M, D]`` at every state of the first ``demos`` successful demonstrations (each
        replayed through its windows) and the demonstrated actions there in the mean's units ``[M, A]``."""
        base, keys = self.base, frame_keys(self.base, self.pool.obs_spec)
        inputs, targets = [], []
        with EpisodeStore.open(path) as store:
            chosen = demonstrations(store, path, str(base.task.get("name")), base.obs_spec, base.action, demos)
            for index in chosen:
                data = store.read_episode(int(index), [*keys, "action"])
                episode = self.controller.new_episode()
                for t, action in enumerate(np.asarray(data["action"], np.float32)):
                    inputs.append(episode.observe({k: data[k][t] for k in keys}))
                    targets.append(np.clip(base.action_norm.normalize(action - episode.offset()), -1.0, 1.0))
        return np.asarray(inputs, np.float32), np.asarray(targets, np.float32), len(chosen)


def train(config: FinetuneConfig, *, progress: Any = None, overwrite: bool = False,
          command: str | None = None) -> dict[str, Any]:
    """Full fine-tuning into ``config.rl.out`` from the BC run ``config.init``; returns the summary."""
    with FinetuneRun(config, progress=progress, overwrite=overwrite, command=command) as rl:
        return rl.run(config)
