"""Chunks that continue a committed prefix: a policy made for asynchronous execution under inference delay.

A robot-side client (:mod:`demo.deploy.controller`) keeps executing while the next chunk is computed, so
a chunk asked for from the observation of step ``s`` arrives ``d`` control steps later, when the actions
for steps ``s .. s + d - 1`` have already been sent (they come from the chunks before). An ordinary
chunk predicts those steps anew, and what it predicts after them assumes its own start, not the one the
robot took: the later the answer, the larger the seam (``demo bench delay`` on ``pick`` from state, training
seeds 0 / 1, 100 episodes each: 88 / 86 at an 8-step delay, against 96 / 94 for the same policy trained
with ``--prefix-steps 8``; 99 / 98 without delay, 98 / 98).

:class:`CommittedPrefixPolicy` wraps any registered policy and tells it the committed actions, in the
spirit of training-time action conditioning for real-time chunking (Black et al. 2025): the wrapped
policy's low-dim vector gets, in every frame, the first ``P = spec.prefix`` actions of the chunk
(normalised, in the policy's own action representation) and one 0/1 flag per step saying which of them
are given. In training each window draws ``d`` uniformly from ``0 .. P``; the steps past ``d`` are
zeroed and flagged absent, and the loss skips the ``d`` given steps (marked as padding, which BC's
and ACT's losses ignore). At execution ``d = 0`` (no prefix) is the ordinary policy; a client that
sends the actions it has committed to (:meth:`demo.policies.actor.PolicyActor.chunk`'s ``prefix``) gets a
chunk whose first ``d`` steps are those actions and whose rest continues from them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from demo.policies.observation import STATE
from demo.policies.policy import Policy, PolicySpec

PREFIX = "prefix"  # the committed actions' entry in an observation dict: [B, P, A] normalised, zero past d
PREFIX_STEPS = "prefix_steps"  # ... and how many of them are given: [B] int (d)


class CommittedPrefixPolicy(Policy):
    """A wrapped policy whose observation carries the committed first ``spec.prefix`` actions (module docstring)."""

    def __init__(self, spec: PolicySpec, config: Any, build: Callable[[PolicySpec], Policy]):
        super().__init__(spec, config)
        if not 1 <= spec.prefix < spec.horizon:
            raise ValueError(f"a committed prefix needs 1 <= prefix < chunk ({spec.horizon}), got {spec.prefix}")
        self.inner = build(dataclasses.replace(spec, prefix=0, obs_dim=spec.obs_dim + spec.prefix * (spec.action_dim + 1)))
        self.name = self.inner.name

    def with_prefix(self, obs: torch.Tensor | dict[str, torch.Tensor], prefix: torch.Tensor, steps: torch.Tensor
                    ) -> torch.Tensor | dict[str, torch.Tensor]:
        """``obs`` with ``prefix [B, P, A]`` (its first ``steps [B]`` rows given) appended to every frame's vector."""
        state = obs[STATE] if isinstance(obs, dict) else obs
        given = torch.arange(self.spec.prefix, device=state.device)[None] < steps[:, None]  # [B, P]
        extra = torch.cat([(prefix * given[..., None]).flatten(1), given.to(state.dtype)], dim=1)
        state = torch.cat([state, extra[:, None].expand(-1, state.shape[1], -1).to(state.dtype)], dim=-1)
        if not isinstance(obs, dict):
            return state
        rest = {k: v for k, v in obs.items() if k not in (STATE, PREFIX, PREFIX_STEPS)}
        return {STATE: state, **rest} if rest else state

    def loss(self, obs: torch.Tensor | dict[str, torch.Tensor], action: torch.Tensor, action_pad: torch.Tensor
             ) -> torch.Tensor:
        batch = action.shape[0]
        steps = torch.randint(0, self.spec.prefix + 1, (batch,), device=action.device)
        committed = torch.arange(action.shape[1], device=action.device)[None] < steps[:, None]  # [B, H]
        return self.inner.loss(self.with_prefix(obs, action[:, : self.spec.prefix], steps), action,
                               action_pad | committed)

    def fit_actions(self, low: np.ndarray, high: np.ndarray) -> None:
        self.inner.fit_actions(low, high)

    @torch.no_grad()
    def predict(self, obs: torch.Tensor | dict[str, torch.Tensor], generator: torch.Generator | None = None
                ) -> torch.Tensor:
        """The chunk for ``obs``; without :data:`PREFIX` in it, for no committed action (``d = 0``)."""
        state = obs[STATE] if isinstance(obs, dict) else obs
        batch, width = state.shape[0], self.spec.action_dim
        prefix = obs.get(PREFIX) if isinstance(obs, dict) else None
        if prefix is None:
            prefix = state.new_zeros(batch, self.spec.prefix, width)
            steps = torch.zeros(batch, dtype=torch.long, device=state.device)
        else:
            steps = obs[PREFIX_STEPS]
        return self.inner.predict(self.with_prefix(obs, prefix.to(state.dtype), steps), generator=generator)


def unwrapped(policy: Policy) -> Policy:
    """The policy a :class:`CommittedPrefixPolicy` wraps (any other: itself)."""
    return policy.inner if isinstance(policy, CommittedPrefixPolicy) else policy
