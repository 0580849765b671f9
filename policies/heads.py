"""Output heads: a distribution over a normalised action chunk, read from a network's flat output.

A head owns no weights (the discrete head keeps its bins' ranges as buffers): the network in front
of it (BC's MLP, :mod:`demo.policies.mlp`) ends in one linear layer of :attr:`ChunkHead.width` outputs,
and the head says what they mean, how to score a demonstrated chunk under them
(:meth:`ChunkHead.loss`) and how to act on them (:meth:`ChunkHead.sample`). Chunks are
``[B, H, A]``: ``H`` steps of ``A`` action dimensions, min-max normalised to [-1, 1] by the shared
pipeline.

- ``mse``: the chunk itself, regressed with mean squared error; acting returns it. Where the data
  holds two modes from one state, the regression lands on their average.
- ``gmm`` (robomimic's GMM actor): ``components`` Gaussians with diagonal covariance over the
  *whole chunk vector* (one mixture weight per component per chunk, not per step, so a sampled chunk
  follows one mode from its first step to its last). Means are unconstrained (no tanh: the data's
  extremes are exactly -1 and 1, where a tanh mean has no gradient), scales ``softplus + min_std``.
  Trained (``objective``) by negative log-likelihood (``nll``, robomimic) or winner-takes-all
  (``wta``): each chunk goes to the component whose mean is nearest (squared distance per kept
  dimension), which alone is fitted by its Gaussian NLL, while the mixture weights learn that
  component's index by cross-entropy and the others move towards the chunk with weight
  ``wta_epsilon / (K - 1)`` (relaxed WTA, Rupprecht et al. 2017, so none is left behind far from the
  data). Under the likelihood a wide component at the average of two modes explains both, and on
  some seeds training stays there (measured on avoid: two components on the average, 3/100); the
  nearest mean cannot be on both sides at once. Acting draws a component from the mixture weights (sharpened
  by ``temperature``: ``w^(1/T)``; 0 = the heaviest) with the caller's generator and returns its mean
  (robomimic's ``low_noise_eval``), or with ``low_noise`` off a full sample of that component.
- ``discrete``: each step's each dimension falls into one of ``bins`` equal bins over that step's
  and dimension's own range in the training data (:meth:`DiscreteHead.fit`; [-1, 1] until fitted);
  per-bin logits trained by cross-entropy on the target's nearest bin centre (quantisation error
  at most 1 / (bins - 1) of the range). One range for all steps would not do: actions relative to
  the query frame span a step's motion at step 0 and a chunk's at step 15, and 64 bins over the
  latter put every first step in the same bin (measured on avoid: 0/100). Acting draws each bin
  from its softmax at ``temperature`` (0 = the likeliest bin). The bins of different steps and
  dimensions are drawn independently.

Chunk steps past the episode end (``keep`` False) are left out of every loss: for the GMM this is
the exact marginal of the kept dimensions (a diagonal Gaussian's marginal drops the others).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

HEADS = ("mse", "gmm", "discrete")
GMM_OBJECTIVES = ("nll", "wta")
MIN_BIN_SPAN = 1e-3  # narrowest range of a discrete head's bins (normalised units): a constant dimension


def draw(logits: torch.Tensor, temperature: float, generator: torch.Generator | None, commit: bool = False) -> torch.Tensor:
    """Indices ``[N]`` drawn from ``softmax(logits [N, C] / temperature)``; temperature 0: the argmax.

    ``commit``: by the inverse CDF at uniforms that are the generator's next numbers, read without
    consuming them, so every call until something else draws from it uses the same uniforms: as the
    probabilities move continuously the index stays where it was unless its own mass moves away."""
    if temperature == 0:
        return logits.argmax(dim=-1)
    probs = (logits.float() / temperature).softmax(dim=-1)
    if not commit:
        return torch.multinomial(probs, 1, generator=generator)[:, 0]
    u = peek(generator, lambda: torch.rand(len(probs), 1, generator=generator, device=probs.device))
    return (probs.cumsum(dim=-1) < u).sum(dim=-1).clamp(max=probs.shape[-1] - 1)


def peek(generator: torch.Generator | None, sample: Callable[[], torch.Tensor]) -> torch.Tensor:
    """``sample()``'s draw from ``generator``, which is left as it was: the next call sees the same numbers
    (a rollout's generator is drawn from by its policy alone, so every query of an episode does)."""
    state = generator.get_state() if generator is not None else None
    out = sample()
    if generator is not None:
        generator.set_state(state)
    return out


def log_normal(x: torch.Tensor, mean: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
    """Elementwise log-density of ``x`` under ``N(mean, scale^2)``."""
    return -0.5 * ((x - mean) / scale).square() - scale.log() - 0.5 * math.log(2 * math.pi)


def masked_mean(values: torch.Tensor, keep: torch.Tensor | None) -> torch.Tensor:
    """Mean of ``values [B, H, ...]`` over the steps where ``keep [B, H]`` (all when None).

    Step 0 is never padded, so the denominator is never zero."""
    if keep is None:
        return values.mean()
    per_step = values[0, 0].numel()
    mask = keep.reshape(*keep.shape, *([1] * (values.dim() - 2))).to(values.dtype)
    return (values * mask).sum() / (mask.sum() * per_step)


class ChunkHead(nn.Module):
    """Base class: a distribution over ``[B, H, A]`` chunks parameterised by ``[B, width]`` outputs.

    A module so that what a head keeps (the discrete bins' ranges) moves and saves with the policy."""

    def __init__(self, horizon: int, action_dim: int):
        super().__init__()
        self.horizon, self.action_dim = horizon, action_dim

    def fit(self, low: np.ndarray, high: np.ndarray) -> None:
        """Take the training actions' ``[H, A]`` per-step limits (normalised) before training; most heads ignore them."""

    @property
    def width(self) -> int:
        raise NotImplementedError

    def outputs(self, flat: torch.Tensor) -> torch.Tensor:
        """The network's flat ``[B, width]`` outputs as the head's parameters (the loss and sampler take either)."""
        return flat

    def loss(self, out: torch.Tensor, action: torch.Tensor, keep: torch.Tensor | None) -> torch.Tensor:
        """Scalar loss of the demonstrated chunk ``action`` under ``out``; ``keep [B, H]`` (None = all steps)."""
        raise NotImplementedError

    def sample(self, out: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
        """The chunk ``[B, H, A]`` to execute; any randomness from ``generator``."""
        raise NotImplementedError


class MSEHead(ChunkHead):
    """The chunk itself; squared error."""

    @property
    def width(self) -> int:
        return self.horizon * self.action_dim

    def outputs(self, flat: torch.Tensor) -> torch.Tensor:
        """The chunk ``[B, H, A]``."""
        return flat.reshape(flat.shape[0], self.horizon, self.action_dim)

    def loss(self, out: torch.Tensor, action: torch.Tensor, keep: torch.Tensor | None) -> torch.Tensor:
        return masked_mean((self.outputs(out) - action).square(), keep)

    def sample(self, out: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
        return self.outputs(out)


class GMMHead(ChunkHead):
    """``components`` diagonal Gaussians over the flattened chunk; outputs per component: mean, scale, logit."""

    def __init__(self, horizon: int, action_dim: int, components: int, min_std: float, low_noise: bool,
                 temperature: float = 1.0, commit: bool = False, objective: str = "nll", wta_epsilon: float = 0.05):
        super().__init__(horizon, action_dim)
        self.components, self.min_std, self.low_noise, self.temperature = components, min_std, low_noise, temperature
        self.commit, self.objective, self.wta_epsilon = commit, objective, wta_epsilon

    @property
    def width(self) -> int:
        return self.components * (2 * self.horizon * self.action_dim + 1)

    def split(self, out: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``out [B, width]`` -> means, scales ``[B, K, H, A]`` and log mixture weights ``[B, K]`` (float32)."""
        b, k, d = out.shape[0], self.components, self.horizon * self.action_dim
        out = out.float()  # the likelihood in float32, also under bfloat16 autocast
        mean, scale, logit = out.split([k * d, k * d, k], dim=1)
        shape = (b, k, self.horizon, self.action_dim)
        return mean.reshape(shape), F.softplus(scale.reshape(shape)) + self.min_std, F.log_softmax(logit, dim=1)

    def kept(self, action: torch.Tensor, keep: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor]:
        """``[B, H]`` float mask of the kept chunk steps and ``[B]`` kept action dimensions per chunk."""
        mask = torch.ones_like(action[:, :, 0], dtype=torch.float32) if keep is None else keep.float()
        return mask, mask.sum(dim=1) * self.action_dim

    def loss(self, out: torch.Tensor, action: torch.Tensor, keep: torch.Tensor | None) -> torch.Tensor:
        """``nll``: negative log-likelihood of the chunk per kept action dimension (nats), mean over the batch."""
        if self.objective == "wta":
            return self.wta_loss(out, action, keep)
        mean, scale, log_w = self.split(out)
        log_p = log_normal(action.float().unsqueeze(1), mean, scale)  # [B, K, H, A]
        mask, per = self.kept(action, keep)
        log_p = (log_p * mask[:, None, :, None]).sum(dim=(2, 3))  # [B, K]: the kept dimensions' marginal
        nll = -torch.logsumexp(log_w + log_p, dim=1)
        return (nll / per).mean()

    def wta_loss(self, out: torch.Tensor, action: torch.Tensor, keep: torch.Tensor | None) -> torch.Tensor:
        """The winner's NLL per kept action dimension, plus cross-entropy of its index under the mixture
        weights, plus the losers' weighted mean squared distance; mean over the batch."""
        mean, scale, log_w = self.split(out)
        mask, per = self.kept(action, keep)
        sq = ((action.float().unsqueeze(1) - mean).square() * mask[:, None, :, None]).sum(dim=(2, 3)) / per[:, None]  # [B, K]
        win = sq.argmin(dim=1)
        k = self.components
        weight = torch.full_like(sq, self.wta_epsilon / max(k - 1, 1)).scatter(1, win[:, None], 0.0)
        wta = (weight * sq).sum(dim=1).mean()  # the losers drift towards the data, so none dies far away
        ce = F.nll_loss(log_w, win)
        rows = torch.arange(len(win), device=win.device)
        log_p = log_normal(action.float(), mean[rows, win], scale[rows, win])  # [B, H, A]
        nll = -((log_p * mask[:, :, None]).sum(dim=(1, 2)) / per).mean()
        return wta + ce + nll

    def sample(self, out: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
        mean, scale, log_w = self.split(out)
        k = draw(log_w, self.temperature, generator, self.commit)  # one component per chunk
        rows = torch.arange(len(k), device=k.device)
        chunk = mean[rows, k]
        if not self.low_noise:
            noise = torch.randn(chunk.shape, generator=generator, device=chunk.device, dtype=chunk.dtype)
            chunk = (chunk + scale[rows, k] * noise).clamp(-1.0, 1.0)  # the data spans [-1, 1]
        return chunk.to(out.dtype)


class DiscreteHead(ChunkHead):
    """``bins`` logits per chunk step and action dimension over equal bins of that step's and dimension's range."""

    def __init__(self, horizon: int, action_dim: int, bins: int, temperature: float = 1.0):
        super().__init__(horizon, action_dim)
        self.bins, self.temperature = bins, temperature
        self.register_buffer("low", torch.full((horizon, action_dim), -1.0))
        self.register_buffer("high", torch.full((horizon, action_dim), 1.0))

    def fit(self, low: np.ndarray, high: np.ndarray) -> None:
        """Bins over ``[low, high]`` per step and dimension (``[H, A]``, normalised units)."""
        low, high = np.asarray(low, np.float32), np.asarray(high, np.float32)
        if low.shape != tuple(self.low.shape) or high.shape != low.shape:
            raise ValueError(f"limits must be {tuple(self.low.shape)}, got {low.shape} and {high.shape}")
        self.low.copy_(torch.from_numpy(low))
        self.high.copy_(torch.from_numpy(np.maximum(high, low + MIN_BIN_SPAN)))

    @property
    def width(self) -> int:
        return self.horizon * self.action_dim * self.bins

    def logits(self, out: torch.Tensor) -> torch.Tensor:
        return out.float().reshape(out.shape[0], self.horizon, self.action_dim, self.bins)

    def centres(self) -> torch.Tensor:
        """``[H, A, bins]`` bin centres, normalised units."""
        u = torch.linspace(0.0, 1.0, self.bins, device=self.low.device)
        return self.low[..., None] + (self.high - self.low)[..., None] * u

    def loss(self, out: torch.Tensor, action: torch.Tensor, keep: torch.Tensor | None) -> torch.Tensor:
        """Cross-entropy (nats) of the target's nearest bin, mean over kept steps and dimensions."""
        u = (action.float() - self.low) / (self.high - self.low)
        target = (u.clamp(0.0, 1.0) * (self.bins - 1)).round().long()
        ce = F.cross_entropy(self.logits(out).flatten(0, 2), target.flatten(), reduction="none")
        return masked_mean(ce.reshape(action.shape), keep)

    def sample(self, out: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
        logits = self.logits(out)
        index = draw(logits.flatten(0, 2), self.temperature, generator).reshape(logits.shape[:-1])
        chunk = self.centres().expand(len(index), -1, -1, -1).gather(-1, index[..., None])[..., 0]
        return chunk.to(out.dtype)


def make_head(name: str, horizon: int, action_dim: int, *, components: int = 5, min_std: float = 0.01,
              low_noise: bool = True, bins: int = 64, temperature: float = 1.0, commit: bool = False,
              objective: str = "nll", wta_epsilon: float = 0.05) -> ChunkHead:
    """The head ``name`` (one of :data:`HEADS`) for ``[horizon, action_dim]`` chunks."""
    if name == "mse":
        return MSEHead(horizon, action_dim)
    if name == "gmm":
        return GMMHead(horizon, action_dim, components, min_std, low_noise, temperature, commit, objective, wta_epsilon)
    if name == "discrete":
        return DiscreteHead(horizon, action_dim, bins, temperature)
    raise ValueError(f"head must be one of {', '.join(HEADS)}, got {name!r}")
