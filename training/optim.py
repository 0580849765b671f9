"""Optimisation of one policy: AdamW, warm-up + cosine learning rate, gradient clipping, EMA.

A :class:`Learner` is the policy being trained and everything its optimisation needs; one
:func:`train_step` is forward, the policy's own loss (:meth:`Policy.loss`), backward and an
optimiser step. The learning-rate schedule runs over a *phase* (``phase_start`` .. ``phase_start +
phase_steps``): one phase per run for BC, one per round for DAgger's learners.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import torch

from demo.training.config import TrainConfig
from demo.training.data import STATE, Batch, Observation, batch_slice, batch_to
from demo.policies.device import autocast
from demo.policies.policy import Policy


class EMA:
    """Exponential moving average of a model's floating-point weights, with the usual warm-up
    (decay ``min(decay, (1 + step) / (10 + step))``) so early averages are not dominated by init."""

    def __init__(self, model: torch.nn.Module, decay: float):
        self.decay = decay
        self.shadow = {k: v.detach().clone() for k, v in model.state_dict().items()}

    @torch.no_grad()
    def update(self, model: torch.nn.Module, step: int) -> None:
        d = min(self.decay, (1 + step) / (10 + step))
        for k, v in model.state_dict().items():
            if v.dtype.is_floating_point:
                self.shadow[k].lerp_(v, 1.0 - d)
            else:
                self.shadow[k].copy_(v)


@dataclass
class Learner:
    """The policy being trained and everything its optimisation needs."""

    policy: Policy
    optimizer: torch.optim.Optimizer
    config: TrainConfig
    ema: EMA | None = None
    step: int = 0
    phase_start: int = 0  # the LR schedule restarts at phase_start (DAgger rounds)
    phase_steps: int = 1
    device: torch.device = torch.device("cpu")
    # The policy's loss under DistributedDataParallel in a data-parallel run (demo.training.distributed.wrap)
    loss_module: torch.nn.Module | None = None
    _eval_copy: Policy | None = None

    def lr_at(self, step: int) -> float:
        """Linear warm-up to ``lr``, then cosine decay to ``min_lr_ratio * lr`` at the phase's end."""
        c = self.config
        s = step - self.phase_start
        warmup = min(c.warmup_steps, max(1, self.phase_steps // 10)) if c.warmup_steps else 0
        if s < warmup:
            return c.lr * (s + 1) / warmup
        progress = min(1.0, (s - warmup) / max(1, self.phase_steps - warmup))
        return c.lr * (c.min_lr_ratio + (1 - c.min_lr_ratio) * 0.5 * (1 + math.cos(math.pi * progress)))

    def eval_weights(self) -> dict[str, torch.Tensor]:
        return self.ema.shadow if self.ema is not None else self.policy.state_dict()

    def eval_policy(self) -> Policy:
        """The weights evaluation uses (EMA when on), in eval mode."""
        if self.ema is None:
            return self.policy.eval()
        if self._eval_copy is None:
            self._eval_copy = copy.deepcopy(self.policy)
        self._eval_copy.load_state_dict(self.ema.shadow)
        return self._eval_copy.eval()


def make_learner(policy: Policy, config: TrainConfig, step: int = 0, phase_steps: int | None = None,
                 device: torch.device | None = None) -> Learner:
    """A fresh optimiser (and EMA) for ``policy`` on ``device`` (default CPU), its schedule's phase starting at ``step``."""
    device = device or torch.device("cpu")
    policy.to(device)
    decay, no_decay = [], []
    for p in policy.parameters():
        if p.requires_grad:  # a frozen part (a pretrained text encoder) is not optimised
            (no_decay if p.ndim < 2 else decay).append(p)  # no weight decay on biases and norms
    groups = [{"params": decay, "weight_decay": config.weight_decay}, {"params": no_decay, "weight_decay": 0.0}]
    try:
        # The fused CPU kernel is ~10x faster than the default per-tensor loop (1 ms vs 13 ms per step
        # for a 512x3 MLP): without it the optimiser step costs half as much as forward + backward.
        optimizer = torch.optim.AdamW(groups, lr=config.lr, fused=True)
    except (RuntimeError, TypeError):
        optimizer = torch.optim.AdamW(groups, lr=config.lr, foreach=True)
    ema = EMA(policy, config.ema) if config.ema > 0 else None
    return Learner(policy, optimizer, config, ema, step=step, phase_start=step,
                   phase_steps=config.steps if phase_steps is None else phase_steps, device=device)


def add_obs_noise(obs: Observation, std: float) -> Observation:
    """Gaussian noise on the normalised low-dim vector (images are augmented by their encoders' crops)."""
    if isinstance(obs, dict):
        return {**obs, STATE: obs[STATE] + std * torch.randn_like(obs[STATE])}
    return obs + std * torch.randn_like(obs)


def train_step(learner: Learner, obs: Observation, action: torch.Tensor, pad: torch.Tensor) -> torch.Tensor:
    """One optimiser step on a batch (moved to the learner's device); returns the (detached) loss."""
    c = learner.config
    policy = learner.policy.train()
    lr = learner.lr_at(learner.step)
    for group in learner.optimizer.param_groups:
        group["lr"] = lr
    obs, action, pad = batch_to((obs, action, pad), learner.device)
    if c.obs_noise > 0:
        obs = add_obs_noise(obs, c.obs_noise)
    with autocast(learner.device):
        # Through DDP when data-parallel: its backward averages the gradients over the ranks.
        loss = policy.loss(obs, action, pad) if learner.loss_module is None else learner.loss_module(obs, action, pad)
    learner.optimizer.zero_grad(set_to_none=True)
    loss.backward()
    if c.grad_clip > 0:
        torch.nn.utils.clip_grad_norm_(policy.parameters(), c.grad_clip)
    learner.optimizer.step()
    if learner.ema is not None:
        learner.ema.update(policy, learner.step - learner.phase_start)
    learner.step += 1
    return loss.detach()


@torch.no_grad()
def validation_loss(learner: Learner, batch: Batch | None) -> float | None:
    """Mean loss of the evaluation weights on ``batch`` (None without one)."""
    if batch is None:
        return None
    policy = learner.eval_policy()
    n = len(batch[1])
    # A stochastic loss (diffusion) stays comparable across steps and leaves the training RNG alone.
    with torch.random.fork_rng(devices=[learner.device] if learner.device.type == "cuda" else []), autocast(learner.device):
        torch.manual_seed(0)
        total = 0.0
        for i in range(0, n, 1024):
            total += policy.loss(*batch_to(batch_slice(batch, i, i + 1024), learner.device)).item() * min(1024, n - i)
    return float(total / n)
