"""Flow matching (Lipman et al. 2023; the action expert of pi0 and SmolVLA): an action chunk integrated
from Gaussian noise along a learned velocity field, conditioned on the observation history.
``demo train DATA --algo flow``.

Reads top to bottom:

1. :class:`FlowConfig`: the velocity network (the diffusion policy's denoisers,
   :func:`demo.policies.diffusion.make_denoiser`: a residual MLP by default, or the 1D UNet), how
   training draws times, and the integration steps at inference. Its training-loop settings are
   diffusion's (:data:`demo.training.config.POLICY_DEFAULTS`).
2. :meth:`FlowPolicy.loss`: the straight path from noise ``x0`` to the clean normalised chunk ``x1``,
   ``x_t = (1 - t) x0 + t x1``; the network regresses its velocity ``x1 - x0`` at a random ``t`` with
   MSE. Times are drawn as pi0 draws them (``beta``: ``t = 1 - s``, ``s ~ 0.999 Beta(1.5, 1)``, more
   weight on the noisy end, where the velocity is hardest to tell) or uniformly.
3. :meth:`FlowPolicy.predict`: ``steps`` Euler steps ``x += v(x, t) / steps`` from ``t = 0`` (noise
   drawn from the caller's seeded generator) to ``t = 1``: deterministic given the start noise. The
   observation's part of the conditioning is computed once per chunk, the times' once per setting.

Time enters the network's sinusoidal embedding scaled by :data:`TIME_SCALE`, the range of the
diffusion policy's timesteps, so that both read their time at the same frequencies.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch
from torch.nn import functional as F

from demo.policies.diffusion import DenoiserConfig, make_denoiser
from demo.policies.policy import Policy, PolicySpec, register_policy

TIME_SCALE = 100.0  # t in [0, 1] -> the embedding's input in [0, 100] (diffusion: timesteps 0..99)
TIME_SAMPLING = ("beta", "uniform")


# ================================================================================== 1. config
@dataclass
class FlowConfig(DenoiserConfig):
    """The flow-matching policy's hyperparameters (``--policy-opt name=value``): its velocity network's
    (the diffusion policy's denoiser, :class:`~demo.policies.diffusion.DenoiserConfig`), then these."""

    time_sampling: str = "beta"  # beta (pi0: more noisy times) | uniform
    inference_steps: int = 10  # Euler steps per chunk (pi0: 10)

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.time_sampling not in TIME_SAMPLING:
            raise ValueError(f"time_sampling must be one of {', '.join(TIME_SAMPLING)}, got {self.time_sampling!r}")
        if not 1 <= self.inference_steps <= 1000:
            raise ValueError(f"inference_steps must lie in [1, 1000], got {self.inference_steps}")


# ================================================================================== 2-3. the policy
@register_policy("flow")
class FlowPolicy(Policy):
    Config = FlowConfig

    def __init__(self, spec: PolicySpec, config: FlowConfig):
        super().__init__(spec, config)
        self.net = make_denoiser(spec, config)
        self._times: tuple[Any, torch.Tensor] | None = None  # (key, the steps' conditioning), see _step_film

    # ---------------------------------------------------------------- 2. training: the straight path's velocity
    def sample_times(self, b: int, device: torch.device) -> torch.Tensor:
        if self.config.time_sampling == "uniform":
            return torch.rand(b, device=device)
        beta = torch.distributions.Beta(torch.tensor(1.5, device=device), torch.tensor(1.0, device=device))
        return 1.0 - 0.999 * beta.sample((b,))

    def loss(self, obs: torch.Tensor, action: torch.Tensor, action_pad: torch.Tensor) -> torch.Tensor:
        """MSE between the network's velocity and ``x1 - x0`` at a random point of the path. Padded chunk
        steps are kept, as diffusion keeps them: they teach the policy to hold still at the goal."""
        b = action.shape[0]
        noise = torch.randn_like(action)
        t = self.sample_times(b, action.device)
        x_t = (1.0 - t)[:, None, None] * noise + t[:, None, None] * action
        velocity = self.net(x_t, t * TIME_SCALE, obs.reshape(b, -1))
        return F.mse_loss(velocity, action - noise)

    # ---------------------------------------------------------------- 3. inference: Euler integration
    @torch.no_grad()
    def predict(self, obs: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
        """Normalised chunk ``[B, horizon, action_dim]``; the start noise is drawn from ``generator``."""
        x = torch.randn((obs.shape[0], self.spec.horizon, self.spec.action_dim), generator=generator, dtype=obs.dtype,
                        device=obs.device)
        return self.integrate(obs, x)

    @torch.no_grad()
    def integrate(self, obs: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """The chunk reached from the start noise ``x`` in ``inference_steps`` Euler steps."""
        steps = self.config.inference_steps
        film_obs = self.net.film_from_obs(obs.reshape(obs.shape[0], -1))  # once per chunk
        step_film = self._step_film(steps, x.device)
        for k in range(steps):
            x = x + self.net.denoise(x, film_obs + step_film[k]) / steps
        return x

    def _step_film(self, steps: int, device: torch.device) -> torch.Tensor:
        """The times' conditioning ``[steps, film_dim]``, rebuilt when the weights or the steps change."""
        key = (steps, tuple((id(p), p.data_ptr(), 0 if p.is_inference() else p._version) for p in self.parameters()))
        if self._times is None or self._times[0] != key or self.training:
            times = torch.arange(steps, device=device, dtype=torch.float32) / steps * TIME_SCALE
            self._times = (key, self.net.film_from_step(times))
        return self._times[1]
