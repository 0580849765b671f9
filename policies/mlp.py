"""Behaviour cloning with an MLP: observation history in, action chunk out, through an output head.

The flattened, normalised history ``[n_obs * obs_dim]`` goes through ``hidden`` fully connected
layers to the outputs of a head (:mod:`demo.policies.heads`): ``mse`` regresses the chunk
(``horizon * action_dim`` outputs, the default), ``gmm`` is a mixture of Gaussians over the chunk and
``discrete`` a categorical per step and dimension; the last two sample at execution with the
rollout's seeded generator. With ``horizon > 1`` this is action chunking as in ACT (Zhao et al. 2023)
without the transformer; :mod:`demo.policies.actor` executes the chunks with receding horizon and
optional temporal ensembling. The loss ignores chunk steps past the episode end (ACT's ``is_pad``)
unless ``loss_on_pad`` is set.

Given a conditioning vector (``spec.cond_dim``: an instruction's, :mod:`demo.policies.instruction`),
every hidden layer's pre-activation ``h`` becomes ``h * (1 + gamma(c)) + beta(c)`` (FiLM, Perez et al.
2018; RT-1's conditioning), ``gamma`` and ``beta`` linear in ``c`` and zero at initialisation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from demo.policies.heads import GMM_OBJECTIVES, HEADS, ChunkHead, make_head
from demo.policies.instruction import CONDITION
from demo.policies.observation import STATE
from demo.policies.policy import Policy, PolicySpec, register_policy

ACTIVATIONS = {"relu": nn.ReLU, "gelu": nn.GELU, "mish": nn.Mish, "silu": nn.SiLU}


@dataclass
class MLPConfig:
    hidden: tuple[int, ...] = (256, 256)
    activation: str = "relu"
    layer_norm: bool = False
    dropout: float = 0.0
    loss_on_pad: bool = False
    head: str = "mse"  # mse | gmm | discrete (demo.policies.heads)
    components: int = 5  # gmm: mixture components over the whole chunk (robomimic: 5)
    # gmm: floor of each component's std, normalised units (robomimic: 1e-4; on avoid with commit, seeds
    # 0-2: 55, 3, 28/100 at 1e-4 against 49, 3, 26 at 0.01: the seed decides, not the floor)
    min_std: float = 0.01
    low_noise: bool = True  # gmm: act on the drawn component's mean (robomimic's low_noise_eval); false: a full sample
    bins: int = 64  # discrete: equal bins over each chunk step's and dimension's range in the data
    temperature: float = 1.0  # gmm, discrete: sampling temperature of the component / bin; 0 = the likeliest
    # gmm: one uniform per episode picks the component at every query (demo.policies.heads.draw), so the
    # ensembled chunks of an episode come from one mode; a fresh draw per query averages the modes
    # across the ensemble (avoid, seed 0: nll 49/100 against 25/100, wta 56/100 against 54/100)
    commit: bool = True
    # gmm: nll (robomimic) | wta, the nearest component fitted alone (demo.policies.heads). On avoid (commit,
    # seeds 0-2): wta 56, 45, 54/100, both sides on separate components on every seed; nll 49, 3, 26/100,
    # where seeds 1 and 2 put their heaviest components on the average of the sides
    objective: str = "wta"
    wta_epsilon: float = 0.05  # gmm, wta: the losers' pull towards the chunk (relaxed WTA)

    def __post_init__(self) -> None:
        self.hidden = tuple(int(h) for h in self.hidden)
        if not self.hidden or min(self.hidden) < 1:
            raise ValueError(f"hidden sizes must be positive, got {self.hidden}")
        if self.activation not in ACTIVATIONS:
            raise ValueError(f"activation {self.activation!r} is not one of {', '.join(ACTIVATIONS)}")
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"dropout must lie in [0, 1), got {self.dropout}")
        if self.head not in HEADS:
            raise ValueError(f"head must be one of {', '.join(HEADS)}, got {self.head!r}")
        if self.components < 1 or self.min_std <= 0:
            raise ValueError(f"components must be >= 1 and min_std > 0, got {self.components}, {self.min_std}")
        if self.objective not in GMM_OBJECTIVES or not 0.0 <= self.wta_epsilon < 1.0:
            raise ValueError(f"objective must be one of {', '.join(GMM_OBJECTIVES)} and wta_epsilon in [0, 1), "
                             f"got {self.objective!r}, {self.wta_epsilon}")
        if self.bins < 2 or self.temperature < 0:
            raise ValueError(f"bins must be >= 2 and temperature >= 0, got {self.bins}, {self.temperature}")


@register_policy("bc")
class MLPPolicy(Policy):
    Config = MLPConfig
    takes_condition = True

    def __init__(self, spec: PolicySpec, config: MLPConfig):
        super().__init__(spec, config)
        self.head: ChunkHead = make_head(config.head, spec.horizon, spec.action_dim, components=config.components,
                                         min_std=config.min_std, low_noise=config.low_noise, bins=config.bins,
                                         temperature=config.temperature, commit=config.commit,
                                         objective=config.objective, wta_epsilon=config.wta_epsilon)
        layers: list[nn.Module] = []
        width = spec.n_obs * spec.obs_dim
        self.film_at: list[int] = []  # the layers whose outputs FiLM modulates (before their activation)
        for h in config.hidden:
            layers.append(nn.Linear(width, h))
            if config.layer_norm:
                layers.append(nn.LayerNorm(h))
            self.film_at.append(len(layers) - 1)
            layers.append(ACTIVATIONS[config.activation]())
            if config.dropout:
                layers.append(nn.Dropout(config.dropout))
            width = h
        # The head's outputs are the last layer's (its parameters are these): an mse run's weights
        # keep the names and shapes they had before heads existed.
        layers.append(nn.Linear(width, self.head.width))
        self.net = nn.Sequential(*layers)
        self.film = None
        if spec.cond_dim:
            self.film = nn.ModuleList(nn.Linear(spec.cond_dim, 2 * h) for h in config.hidden)
            for f in self.film:  # identity at initialisation: the condition's effect is learnt
                nn.init.zeros_(f.weight)
                nn.init.zeros_(f.bias)

    def forward(self, obs: torch.Tensor | dict[str, torch.Tensor]) -> torch.Tensor:
        """The head's parameters for ``obs [B, n_obs, obs_dim]`` (with a condition: ``{"state": that, "condition":
        [B, cond_dim]}``): mse the chunk ``[B, H, A]``, else ``[B, head.width]``."""
        if self.film is None:
            return self.head.outputs(self.net(obs.reshape(obs.shape[0], -1)))
        x, c = obs[STATE], obs[CONDITION]
        x = x.reshape(x.shape[0], -1)
        films = iter(self.film)
        for i, layer in enumerate(self.net):
            x = layer(x)
            if i in self.film_at:
                gamma, beta = next(films)(c).chunk(2, dim=-1)
                x = x * (1.0 + gamma) + beta
        return self.head.outputs(x)

    def loss(self, obs: torch.Tensor, action: torch.Tensor, action_pad: torch.Tensor) -> torch.Tensor:
        keep = None if self.config.loss_on_pad or self.spec.horizon == 1 else ~action_pad
        return self.head.loss(self(obs), action, keep)

    def fit_actions(self, low: np.ndarray, high: np.ndarray) -> None:
        self.head.fit(low, high)

    @torch.no_grad()
    def predict(self, obs: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
        return self.head.sample(self(obs), generator)
