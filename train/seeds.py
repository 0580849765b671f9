"""Episode seeds of training-time processes, disjoint from the seeds demonstrations are collected with.

``demo collect --seed S`` starts episode ``i`` from ``episode_seed(S, i)`` (avoid: ``episode_seed(S, i // 2)``, pairs share a start state)
(:func:`demo.collect.scripted.episode_seed`, numpy ``SeedSequence([S, i])``). Every other process
that starts episodes shifts the run seed by its own offset before deriving episode seeds, so its
initial states are drawn from a different stream:

=============================  ===========================================
``demo eval --seed S``         ``episode_seed(S + 10_000_000, i)``
DAgger rollouts, round ``r``   ``episode_seed(S + 20_000_000, r * 100_000 + i)``
periodic eval in training      ``episode_seed(S + 30_000_000, i)``
=============================  ===========================================

Streams could still collide by chance on a 32-bit seed (~1e-7 per pair of 1,000-episode sets), so
``demo eval`` also checks its seeds against the seeds recorded with the run's training data and
reports the overlap (0 in every run we have made).
"""

from __future__ import annotations

from demo.collect.scripted import episode_seed

EVAL_OFFSET = 10_000_000
DAGGER_OFFSET = 20_000_000
MONITOR_OFFSET = 30_000_000


def eval_seeds(seed: int, n: int, offset: int = EVAL_OFFSET, first: int = 0) -> list[int]:
    return [episode_seed(seed + offset, i) for i in range(first, first + n)]


def dagger_seeds(seed: int, round_index: int, n: int) -> list[int]:
    return [episode_seed(seed + DAGGER_OFFSET, round_index * 100_000 + i) for i in range(n)]
