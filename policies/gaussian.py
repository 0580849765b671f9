"""The Gaussian policy of the RL algorithms (PPO, GAIL, AIRL, linear IRL: :mod:`demo.rl`), registered as ``ppo``.

A diagonal Gaussian over normalised actions (``[-1, 1]`` per dimension): a tanh MLP mean and a
state-independent log std. A run it is saved in evaluates with ``demo eval`` like any other policy.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch
from torch import nn
from torch.distributions import Normal

from demo.policies.policy import Policy, PolicySpec, register_policy


def mlp(sizes: Sequence[int], out_gain: float) -> nn.Sequential:
    """tanh MLP with orthogonal weights (gain sqrt 2; ``out_gain`` on the last layer), zero biases."""
    layers: list[nn.Module] = []
    for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:])):
        linear = nn.Linear(a, b)
        nn.init.orthogonal_(linear.weight, out_gain if i == len(sizes) - 2 else math.sqrt(2))
        nn.init.zeros_(linear.bias)
        layers += [linear, nn.Tanh()]
    return nn.Sequential(*layers[:-1])


@dataclass
class GaussianConfig:
    hidden: tuple[int, ...] = (256, 256)
    init_log_std: float = -1.0

    def __post_init__(self) -> None:
        self.hidden = tuple(int(h) for h in self.hidden)
        if not self.hidden or min(self.hidden) < 1:
            raise ValueError(f"hidden sizes must be positive, got {self.hidden}")


@register_policy("ppo")
class GaussianPolicy(Policy):
    """A diagonal Gaussian over normalised actions: an MLP mean and a state-independent log std.

    ``predict`` is the mean clipped to [-1, 1] (what is executed in evaluation); ``loss`` is the mean's
    squared error to normalised actions (behaviour cloning, for ``--init-bc``)."""

    Config = GaussianConfig

    def __init__(self, spec: PolicySpec, config: GaussianConfig):
        super().__init__(spec, config)
        if spec.n_obs != 1 or spec.horizon != 1 or spec.images:
            raise ValueError("the Gaussian policy reads one frame of low-dim state and acts one step")
        self.mean = mlp([spec.obs_dim, *config.hidden, spec.action_dim], out_gain=0.01)
        self.log_std = nn.Parameter(torch.full((spec.action_dim,), float(config.init_log_std)))

    def distribution(self, obs: torch.Tensor) -> Normal:
        """The action distribution for normalised observations ``[B, obs_dim]``."""
        mean = self.mean(obs)
        return Normal(mean, self.log_std.exp().expand_as(mean))

    def loss(self, obs: torch.Tensor, action: torch.Tensor, action_pad: torch.Tensor) -> torch.Tensor:
        return ((self.mean(obs[:, -1]) - action[:, 0]) ** 2).mean()

    @torch.no_grad()
    def predict(self, obs: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
        return self.mean(obs[:, -1]).clamp(-1.0, 1.0)[:, None]
