"""DDPM noise schedule for training and DDPM / DDIM samplers for inference.

Own code rather than ``diffusers``: what Diffusion Policy uses of it is ~100 lines of arithmetic
(a beta schedule, ``add_noise`` and two update rules), while the library would add a large
dependency (and its config/serialisation machinery) to a CLI that must install fast and offline.

Conventions (Ho et al. 2020; Song et al. 2021), for a clean sample ``x0`` in [-1, 1]:

- ``alpha_bar[t]`` for ``t = 0 .. T-1``; ``x_t = sqrt(alpha_bar[t]) x0 + sqrt(1 - alpha_bar[t]) eps``.
- The schedule is ``squaredcos_cap_v2`` (Nichol & Dhariwal's cosine schedule, betas capped at
  0.999), the one Diffusion Policy trains with, with ``T = 100`` by default.
- The network predicts ``eps`` (``prediction="epsilon"``) or ``x0`` (``prediction="sample"``).
- Samplers walk a decreasing list of timesteps and end at ``alpha_bar = 1`` (the clean sample).
  DDPM with all ``T`` steps is the published reference; DDIM (eta = 0, deterministic given the
  starting noise) takes a few of them. The first step is always ``T-1`` ("trailing", Lin et al.
  2024) so that even 3-5 steps start from pure noise, where diffusers' default "leading" spacing
  would start from a partly clean sample that the Gaussian start does not match.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import torch

PREDICTIONS = ("epsilon", "sample")
SAMPLERS = ("ddim", "ddpm")
SPACINGS = ("quadratic", "linear")


def squared_cosine_betas(train_steps: int, max_beta: float = 0.999) -> torch.Tensor:
    """``squaredcos_cap_v2``: betas from ``alpha_bar(s) = cos((s + 0.008) / 1.008 * pi / 2)^2``."""

    def alpha_bar(s: float) -> float:
        return math.cos((s + 0.008) / 1.008 * math.pi / 2) ** 2

    betas = [
        min(1.0 - alpha_bar((i + 1) / train_steps) / alpha_bar(i / train_steps), max_beta) for i in range(train_steps)
    ]
    return torch.tensor(betas, dtype=torch.float64)


class NoiseScheduler:
    """The forward (noising) process and the reverse-step arithmetic; holds no network."""

    def __init__(self, train_steps: int = 100, prediction: str = "epsilon", clip_sample: float | None = 1.0):
        if prediction not in PREDICTIONS:
            raise ValueError(f"prediction must be one of {PREDICTIONS}, not {prediction!r}")
        if train_steps < 2:
            raise ValueError("train_steps must be >= 2")
        self.train_steps = train_steps
        self.prediction = prediction
        self.clip_sample = clip_sample
        betas = squared_cosine_betas(train_steps)
        # float64 for the cumulative product, float32 for use with the network.
        self.betas = betas.float()
        alpha_bar = torch.cumprod(1.0 - betas, dim=0)
        self.alpha_bar = alpha_bar.float()
        self._ab = alpha_bar.tolist()  # python floats: per-step arithmetic without tensor scalars

    # ------------------------------------------------------------------ training
    def add_noise(self, x0: torch.Tensor, noise: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        """``x_t`` for a batch: ``t`` is an integer tensor [B], ``x0`` and ``noise`` are [B, ...]."""
        ab = self.alpha_bar.to(x0.device)[t].reshape(-1, *([1] * (x0.dim() - 1)))
        return ab.sqrt() * x0 + (1.0 - ab).sqrt() * noise

    def target(self, x0: torch.Tensor, noise: torch.Tensor) -> torch.Tensor:
        """What the network is trained to output (MSE regression target)."""
        return noise if self.prediction == "epsilon" else x0

    # ------------------------------------------------------------------ inference
    def timesteps(self, steps: int, sampler: str = "ddim", spacing: str = "quadratic") -> list[int]:
        """``steps`` distinct, decreasing training timesteps visited by a sampler, first ``T-1``.

        ``linear`` spaces them evenly ("trailing"); ``quadratic`` (DDIM paper, Song et al. 2021,
        appendix D.2) puts more of them at low noise, where the choice between modes is finished:
        with 4-6 steps it keeps samples on the modes where linear spacing leaves some between them
        (measured with the exact denoiser of a two-point distribution, tests/policies/test_noise_scheduler.py).
        DDPM with ``steps == T`` visits every timestep whatever the spacing.
        """
        if sampler not in SAMPLERS:
            raise ValueError(f"sampler must be one of {SAMPLERS}, not {sampler!r}")
        if spacing not in SPACINGS:
            raise ValueError(f"spacing must be one of {SPACINGS}, not {spacing!r}")
        if not 1 <= steps <= self.train_steps:
            raise ValueError(f"steps must be in 1..{self.train_steps}, not {steps}")
        power = 1.0 if spacing == "linear" else 2.0
        T = self.train_steps
        ts = [max(0, round(T * (1.0 - i / steps) ** power) - 1) for i in range(steps)]
        for i in range(steps - 2, -1, -1):  # strictly decreasing, so exactly `steps` network calls
            ts[i] = max(ts[i], ts[i + 1] + 1)
        return ts

    def split(self, model_out: torch.Tensor, x_t: torch.Tensor, t: int) -> tuple[torch.Tensor, torch.Tensor]:
        """``(x0, eps)`` implied by the network's output at timestep ``t``; x0 clipped if configured."""
        ab = self._ab[t]
        if self.prediction == "epsilon":
            eps = model_out
            x0 = (x_t - math.sqrt(1.0 - ab) * eps) / math.sqrt(ab)
        else:
            x0 = model_out
            eps = (x_t - math.sqrt(ab) * x0) / math.sqrt(1.0 - ab)
        if self.clip_sample is not None:
            x0 = x0.clamp(-self.clip_sample, self.clip_sample)
            # keep eps consistent with the clipped x0, so the step stays on the same trajectory
            eps = (x_t - math.sqrt(ab) * x0) / math.sqrt(1.0 - ab)
        return x0, eps

    def step(
        self,
        model_out: torch.Tensor,
        x_t: torch.Tensor,
        t: int,
        t_prev: int,
        sampler: str = "ddim",
        generator: torch.Generator | None = None,
    ) -> torch.Tensor:
        """One reverse step from timestep ``t`` to ``t_prev`` (``-1`` means the clean sample)."""
        x0, eps = self.split(model_out, x_t, t)
        ab_t = self._ab[t]
        ab_prev = self._ab[t_prev] if t_prev >= 0 else 1.0
        if sampler == "ddim":  # eta = 0: deterministic
            return math.sqrt(ab_prev) * x0 + math.sqrt(1.0 - ab_prev) * eps
        # DDPM posterior q(x_prev | x_t, x0), variance "fixed_small"; with stride > 1 the per-step
        # alpha is the ratio of alpha_bars, which reduces to 1 - beta_t for consecutive steps.
        alpha = ab_t / ab_prev
        beta = 1.0 - alpha
        mean = (math.sqrt(ab_prev) * beta / (1.0 - ab_t)) * x0 + (math.sqrt(alpha) * (1.0 - ab_prev) / (1.0 - ab_t)) * x_t
        if t_prev < 0:
            return mean
        var = max(beta * (1.0 - ab_prev) / (1.0 - ab_t), 1e-20)
        noise = torch.randn(x_t.shape, generator=generator, dtype=x_t.dtype, device=x_t.device)
        return mean + math.sqrt(var) * noise

    def sample(
        self,
        denoise: Callable[[torch.Tensor, int, int], torch.Tensor],
        x_T: torch.Tensor,
        steps: int = 10,
        sampler: str = "ddim",
        generator: torch.Generator | None = None,
        timesteps: Sequence[int] | None = None,
        spacing: str = "quadratic",
    ) -> torch.Tensor:
        """Run the reverse process from ``x_T`` (standard normal).

        ``denoise(x_t, t, k)`` returns the network output at training timestep ``t``, the ``k``-th
        call of this run (so a caller can look up per-step quantities it precomputed).
        """
        ts = list(timesteps) if timesteps is not None else self.timesteps(steps, sampler, spacing)
        x = x_T
        for k, t in enumerate(ts):
            t_prev = ts[k + 1] if k + 1 < len(ts) else -1
            x = self.step(denoise(x, t, k), x, t, t_prev, sampler, generator)
        return x
