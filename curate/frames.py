"""The arrays every curation signal reads, loaded once: actions and low-dimensional observations.

Signals never touch images: a store with camera features is curated from its actions and its
low-dimensional ``obs.*`` keys (joint positions, gripper, object poses, ...), so image datasets and
imported datasets are handled the same way as scripted ones.

Normalisation is per dimension by its *typical range* (:meth:`FrameData.typical_range`): how far
the dimension moves within a typical episode (the median over episodes of its max - min), so "1.0"
means "as far as a demonstration usually moves it". A median over episodes is not inflated by a
minority of wild episodes (a poor operator flailing over the whole joint range), which a range over
all frames would be. Dimensions that stay constant within episodes but vary between them (a goal,
an object's initial pose) use the 1st-99th percentile spread over all frames instead; dimensions
that never move get scale ``inf`` and drop out of every distance.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from demo.errors import DemoError
from demo.store import EpisodeStore

# Representations whose action is a rate or a per-step delta (not an absolute target): the
# trajectory they command is the running sum of the action.
DELTA_ACTIONS = frozenset({"joint_vel", "ee_delta", "ee7", "delta", "ee_vel"})
GRIPPER_WORDS = ("grip", "finger", "claw", "hand")
MAX_LOWDIM = 256  # per-frame elements; anything larger is treated as an image-like feature
SCALE_ROWS = 100_000  # frames used to estimate the robust ranges


@dataclass
class FrameData:
    """All frames of a store, concatenated in episode order (as in the store)."""

    action: np.ndarray  # [N, A] float32, the store's action representation
    obs: np.ndarray  # [N, D] float32, concatenated low-dim obs.* keys (D may be 0)
    obs_keys: list[str]
    ends: np.ndarray  # [E] int64 cumulative episode ends
    fps: float  # frames per second
    action_names: tuple[str, ...]
    action_is_delta: bool  # True for rate/delta representations (see DELTA_ACTIONS)
    gripper_dims: np.ndarray  # [A] bool, gripper-like action dims (excluded from jerk)
    _ranges: dict[str, np.ndarray] = field(default_factory=dict, repr=False)

    @property
    def obs_range(self) -> np.ndarray:
        """[D] typical range of each observation dim (computed once)."""
        if "obs" not in self._ranges:
            self._ranges["obs"] = self.typical_range(self.obs)
        return self._ranges["obs"]

    @property
    def action_range(self) -> np.ndarray:
        """[A] typical range of each action dim (computed once)."""
        if "action" not in self._ranges:
            self._ranges["action"] = self.typical_range(self.action)
        return self._ranges["action"]

    def typical_range(self, x: np.ndarray) -> np.ndarray:
        """[D] float32 per-dim median over episodes of (max - min) within the episode, for any
        per-frame array ``x`` [N, D] in store order; the all-frames 1st-99th percentile spread
        where that median is 0 (constant within episodes); ``inf`` where neither moves."""
        if x.shape[1] == 0:
            return np.zeros(0, np.float32)
        starts = self.starts
        spans = np.maximum.reduceat(x, starts, axis=0) - np.minimum.reduceat(x, starts, axis=0)  # [E, D]
        typical = np.median(spans, axis=0).astype(np.float32)
        between = robust_range(x)
        return np.where(typical > 1e-9, typical, between).astype(np.float32)

    @property
    def num_frames(self) -> int:
        return int(self.action.shape[0])

    @property
    def num_episodes(self) -> int:
        return int(self.ends.shape[0])

    @property
    def starts(self) -> np.ndarray:
        return np.concatenate([[0], self.ends[:-1]]).astype(np.int64)

    @property
    def lengths(self) -> np.ndarray:
        return self.ends - self.starts

    def episode_of_frame(self) -> np.ndarray:
        """[N] int64 episode index of every frame."""
        return np.repeat(np.arange(self.num_episodes, dtype=np.int64), self.lengths)

    def trajectory(self) -> np.ndarray:
        """[N, A] the commanded trajectory: the action itself, or its running sum per episode for
        delta/rate representations (so that derivatives mean the same thing for both)."""
        if not self.action_is_delta:
            return self.action
        out = np.cumsum(self.action, axis=0, dtype=np.float64)
        # Restart the sum at every episode: subtract the running total reached before its start.
        before = np.zeros((self.num_episodes, out.shape[1]))
        before[1:] = out[self.starts[1:] - 1]
        out -= np.repeat(before, self.lengths, axis=0)
        return out.astype(np.float32)


def lowdim_obs_keys(store: EpisodeStore) -> list[str]:
    """``obs.*`` keys that are small numeric vectors (images and other large arrays left out)."""
    keys = []
    for key, spec in store.meta.features.items():
        if not key.startswith("obs."):
            continue
        size = int(np.prod(spec.shape, dtype=np.int64)) if spec.shape else 1
        if spec.np_dtype.kind in "fiub" and size <= MAX_LOWDIM and len(spec.shape) <= 1 and spec.np_dtype != np.uint8:
            keys.append(key)
    return keys


def gripper_dims(names: tuple[str, ...], action: np.ndarray) -> np.ndarray:
    """Action dims that are gripper commands: named so, or taking at most two values (open/close)."""
    dims = np.array([any(w in n.lower() for w in GRIPPER_WORDS) for n in names], dtype=bool)
    if action.shape[0]:
        sample = action[:: max(1, action.shape[0] // SCALE_ROWS)]
        for j in range(action.shape[1]):
            if not dims[j] and np.unique(sample[:, j]).size <= 2 and np.ptp(sample[:, j]) > 0:
                dims[j] = True
    return dims


def load_frames(store: EpisodeStore) -> FrameData:
    """Read ``action`` and the low-dim ``obs.*`` keys of every episode into memory."""
    if store.num_episodes == 0:
        raise DemoError(store.path, "has no episodes to curate")
    keys = lowdim_obs_keys(store)
    data, ends = store.load(["action", *keys])
    n = int(ends[-1])
    action = np.ascontiguousarray(data["action"], dtype=np.float32).reshape(n, -1)
    parts = [np.asarray(data[k], dtype=np.float32).reshape(n, -1) for k in keys]
    obs = np.concatenate(parts, axis=1) if parts else np.zeros((n, 0), np.float32)
    spec = store.meta.action
    names = tuple(spec.names) if len(spec.names) == action.shape[1] else tuple(f"a{i}" for i in range(action.shape[1]))
    is_delta = spec.name in DELTA_ACTIONS or bool(spec.params.get("delta", False))
    return FrameData(
        action=action,
        obs=np.ascontiguousarray(obs),
        obs_keys=keys,
        ends=np.asarray(ends, dtype=np.int64),
        fps=float(store.meta.fps),
        action_names=names,
        action_is_delta=is_delta,
        gripper_dims=gripper_dims(names, action),
    )


def robust_range(x: np.ndarray, lo: float = 1.0, hi: float = 99.0) -> np.ndarray:
    """[D] per-dimension ``p_hi - p_lo`` over (a strided sample of) the rows of ``x``; ``inf``
    where a dimension does not move, so dividing by it zeroes that dimension."""
    if x.shape[0] == 0 or x.shape[1] == 0:
        return np.full(x.shape[1], np.inf, dtype=np.float32)
    sample = x[:: max(1, x.shape[0] // SCALE_ROWS)]
    p = np.percentile(sample, [lo, hi], axis=0)
    spread = (p[1] - p[0]).astype(np.float32)
    full = np.ptp(sample, axis=0).astype(np.float32)
    # A dimension that is constant except for rare values (a gripper closed 1% of the time) still
    # moves: fall back to its full range rather than calling it constant.
    spread = np.where(spread > 0, spread, full)
    return np.where(spread > 1e-9, spread, np.inf).astype(np.float32)
