"""Diffusion Policy (Chi et al. 2023): an action chunk sampled by denoising, conditioned on the
observation history. ``demo train DATA --algo diffusion``.

Reads top to bottom:

1. :class:`DiffusionConfig`: every hyperparameter of the policy (denoiser and its size, noise
   schedule, prediction target, sampler). The training-loop settings it is trained with (horizon
   16, n_obs 2, execute 4, 16,000 steps, AdamW, EMA) are in :data:`demo.training.config.POLICY_DEFAULTS`.
2. :meth:`DiffusionPolicy.loss`: forward noising. A clean normalised chunk ``x0`` (actions
   min-max normalised to [-1, 1] by the shared pipeline) is noised to a random timestep ``t`` of
   the 100-step squared-cosine DDPM schedule (:mod:`demo.policies.noise_scheduler`); the denoiser
   regresses ``x0`` (``sample``, default) or the noise (``epsilon``, published) with MSE. Denoisers:
   a residual MLP over the flattened chunk (:mod:`demo.policies.denoiser_mlp`, default: trains and
   samples fast on a CPU) or the published conditional 1D temporal UNet with FiLM conditioning
   (:mod:`demo.policies.unet1d`; ``large`` for the published (256, 512, 1024) size).
3. :meth:`DiffusionPolicy.predict`: reverse denoising from Gaussian noise with DDIM (few steps,
   deterministic given the start noise, which comes from the caller's seeded generator) or DDPM
   (all 100 steps: the published reference). The observation part of the conditioning is computed
   once per chunk, the timestep part once per sampler configuration, and the rest of the denoiser
   is traced and frozen (TorchScript) on first use, so a denoising step costs that rest only.
Training is behaviour cloning's (:func:`demo.imitation.bc.train` on the shared
:class:`demo.training.trainer.TrainingRun`: data pipeline, AdamW with warm-up + cosine, EMA, validation,
progress, checkpoints, plots, periodic rollouts) with the defaults of (1): diffusion brings a loss
and a sampler, nothing else.

Execution is the shared receding-horizon executor (:mod:`demo.policies.actor`): a chunk of
``horizon`` actions is sampled every ``execute`` steps, never temporally ensembled. Step 0 of a
chunk is the current frame's action (the shared convention; the reference implementation also
predicts the ``n_obs - 1`` past actions, which the shared window sampler does not provide).
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass
from typing import Any

import torch
from torch import nn
from torch.nn import functional as F

from demo.errors import DemoError
from demo.policies.denoiser_mlp import MLPDenoiser
from demo.policies.noise_scheduler import PREDICTIONS, SAMPLERS, SPACINGS, NoiseScheduler
from demo.policies.policy import Policy, PolicySpec, register_policy
from demo.policies.unet1d import LARGE, SMALL, ConditionalUnet1D


# ================================================================================== 1. config
DENOISERS = ("unet", "mlp")


@dataclass
class DenoiserConfig:
    """The network that maps a noisy chunk, a time and the observation to a chunk-shaped output: the
    diffusion policy's denoiser, flow matching's velocity field (:mod:`demo.policies.flow`)."""

    # mlp: residual MLP over the flattened chunk (demo.policies.denoiser_mlp) | unet: the published
    # conditional 1D temporal UNet (demo.policies.unet1d). On pick (100 demos, one CPU core) the MLP,
    # 8000 steps in ~12 min of CPU, reaches 96%; on an earlier avoid set the UNet (32,64,128),
    # 3000 steps in 27 min, reached 14-30% where the MLP reached 85-88%.
    denoiser: str = "mlp"
    channels: tuple[int, ...] = SMALL  # UNet widths per level
    large: bool = False  # the published UNet (256,512,1024) instead of ``channels``
    width: int = 512  # mlp denoiser: hidden width
    depth: int = 3  # mlp denoiser: residual blocks
    step_embed_dim: int = 128  # sinusoidal timestep embedding (published: 256)
    kernel: int = 5
    groups: int = 8  # GroupNorm groups

    def __post_init__(self) -> None:
        if self.denoiser not in DENOISERS:
            raise ValueError(f"denoiser must be one of {', '.join(DENOISERS)}, got {self.denoiser!r}")
        if self.width < 1 or self.depth < 0:
            raise ValueError(f"width must be >= 1 and depth >= 0, got {self.width}, {self.depth}")
        self.channels = tuple(int(c) for c in self.channels)
        if not self.channels or min(self.channels) < 1:
            raise ValueError(f"channels must be positive, got {self.channels}")
        if any(c % self.groups for c in self.net_channels):
            raise ValueError(f"every channel count must be divisible by groups={self.groups}: {self.net_channels}")
        if self.step_embed_dim < 2 or self.step_embed_dim % 2:
            raise ValueError(f"step_embed_dim must be even and >= 2, got {self.step_embed_dim}")

    @property
    def net_channels(self) -> tuple[int, ...]:
        return LARGE if self.large else self.channels


@dataclass
class DiffusionConfig(DenoiserConfig):
    """The diffusion policy's hyperparameters (``--policy-opt name=value``): its denoiser's, then these."""

    train_steps: int = 100  # DDPM timesteps (published: 100)
    # What the network predicts. "sample" (x0) rather than the published "epsilon": after minutes of
    # training, epsilon's x0 estimate at the first DDIM steps (its error amplified ~2000x at t = 99)
    # is clipped garbage and 4-8 DDIM steps land off the modes, while x0 prediction is as good with
    # 4 DDIM steps as with DDPM-100 (tests/policies/test_diffusion.py::test_sample_prediction_...).
    prediction: str = "sample"
    clip_sample: float = 1.0  # clip predicted x0 to [-c, c] while sampling; 0 = off
    inference_steps: int = 8  # network calls per chunk at inference
    sampler: str = "ddim"  # ddim (deterministic, few steps) | ddpm (stochastic; 100 steps = published)
    spacing: str = "quadratic"  # timesteps visited: quadratic (more at low noise) | linear
    jit: bool = True  # trace + freeze the denoiser for inference (same numbers, ~1.5-2x faster at batch 1)

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.prediction not in PREDICTIONS:
            raise ValueError(f"prediction must be one of {', '.join(PREDICTIONS)}, got {self.prediction!r}")
        if self.sampler not in SAMPLERS:
            raise ValueError(f"sampler must be one of {', '.join(SAMPLERS)}, got {self.sampler!r}")
        if self.spacing not in SPACINGS:
            raise ValueError(f"spacing must be one of {', '.join(SPACINGS)}, got {self.spacing!r}")
        if self.train_steps < 2:
            raise ValueError(f"train_steps must be >= 2, got {self.train_steps}")
        if not 1 <= self.inference_steps <= self.train_steps:
            raise ValueError(f"inference_steps must lie in [1, train_steps={self.train_steps}], got {self.inference_steps}")
        if self.clip_sample < 0:
            raise ValueError(f"clip_sample must be >= 0, got {self.clip_sample}")


def make_denoiser(spec: PolicySpec, config: DenoiserConfig) -> ConditionalUnet1D | MLPDenoiser:
    """The denoiser ``config`` describes for chunks of ``spec``, conditioned on the flattened observation
    history; also flow matching's velocity network (:mod:`demo.policies.flow`)."""
    cond_dim = spec.n_obs * spec.obs_dim
    if config.denoiser == "mlp":
        return MLPDenoiser(spec.action_dim, spec.horizon, cond_dim, config.width, config.depth, config.step_embed_dim)
    levels = len(config.net_channels)
    if spec.horizon % 2 ** (levels - 1):
        raise DemoError("--chunk", f"the UNet denoiser halves the chunk {levels - 1} times: chunk must be a multiple of "
                                   f"{2 ** (levels - 1)}, got {spec.horizon}")
    return ConditionalUnet1D(action_dim=spec.action_dim, cond_dim=cond_dim, channels=config.net_channels,
                             step_embed_dim=config.step_embed_dim, kernel=config.kernel, groups=config.groups)


# ================================================================================== 2-3. the policy
class _Denoiser(nn.Module):
    """The denoiser without its conditioning (``net.denoise``), as a module to trace."""

    def __init__(self, net: nn.Module):
        super().__init__()
        self.net = net

    def forward(self, x: torch.Tensor, film: torch.Tensor) -> torch.Tensor:
        return self.net.denoise(x, film)


@register_policy("diffusion")
class DiffusionPolicy(Policy):
    Config = DiffusionConfig

    def __init__(self, spec: PolicySpec, config: DiffusionConfig):
        super().__init__(spec, config)
        self.net = make_denoiser(spec, config)
        self._fast: dict[str, Any] | None = None  # inference cache, see _inference_plan

    def scheduler(self) -> NoiseScheduler:
        c = self.config
        return NoiseScheduler(c.train_steps, c.prediction, c.clip_sample or None)

    # ---------------------------------------------------------------- 2. training: forward noising
    def loss(self, obs: torch.Tensor, action: torch.Tensor, action_pad: torch.Tensor) -> torch.Tensor:
        """MSE between the denoiser's output and the clean chunk (or the noise) at a random timestep.

        Padded chunk steps (past the episode end, repeating the last action: "stay") are kept as
        in the reference implementation: they teach the policy to hold still at the goal.
        """
        scheduler = self._scheduler()
        b = action.shape[0]
        noise = torch.randn_like(action)
        t = torch.randint(0, scheduler.train_steps, (b,), device=action.device)
        noisy = scheduler.add_noise(action, noise, t)
        out = self.net(noisy, t, obs.reshape(b, -1))
        return F.mse_loss(out, scheduler.target(action, noise))

    # ---------------------------------------------------------------- 3. inference: reverse denoising
    @torch.no_grad()
    def predict(self, obs: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
        """Normalised chunk ``[B, horizon, action_dim]``; the start noise is drawn from ``generator``."""
        x = torch.randn((obs.shape[0], self.spec.horizon, self.spec.action_dim), generator=generator, dtype=obs.dtype,
                        device=obs.device)
        return self.sample(obs, x, generator)

    @torch.no_grad()
    def sample(self, obs: torch.Tensor, x_T: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
        """The normalised chunk the sampler reaches from the start noise ``x_T [B, horizon, action_dim]``:
        a deterministic function of ``(obs, x_T)`` with DDIM (DDPM draws its step noise from ``generator``)."""
        c = self.config
        b = obs.shape[0]
        plan = self._inference_plan(b)
        scheduler, timesteps, step_film, denoise = plan["scheduler"], plan["timesteps"], plan["step_film"], plan["denoise"]
        film_obs = self.net.film_from_obs(obs.reshape(b, -1))  # once per chunk
        return scheduler.sample(lambda x, t, k: denoise(x, film_obs + step_film[k]), x_T, sampler=c.sampler,
                                generator=generator, timesteps=timesteps)

    def one_step(self, obs: torch.Tensor, x_T: torch.Tensor) -> torch.Tensor:
        """The denoiser's clean chunk from pure noise ``x_T`` at the top timestep ``T-1``, with gradients:
        what a one-step sampler returns (before clipping), the output a distilled student trains
        (:mod:`demo.imitation.distill`). Needs ``prediction="sample"``: an epsilon estimate at ``T-1``
        would be divided by ``sqrt(alpha_bar[T-1])`` (5e-4 for T = 100) to become a chunk."""
        if self.config.prediction != "sample":
            raise ValueError("one_step needs prediction='sample'")
        b = obs.shape[0]
        t = torch.full((b,), self._scheduler().timesteps(1)[0], device=x_T.device)
        return self.net(x_T, t, obs.reshape(b, -1))

    def _inference_plan(self, batch: int) -> dict[str, Any]:
        """Timesteps, their conditioning contributions and the (traced) denoiser; rebuilt when the weights,
        the sampler settings or the batch size change (tensor version counters see in-place updates)."""
        c = self.config
        key = (
            batch, c.inference_steps, c.sampler, c.spacing, c.prediction, c.clip_sample, c.jit and not self.training,
            tuple((id(p), p.data_ptr(), 0 if p.is_inference() else p._version) for p in self.parameters()),
        )
        if self._fast is not None and self._fast["key"] == key:
            return self._fast
        scheduler = self._scheduler()
        timesteps = scheduler.timesteps(c.inference_steps, c.sampler, c.spacing)
        with torch.no_grad():
            step_film = self.net.film_from_step(torch.tensor(timesteps, device=self._device()))  # [K, film_dim]
        denoise: Any = self.net.denoise
        if c.jit and not self.training:
            denoise = self._traced(batch)
        self._fast = {"key": key, "scheduler": scheduler, "timesteps": timesteps, "step_film": step_film, "denoise": denoise}
        return self._fast

    def _traced(self, batch: int) -> Any:
        x = torch.zeros(batch, self.spec.horizon, self.spec.action_dim, device=self._device())
        film = torch.zeros(batch, self.net.film_dim, device=self._device())
        # TorchScript is deprecated in favour of torch.compile, but compiling takes minutes on 2
        # cores and tracing ~1 s; the traced graph runs the same kernels as eager, without Python.
        with torch.no_grad(), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            traced = torch.jit.trace(_Denoiser(self.net).eval(), (x, film), check_trace=False)
            return torch.jit.optimize_for_inference(torch.jit.freeze(traced))

    def _device(self) -> torch.device:
        return next(self.parameters()).device

    def _scheduler(self) -> NoiseScheduler:
        """:meth:`scheduler`, rebuilt only when its settings change."""
        key = (self.config.train_steps, self.config.prediction, self.config.clip_sample)
        if getattr(self, "_scheduler_key", None) != key:
            self._scheduler_obj, self._scheduler_key = self.scheduler(), key
        return self._scheduler_obj

    def __getstate__(self) -> dict[str, Any]:
        # copy.deepcopy (the EMA evaluation copy) must not copy the traced module
        state = self.__dict__.copy()
        state["_fast"] = None
        return state


def with_sampler(policy: DiffusionPolicy, steps: int | None = None, sampler: str | None = None,
                 spacing: str | None = None, jit: bool | None = None) -> DiffusionPolicy:
    """Change how ``policy`` samples (in place, e.g. for DDPM-100 reference evaluation); returns it."""
    changes = {k: v for k, v in {"inference_steps": steps, "sampler": sampler, "spacing": spacing, "jit": jit}.items() if v is not None}
    policy.config = dataclasses.replace(policy.config, **changes)
    return policy
