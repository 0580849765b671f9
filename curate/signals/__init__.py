"""Per-episode quality signals, one module per family. Every signal is a documented number with
units; each module lists its own in ``SIGNALS`` and computes them for all episodes at once from a
:class:`demo.curate.frames.FrameData` (vectorised over frames, no per-episode Python loops)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Signal:
    """What a ``score.<name>`` column means."""

    name: str
    units: str
    description: str


def episode_sum(values: np.ndarray, episode: np.ndarray, num_episodes: int) -> np.ndarray:
    """[E] float64 sum of per-frame ``values`` within each episode (``episode`` = episode of frame)."""
    return np.bincount(episode, weights=values, minlength=num_episodes)


def episode_diff(x: np.ndarray, starts: np.ndarray, order: int = 1, lag: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """``order``-th backward difference at ``lag`` frames that never crosses an episode boundary.

    Returns ``(d, valid)``: ``d[t]`` = difference ending at frame ``t`` (float32, shape of ``x``),
    and ``valid[t]`` whether frames ``t - order * lag ... t`` all lie in one episode.
    """
    d = x.astype(np.float32, copy=True)
    for _ in range(order):
        d[lag:] = d[lag:] - d[:-lag]
    n = x.shape[0]
    since_start = np.arange(n, dtype=np.int64)
    since_start -= np.repeat(starts, np.diff(np.append(starts, n)))
    return d, since_start >= order * lag
