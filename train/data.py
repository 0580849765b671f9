"""Training data: store -> split -> normalisers -> windows, shared by every algorithm.

:func:`prepare` reads top to bottom:

1. **observations**: the store's low-dim ``obs.*`` keys are concatenated per frame (:class:`ObsSpec`);
2. **split**: episodes into training and validation (a store mask ``val_mask``, or a seeded random
   ``val_fraction`` of the episodes); failed episodes are left out unless ``include_failures``;
3. **normalisers**: min-max to [-1, 1] for observations and actions, fitted on the training frames
   (actions over every step of every training window, relative to the query frame when actions
   are relative, :mod:`demo.train.relative`) and stored with the policy;
4. **windows**: :class:`Windows` over the normalised arrays gives observation histories
   ``[B, n_obs, D]`` and action chunks ``[B, chunk, A]``, padded at episode edges
   (:class:`demo.store.WindowSampler`). With cameras, an observation is a dict: the vector under
   ``"state"`` and each camera's uint8 images ``[B, n_obs, H, W, 3]`` under its key; images stay
   bytes in memory and become floats in the policy's encoder (:mod:`demo.train.visuomotor`).

Frames may carry a per-frame expert-label flag (:data:`LABEL_KEY`, written by DAgger): windows then
start at labelled frames only, and chunk steps on unlabelled frames count as padding (no loss).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import torch

from demo.errors import DemoError
from demo.store import EpisodeStore, WindowSampler
from demo.train.config import TrainConfig
from demo.train.normalizer import OBS_CLIP, MinMaxNormalizer
from demo.train.observation import ObsSpec
from demo.train.policy import PolicySpec
from demo.train.relative import RelativeActions, default_relative

LABEL_KEY = "info.labelled"  # optional per-frame flag: this frame's action is an expert label
VALIDATION_WINDOWS = 4096  # windows of the fixed validation batch
VALIDATION_WINDOWS_IMAGES = 512  # with cameras: a validation pass stays a few seconds of encoder time
MIN_TRAIN_EPISODES = 2  # below this a policy sees one trajectory: refused, not trained silently

_UNIT = MinMaxNormalizer.from_limits(np.full(1, -1.0, np.float32), np.ones(1, np.float32))  # placeholder until fitted
STATE = "state"  # the low-dim vector's entry in an observation dict (with cameras)
Observation = torch.Tensor | dict[str, torch.Tensor]  # [B, n_obs, D], or {"state": that, camera key: uint8 [B, n_obs, H, W, 3]}
Batch = tuple[Observation, torch.Tensor, torch.Tensor]  # obs, action [B, H, A], action_pad [B, H]


def batch_slice(batch: Batch, start: int, stop: int) -> Batch:
    """Windows ``start:stop`` of a batch."""
    obs, action, pad = batch
    part = {k: v[start:stop] for k, v in obs.items()} if isinstance(obs, dict) else obs[start:stop]
    return part, action[start:stop], pad[start:stop]


def batch_to(batch: Batch, device: torch.device) -> Batch:
    """The batch on ``device`` (a no-op on the CPU)."""
    if device.type == "cpu":
        return batch
    obs, action, pad = batch
    moved = {k: v.to(device, non_blocking=True) for k, v in obs.items()} if isinstance(obs, dict) else obs.to(device, non_blocking=True)
    return moved, action.to(device, non_blocking=True), pad.to(device, non_blocking=True)


@dataclass
class TrainingData:
    """A store's frames in memory with their split, normalisers and the shapes of the policy.

    Observations are normalised; actions stay raw, since their normalised form depends on the
    window's query frame when they are relative.
    """

    obs: np.ndarray  # [N, D] normalised observations (clipped to +-OBS_CLIP, as the actor does)
    action: np.ndarray  # [N, A] raw actions (the store's representation and units)
    base: np.ndarray | None  # [N, A] subtracted from the actions of windows queried at each frame; None = absolute
    ends: np.ndarray  # cumulative episode ends (every store episode)
    labelled: np.ndarray | None  # [N] bool, frames holding an expert label; None = every frame
    train_episodes: np.ndarray
    val_episodes: np.ndarray
    obs_spec: ObsSpec
    obs_norm: MinMaxNormalizer
    action_norm: MinMaxNormalizer
    relative: RelativeActions | None
    spec: PolicySpec  # obs_dim, action_dim, n_obs, horizon (= chunk), cameras
    images: dict[str, np.ndarray] = field(default_factory=dict)  # camera key -> [N, H, W, 3] uint8; none = state only

    def frames(self, episodes: np.ndarray) -> int:
        """Frames of ``episodes`` that hold an action label (all of them without label flags)."""
        starts = np.concatenate([[0], self.ends[:-1]])
        if self.labelled is None:
            return int((self.ends[episodes] - starts[episodes]).sum())
        return int(sum(self.labelled[starts[i] : self.ends[i]].sum() for i in episodes))

    def windows(self, episodes: np.ndarray) -> "Windows":
        return Windows(self, episodes)

    def validation_batch(self, seed: int) -> Batch | None:
        """The fixed validation windows (up to :data:`VALIDATION_WINDOWS`), or None without any."""
        return self.windows(self.val_episodes).fixed(VALIDATION_WINDOWS_IMAGES if self.images else VALIDATION_WINDOWS, seed)

    def reload(self, store: EpisodeStore, train_episodes: np.ndarray, val_episodes: np.ndarray) -> "TrainingData":
        """The store's frames now (it may have grown) with another split and *these* normalisers."""
        raw = _load_arrays(store, self.obs_spec, self.relative)
        return replace(self, obs=_normalized_obs(raw[0], self.obs_norm), images=raw[5], action=raw[1], base=raw[2],
                       ends=raw[3], labelled=raw[4], train_episodes=train_episodes, val_episodes=val_episodes)


def prepare(config: TrainConfig, store: EpisodeStore, among: np.ndarray | None = None,
            split: tuple[np.ndarray, np.ndarray] | None = None) -> TrainingData:
    """Steps 1-3 for a resolved ``config``: split drawn from ``among`` (default: all episodes) or given.

    Refuses (DemoError) a training split below the minimum: :data:`MIN_TRAIN_EPISODES` episodes and
    one window's worth of labelled frames, ``n_obs + chunk - 1``.
    """
    obs_spec = ObsSpec.from_features(store.meta.features, config.obs_keys or None, str(store.path))
    relative = default_relative(store.meta) if config.relative_actions else None
    train_eps, val_eps = split if split is not None else split_episodes(store, config, among)
    obs, action, base, ends, labelled, images = _load_arrays(store, obs_spec, relative)
    frames = frame_indices(ends, train_eps)
    if labelled is not None:
        frames = frames[labelled[frames]]
    window = config.n_obs + config.chunk - 1
    if len(train_eps) < MIN_TRAIN_EPISODES or len(frames) < window:
        raise DemoError(store.path, f"too little to train on: {len(train_eps)} training episode(s) with {len(frames)} "
                                    f"labelled frame(s); the minimum is {MIN_TRAIN_EPISODES} episodes and one window "
                                    f"of {window} frames (n_obs {config.n_obs} + chunk {config.chunk} - 1)")
    obs_norm = MinMaxNormalizer.fit(obs[frames])
    cameras = tuple((key, shape[0], shape[1]) for key, shape in zip(obs_spec.images, obs_spec.image_shapes))
    spec = PolicySpec(obs_spec.dim, store.meta.action.dim, config.n_obs, config.chunk, cameras)
    data = TrainingData(_normalized_obs(obs, obs_norm), action, base, ends, labelled, train_eps, val_eps, obs_spec,
                        obs_norm, _UNIT, relative, spec, images)
    data.action_norm = _fit_action_normalizer(data)  # its windows are read unnormalised
    return data


def split_episodes(store: EpisodeStore, config: TrainConfig, among: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Training and validation episode indices (disjoint, sorted), from ``among`` (default: all)."""
    candidates = store.select(config.train_mask) if config.train_mask else np.arange(store.num_episodes)
    if among is not None:
        candidates = np.intersect1d(candidates, among)
    if not config.include_failures and store.num_episodes:
        ok = store.column("success").astype(bool)
        candidates = candidates[ok[candidates]]
    if config.val_mask:
        val = np.intersect1d(store.select(config.val_mask), np.arange(store.num_episodes))
        train = np.setdiff1d(candidates, val)
    else:
        n_val = int(round(config.val_fraction * len(candidates)))
        if config.val_fraction > 0 and len(candidates) >= 4:
            n_val = max(1, n_val)
        perm = np.random.default_rng([config.seed, 0x5E1]).permutation(len(candidates))
        val = np.sort(candidates[perm[:n_val]])
        train = np.sort(candidates[perm[n_val:]])
    if len(train) == 0:
        raise DemoError(store.path, "has no episodes left to train on (check --train-mask/--val-mask/--include-failures)")
    return train, np.sort(val)


def frame_indices(ends: np.ndarray, episodes: np.ndarray) -> np.ndarray:
    """Indices of every frame of ``episodes`` (ends: cumulative episode ends)."""
    starts = np.concatenate([[0], ends[:-1]])
    return np.concatenate([np.arange(starts[i], ends[i]) for i in episodes]) if len(episodes) else np.zeros(0, np.int64)


def _load_arrays(store: EpisodeStore, obs_spec: ObsSpec, relative: RelativeActions | None):
    """Concatenated observations, actions, relative-action bases, episode ends, label flags, images."""
    keys = [*obs_spec.source_keys, *obs_spec.images, "action"] + ([LABEL_KEY] if LABEL_KEY in store.meta.features else [])
    if relative is not None and relative.obs_key not in keys:
        keys.append(relative.obs_key)
    arrays, ends = store.load(keys)
    labelled = arrays[LABEL_KEY].reshape(-1).astype(bool) if LABEL_KEY in arrays else None
    action = np.asarray(arrays["action"], dtype=np.float32)
    base = relative.base(arrays, action.shape[1]) if relative is not None else None
    images = {k: np.ascontiguousarray(arrays[k], dtype=np.uint8) for k in obs_spec.images}
    return obs_spec.concat(arrays), action, base, ends, labelled, images


def _normalized_obs(obs: np.ndarray, norm: MinMaxNormalizer) -> np.ndarray:
    return np.clip(norm.normalize(obs), -OBS_CLIP, OBS_CLIP)  # as the actor does in rollouts


def _fit_action_normalizer(data: TrainingData) -> MinMaxNormalizer:
    """Min-max over every action of every training window (chunk steps included), in blocks."""
    windows = Windows(data, data.train_episodes, normalize=False)
    lo = np.full(data.action.shape[1], np.inf, np.float32)
    hi = np.full(data.action.shape[1], -np.inf, np.float32)
    idx = windows.sampler.indices
    for i in range(0, len(idx), 65536):
        block = windows.actions(idx[i : i + 65536]).reshape(-1, data.action.shape[1])
        lo, hi = np.minimum(lo, block.min(axis=0)), np.maximum(hi, block.max(axis=0))
    return MinMaxNormalizer.from_limits(lo, hi)


class Windows:
    """Training windows of some episodes as tensors: the WindowSampler on in-memory arrays, then
    actions made relative to the query frame (if so) and normalised, a few array operations per batch."""

    def __init__(self, data: TrainingData, episodes: np.ndarray, normalize: bool = True):
        partial = data.labelled is not None and not data.labelled.all()
        # The label flag rides along as an extra action column, so one gather serves both.
        action = np.concatenate([data.action, data.labelled[:, None].astype(np.float32)], axis=1) if partial else data.action
        self.cameras = list(data.images)
        self.sampler = WindowSampler({"obs": data.obs, **data.images, "action": action}, data.ends, ["obs", *self.cameras],
                                     "action", data.spec.n_obs, data.spec.horizon, episodes=episodes)
        if data.labelled is not None:
            self.sampler.indices = self.sampler.indices[data.labelled[self.sampler.indices]]
        self.partial = partial
        self.base = data.base
        self.norm = data.action_norm if normalize else None

    def __len__(self) -> int:
        return len(self.sampler)

    def _window(self, t: np.ndarray) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray]:
        b = self.sampler.get(t)
        action, pad = b.action, b.action_pad
        if self.partial:
            action, pad = action[..., :-1], pad | (action[..., -1] < 0.5)
        if self.base is not None:
            action = action - self.base[b.index][:, None, :]
        return b.obs, action, pad

    def actions(self, t: np.ndarray) -> np.ndarray:
        """``[B, H, A]`` raw actions of the windows at ``t``, relative to their query frame if so."""
        return self._window(t)[1]

    def get(self, t: np.ndarray) -> Batch:
        frames, action, pad = self._window(t)
        action = self.norm.normalize(action) if self.norm is not None else action
        obs: Observation = torch.from_numpy(frames["obs"])
        if self.cameras:
            obs = {STATE: obs, **{k: torch.from_numpy(frames[k]) for k in self.cameras}}
        return obs, torch.from_numpy(np.ascontiguousarray(action)), torch.from_numpy(pad)

    def sample(self, batch_size: int, rng: np.random.Generator) -> Batch:
        return self.get(self.sampler.indices[rng.integers(0, len(self.sampler.indices), size=batch_size)])

    def fixed(self, n: int, seed: int) -> Batch | None:
        """Up to ``n`` windows chosen once (validation), or None when there are none."""
        if len(self.sampler) == 0:
            return None
        idx = self.sampler.indices
        if len(idx) > n:
            idx = np.sort(np.random.default_rng(seed).choice(idx, size=n, replace=False))
        return self.get(idx)
