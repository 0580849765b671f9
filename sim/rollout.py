"""Run a task's expert for one episode (tests, benchmarks, success-rate checks).

The collector (demo.collect) has its own loop that records frames; this one only judges.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from demo.sim.env import Env


@dataclass
class Rollout:
    seed: int
    success: bool  # success reached at some step
    first_success: int | None  # control step at which it was first reached
    steps: int  # control steps run
    final_success: bool  # success at the last step
    modes: list[str | None] = field(default_factory=list)  # expert.mode per step


def run_expert(
    env: Env,
    seed: int,
    rng: np.random.Generator | None = None,
    after_success: int = 5,
    max_steps: int | None = None,
    perturb: Callable[[Env, int], None] | None = None,
    **style: Any,
) -> Rollout:
    """Reset to ``seed``, act with ``env.expert(rng, **style)`` until ``after_success`` steps past
    the first success or the horizon. ``perturb(env, t)`` runs before each step's action."""
    env.reset(seed)
    expert = env.expert(rng, **style)
    first: int | None = None
    steps = 0
    modes: list[str | None] = []
    ok = False
    limit = env.horizon if max_steps is None else max_steps
    for t in range(limit):
        if perturb is not None:
            perturb(env, t)
        _, _, ok, truncated, _ = env.step(expert.act(env))
        modes.append(expert.mode)
        steps += 1
        if ok and first is None:
            first = t
        if (first is not None and t >= first + after_success) or truncated:
            break
    return Rollout(seed, first is not None, first, steps, bool(ok), modes)
