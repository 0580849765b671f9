"""Conditional 1D temporal UNet over action chunks (Diffusion Policy's CNN denoiser, Chi et al. 2023).

Input: a noisy action chunk ``x`` [B, horizon, action_dim] (time along the sequence), the diffusion
timestep ``t`` [B] and the flattened observation history ``obs`` [B, n_obs * obs_dim]. Output: the
same shape as ``x`` (predicted noise or clean chunk). Convolutions run over the time axis; every
residual block is modulated by FiLM (per-channel scale and bias) computed from
``cond = [step_embedding(t), obs]``.

One deliberate difference from the reference implementation: the per-block FiLM layers
``Linear(Mish(cond))`` are stacked into one ``Linear`` (the same function, one matmul instead of
one per block). Because Mish acts elementwise, that matmul splits exactly into an observation part
and a timestep part; at inference the observation part is computed once per action chunk and the
timestep part once per sampler step at load time, so a denoising step is the convolution stack
alone (:meth:`ConditionalUnet1D.denoise`), which is what gets traced and frozen for speed.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import nn
from torch.nn import functional as F

SMALL = (64, 128, 256)  # trains on 2 CPU cores in minutes
LARGE = (256, 512, 1024)  # the published size


class SinusoidalEmbedding(nn.Module):
    """Transformer-style sinusoidal embedding of a (float) timestep, [B] -> [B, dim]."""

    def __init__(self, dim: int):
        super().__init__()
        half = dim // 2
        freqs = torch.exp(-math.log(10000.0) * torch.arange(half, dtype=torch.float32) / max(1, half - 1))
        self.register_buffer("freqs", freqs, persistent=False)

    def forward(self, t: torch.Tensor) -> torch.Tensor:
        arg = t.float()[:, None] * self.freqs[None, :]
        return torch.cat([arg.sin(), arg.cos()], dim=-1)


class Conv1dBlock(nn.Sequential):
    """Conv1d -> GroupNorm -> Mish, 'same' padding."""

    def __init__(self, c_in: int, c_out: int, kernel: int, groups: int):
        super().__init__(nn.Conv1d(c_in, c_out, kernel, padding=kernel // 2), nn.GroupNorm(groups, c_out), nn.Mish())


class ResidualBlock(nn.Module):
    """Two conv blocks with FiLM (scale, bias) between them, plus a (1x1 conv) residual path."""

    def __init__(self, c_in: int, c_out: int, kernel: int, groups: int):
        super().__init__()
        self.c_out = c_out
        self.block1 = Conv1dBlock(c_in, c_out, kernel, groups)
        self.block2 = Conv1dBlock(c_out, c_out, kernel, groups)
        self.residual = nn.Conv1d(c_in, c_out, 1) if c_in != c_out else nn.Identity()

    def forward(self, x: torch.Tensor, film: torch.Tensor) -> torch.Tensor:
        scale, bias = film[:, : self.c_out, None], film[:, self.c_out :, None]
        h = self.block1(x) * scale + bias
        return self.block2(h) + self.residual(x)


class ConditionalUnet1D(nn.Module):
    """The denoiser ``eps_or_x0 = net(x, t, obs)``; see the module docstring for shapes."""

    def __init__(
        self,
        action_dim: int,
        cond_dim: int,
        channels: Sequence[int] = SMALL,
        step_embed_dim: int = 128,
        kernel: int = 5,
        groups: int = 8,
    ):
        super().__init__()
        channels = tuple(int(c) for c in channels)
        if any(c % groups for c in channels):
            raise ValueError(f"every channel count must be divisible by groups={groups}: {channels}")
        self.action_dim, self.cond_dim, self.channels = action_dim, cond_dim, channels
        self.step_embed_dim = step_embed_dim
        self.step_encoder = nn.Sequential(
            SinusoidalEmbedding(step_embed_dim),
            nn.Linear(step_embed_dim, 4 * step_embed_dim),
            nn.Mish(),
            nn.Linear(4 * step_embed_dim, step_embed_dim),
        )
        widths = [action_dim, *channels]
        blocks: list[ResidualBlock] = []
        self.down = nn.ModuleList()
        for i, (c_in, c_out) in enumerate(zip(widths[:-1], widths[1:])):
            last = i == len(channels) - 1
            pair = [ResidualBlock(c_in, c_out, kernel, groups), ResidualBlock(c_out, c_out, kernel, groups)]
            blocks += pair
            self.down.append(
                nn.ModuleList([*pair, nn.Conv1d(c_out, c_out, 3, stride=2, padding=1) if not last else nn.Identity()])
            )
        mid = channels[-1]
        self.mid = nn.ModuleList([ResidualBlock(mid, mid, kernel, groups), ResidualBlock(mid, mid, kernel, groups)])
        blocks += list(self.mid)
        self.up = nn.ModuleList()
        # Up levels concatenate the skips coarsest first and each undoes one downsampling; the finest
        # level's skip is left unused, as in the reference implementation.
        for c_out, c_in in reversed(list(zip(channels[:-1], channels[1:]))):
            pair = [ResidualBlock(2 * c_in, c_out, kernel, groups), ResidualBlock(c_out, c_out, kernel, groups)]
            blocks += pair
            self.up.append(nn.ModuleList([*pair, nn.ConvTranspose1d(c_out, c_out, 4, stride=2, padding=1)]))
        self.final = nn.Sequential(Conv1dBlock(channels[0], channels[0], kernel, groups), nn.Conv1d(channels[0], action_dim, 1))
        # FiLM of every block from one Linear over Mish(cond), cond = [step_embedding, obs].
        self._film_sizes = [2 * b.c_out for b in blocks]
        self.film = nn.Linear(step_embed_dim + cond_dim, sum(self._film_sizes))

    @property
    def film_dim(self) -> int:
        return sum(self._film_sizes)

    # ------------------------------------------------------------------ conditioning
    def film_from_obs(self, obs: torch.Tensor) -> torch.Tensor:
        """Observation part of all FiLM parameters (bias included), [B, cond_dim] -> [B, film_dim]."""
        w = self.film.weight[:, self.step_embed_dim :]
        return F.linear(F.mish(obs), w, self.film.bias)

    def film_from_step(self, t: torch.Tensor) -> torch.Tensor:
        """Timestep part of all FiLM parameters, [B] -> [B, film_dim]."""
        w = self.film.weight[:, : self.step_embed_dim]
        return F.linear(F.mish(self.step_encoder(t)), w)

    # ------------------------------------------------------------------ network
    def denoise(self, x: torch.Tensor, film: torch.Tensor) -> torch.Tensor:
        """The convolution stack: ``x`` [B, horizon, action_dim], ``film`` [B, film_dim]."""
        films = torch.split(film, self._film_sizes, dim=1)
        k = 0
        h = x.transpose(1, 2)
        skips = []
        for res1, res2, downsample in self.down:
            h = res1(h, films[k])
            h = res2(h, films[k + 1])
            k += 2
            skips.append(h)
            h = downsample(h)
        for res in self.mid:
            h = res(h, films[k])
            k += 1
        for res1, res2, upsample in self.up:
            h = torch.cat([h, skips.pop()], dim=1)
            h = res1(h, films[k])
            h = res2(h, films[k + 1])
            k += 2
            h = upsample(h)
        return self.final(h).transpose(1, 2)

    def forward(self, x: torch.Tensor, t: torch.Tensor, obs: torch.Tensor) -> torch.Tensor:
        return self.denoise(x, self.film_from_obs(obs) + self.film_from_step(t))


def count_parameters(net: nn.Module) -> int:
    return sum(p.numel() for p in net.parameters())
