"""Episode seeds: which ``env.reset`` seed each process starts its episodes from.

Every stream derives 32-bit seeds from a run seed ``S`` and an episode index ``i`` with
:func:`episode_seed` (numpy ``SeedSequence([S, i])``), so runs with different ``S`` do not share
initial states. Processes other than collection shift ``S`` by their own offset first, so their
initial states are drawn from a different stream than the demonstrations':

=============================  ==========================================================
``demo collect --seed S``      ``episode_seed(S, i)`` (avoid: ``episode_seed(S, i // 2)``,
                               pairs share a start state; :func:`demo.collect.scripted.start_seed`)
``demo eval --seed S``         ``episode_seed(S + 10_000_000, i)``
DAgger rollouts, round ``r``   ``episode_seed(S + 20_000_000, r * 100_000 + i)``
periodic eval in training      ``episode_seed(S + 30_000_000, i)``
RL episodes (PPO and IRL)      ``episode_seed(S + 40_000_000, i)``
=============================  ==========================================================

Streams could still collide by chance on a 32-bit seed (~1e-7 per pair of 1,000-episode sets), so
``demo eval`` also checks its seeds against the seeds recorded with the run's training data and
reports the overlap (0 in every run we have made).
"""

from __future__ import annotations

import numpy as np

EVAL_OFFSET = 10_000_000
DAGGER_OFFSET = 20_000_000
MONITOR_OFFSET = 30_000_000
RL_OFFSET = 40_000_000
DAGGER_ROUND_STRIDE = 100_000  # episode indices per DAgger round: rounds never share an index


def episode_seed(seed: int, index: int) -> int:
    """The ``env.reset`` seed of episode ``index`` of a run seeded ``seed`` (a 32-bit integer)."""
    return int(np.random.SeedSequence([seed, index]).generate_state(1)[0])


def eval_seeds(seed: int, n: int, offset: int = EVAL_OFFSET, first: int = 0) -> list[int]:
    """Reset seeds of episodes ``first .. first + n - 1`` of an evaluation seeded ``seed``
    (``offset``: ``EVAL_OFFSET`` for ``demo eval``, ``MONITOR_OFFSET`` for evaluation during training)."""
    return [episode_seed(seed + offset, i) for i in range(first, first + n)]


def dagger_seeds(seed: int, round_index: int, n: int) -> list[int]:
    """Reset seeds of the ``n`` rollouts of DAgger round ``round_index`` of a run seeded ``seed``."""
    return [episode_seed(seed + DAGGER_OFFSET, round_index * DAGGER_ROUND_STRIDE + i) for i in range(n)]
