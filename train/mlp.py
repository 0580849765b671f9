"""Behaviour cloning with an MLP: observation history in, action chunk out, MSE loss.

The flattened, normalised history ``[n_obs * obs_dim]`` goes through ``hidden`` fully connected
layers to ``horizon * action_dim`` outputs. With ``horizon > 1`` this is action chunking as in ACT
(Zhao et al. 2023) without the transformer; :mod:`demo.train.actor` executes the chunks with
receding horizon and optional temporal ensembling. The loss ignores chunk steps past the episode
end (ACT's ``is_pad``) unless ``loss_on_pad`` is set.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from demo.train.policy import Policy, PolicySpec, register_policy

ACTIVATIONS = {"relu": nn.ReLU, "gelu": nn.GELU, "mish": nn.Mish, "silu": nn.SiLU}


@dataclass
class MLPConfig:
    hidden: tuple[int, ...] = (256, 256)
    activation: str = "relu"
    layer_norm: bool = False
    dropout: float = 0.0
    loss_on_pad: bool = False

    def __post_init__(self) -> None:
        self.hidden = tuple(int(h) for h in self.hidden)
        if not self.hidden or min(self.hidden) < 1:
            raise ValueError(f"hidden sizes must be positive, got {self.hidden}")
        if self.activation not in ACTIVATIONS:
            raise ValueError(f"activation {self.activation!r} is not one of {', '.join(ACTIVATIONS)}")
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"dropout must lie in [0, 1), got {self.dropout}")


@register_policy("bc")
class MLPPolicy(Policy):
    Config = MLPConfig

    def __init__(self, spec: PolicySpec, config: MLPConfig):
        super().__init__(spec, config)
        layers: list[nn.Module] = []
        width = spec.n_obs * spec.obs_dim
        for h in config.hidden:
            layers.append(nn.Linear(width, h))
            if config.layer_norm:
                layers.append(nn.LayerNorm(h))
            layers.append(ACTIVATIONS[config.activation]())
            if config.dropout:
                layers.append(nn.Dropout(config.dropout))
            width = h
        layers.append(nn.Linear(width, spec.horizon * spec.action_dim))
        self.net = nn.Sequential(*layers)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        out = self.net(obs.reshape(obs.shape[0], -1))
        return out.reshape(obs.shape[0], self.spec.horizon, self.spec.action_dim)

    def loss(self, obs: torch.Tensor, action: torch.Tensor, action_pad: torch.Tensor) -> torch.Tensor:
        err = (self(obs) - action).square()
        if self.config.loss_on_pad or self.spec.horizon == 1:
            return err.mean()
        keep = (~action_pad).unsqueeze(-1).to(err.dtype)
        # Step 0 is never padded, so the denominator is at least B * A.
        return (err * keep).sum() / (keep.sum() * err.shape[-1])

    @torch.no_grad()
    def predict(self, obs: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
        return self(obs)
