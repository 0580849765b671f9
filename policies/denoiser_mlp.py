"""A light denoiser for low-dimensional policies: a residual MLP over the flattened action chunk.

Same interface as :class:`demo.policies.unet1d.ConditionalUnet1D`: ``net(x, t, obs)`` with ``x``
[B, horizon, action_dim], timestep ``t`` [B], flattened observation history ``obs`` [B, cond_dim];
``film_from_obs`` / ``film_from_step`` / ``denoise`` split the conditioning from the rest so that it
is computed once per chunk (observation) and once per sampler configuration (timesteps).

The conditioning enters the first layer, ``h0 = W_x x + W_t emb(t) + W_o obs + b`` (IDQL-style
concatenation), which is linear in each part, so the split is exact: the cached "FiLM" here is the
first layer's timestep and observation contribution. Then ``depth`` pre-LayerNorm residual blocks
``h += W2 mish(W1 LN(h))`` and a linear read-out.

Why it exists: at batch 1 a 1D UNet step is ~30 small convolution/normalisation kernels whose
per-call overhead dominates on a CPU, and at batch 256 it trains ~10x slower than an MLP of
similar quality on low-dimensional state. This one costs a few matrix-vector products per
denoising step.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

from demo.policies.unet1d import SinusoidalEmbedding


class ResidualMLPBlock(nn.Module):
    def __init__(self, width: int, expansion: int = 2):
        super().__init__()
        self.norm = nn.LayerNorm(width)
        self.fc1 = nn.Linear(width, expansion * width)
        self.fc2 = nn.Linear(expansion * width, width)

    def forward(self, h: torch.Tensor) -> torch.Tensor:
        return h + self.fc2(F.mish(self.fc1(self.norm(h))))


class MLPDenoiser(nn.Module):
    """``eps_or_x0 = net(x, t, obs)`` for chunks ``x`` [B, horizon, action_dim]."""

    def __init__(self, action_dim: int, horizon: int, cond_dim: int, width: int = 512, depth: int = 3, step_embed_dim: int = 128):
        super().__init__()
        self.action_dim, self.horizon, self.cond_dim = action_dim, horizon, cond_dim
        self.step_encoder = nn.Sequential(
            SinusoidalEmbedding(step_embed_dim),
            nn.Linear(step_embed_dim, 2 * step_embed_dim),
            nn.Mish(),
            nn.Linear(2 * step_embed_dim, step_embed_dim),
        )
        self.inp_x = nn.Linear(horizon * action_dim, width)
        self.inp_t = nn.Linear(step_embed_dim, width, bias=False)
        self.inp_o = nn.Linear(cond_dim, width)
        self.blocks = nn.ModuleList([ResidualMLPBlock(width) for _ in range(depth)])
        self.out_norm = nn.LayerNorm(width)
        self.out = nn.Linear(width, horizon * action_dim)
        self.film_dim = width

    def film_from_obs(self, obs: torch.Tensor) -> torch.Tensor:
        return self.inp_o(obs)

    def film_from_step(self, t: torch.Tensor) -> torch.Tensor:
        return self.inp_t(self.step_encoder(t))

    def denoise(self, x: torch.Tensor, film: torch.Tensor) -> torch.Tensor:
        b = x.shape[0]
        h = self.inp_x(x.reshape(b, -1)) + film
        for block in self.blocks:
            h = block(h)
        return self.out(F.mish(self.out_norm(h))).reshape(b, self.horizon, self.action_dim)

    def forward(self, x: torch.Tensor, t: torch.Tensor, obs: torch.Tensor) -> torch.Tensor:
        return self.denoise(x, self.film_from_obs(obs) + self.film_from_step(t))
