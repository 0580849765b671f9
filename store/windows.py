"""Training windows: observation history and action horizon around a frame, padded at episode edges.

For a frame ``t`` of an episode spanning ``[s, e)``:

- observations are frames ``t - n_obs + 1 ... t``,
- actions are frames ``t + action_offset ... t + action_offset + horizon - 1``,

each index clamped into ``[s, e - 1]`` so the first/last frame repeats at the edges (Diffusion
Policy's ``pad_before`` / ``pad_after``). ``action_pad`` marks the action steps that were padded
past the episode's end, for losses that ignore them (ACT's ``is_pad``).

Everything is precomputed index arithmetic plus one fancy-indexing gather per key, so a batch
costs about as much as copying its bytes.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


@dataclass
class Batch:
    obs: dict[str, np.ndarray]  # key -> [B, n_obs, *shape]
    action: np.ndarray  # [B, horizon, action_dim]
    action_pad: np.ndarray  # [B, horizon] bool, True where the step lies past the episode end
    index: np.ndarray  # [B] frame index t in the concatenated arrays


class WindowSampler:
    """Samples windows from in-memory arrays (from :meth:`EpisodeStore.load`)."""

    def __init__(
        self,
        data: dict[str, np.ndarray],
        episode_ends: np.ndarray,
        obs_keys: Sequence[str],
        action_key: str = "action",
        n_obs: int = 1,
        horizon: int = 1,
        action_offset: int = 0,
        episodes: np.ndarray | None = None,
    ):
        if n_obs < 1 or horizon < 1:
            raise ValueError("n_obs and horizon must be >= 1")
        self.obs = {k: np.ascontiguousarray(data[k]) for k in obs_keys}
        self.action = np.ascontiguousarray(data[action_key])
        self.n_obs, self.horizon, self.action_offset = n_obs, horizon, action_offset
        ends = np.asarray(episode_ends, dtype=np.int64)
        starts = np.concatenate([[0], ends[:-1]]).astype(np.int64)
        lengths = ends - starts
        chosen = np.arange(len(ends)) if episodes is None else np.asarray(episodes)
        if chosen.dtype == bool:
            chosen = np.flatnonzero(chosen)
        # Per frame: the start and last index of its episode.
        self._start = np.repeat(starts, lengths)
        self._last = np.repeat(ends - 1, lengths)
        self.indices = (
            np.concatenate([np.arange(starts[i], ends[i]) for i in chosen]) if len(chosen) else np.zeros(0, np.int64)
        )
        self._obs_offsets = np.arange(-n_obs + 1, 1, dtype=np.int64)
        self._act_offsets = np.arange(horizon, dtype=np.int64) + action_offset

    def __len__(self) -> int:
        return len(self.indices)

    def get(self, t: np.ndarray) -> Batch:
        """Windows around the frames ``t`` (indices into the concatenated arrays)."""
        t = np.asarray(t, dtype=np.int64)
        obs_idx = np.clip(t[:, None] + self._obs_offsets, self._start[t][:, None], self._last[t][:, None])
        action, pad = self.actions(t)
        return Batch(obs={k: v[obs_idx] for k, v in self.obs.items()}, action=action, action_pad=pad, index=t)

    def actions(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The action windows ``[B, horizon, ...]`` of the frames ``t`` and their pad flags ``[B, horizon]``
        (steps past the episode end, which repeat its last action), without gathering any observation."""
        t = np.asarray(t, dtype=np.int64)
        raw_act = t[:, None] + self._act_offsets
        hi = self._last[t][:, None]
        return self.action[np.clip(raw_act, self._start[t][:, None], hi)], raw_act > hi

    def sample(self, batch_size: int, rng: np.random.Generator) -> Batch:
        return self.get(self.indices[rng.integers(0, len(self.indices), size=batch_size)])
