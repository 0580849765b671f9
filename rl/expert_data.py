"""Demonstrations as the transitions inverse RL learns from: ``(s, a, s')`` in the RL policy's units.

A store (``demo collect``, ``demo convert``) holds per frame the observations *before* the action
of that step, so an episode of ``L`` frames gives ``L - 1`` transitions ``(s_t, a_t, s_{t+1})``
(the state after the last action is not recorded). Only successful episodes are used.

- ``obs`` / ``next_obs``: the raw observation vectors of the RL policy (:class:`ObsSpec`);
- ``actions``: the stored actions in the policy's normalised units (the same bounds as the policy's
  actions, :func:`demo.rl.ppo.action_bounds`; relative to the measured joints for ``joint_pos``),
  clipped to [-1, 1] as an executed policy action is;
- ``features``: the task reward's features (:mod:`demo.rl.rewards`) of ``s_{t+1}``;
- ``episode``: which episode each transition belongs to (0-based among those used);
- ``frames`` / ``next_frames``: every low-dim ``obs.*`` key of ``s_t`` and ``s_{t+1}``, for a
  model that reads another observation vector than the policy (a discriminator, a reward);
- ``weights``: each transition's share of the expert's state occupancy over the task's horizon. A
  demonstration ends once success has held 0.5 s, settled (reach: ~27 of 100 steps), while an RL
  episode runs the whole horizon: the expert would have stayed, so an episode's last transition
  stands for the ``horizon - L + 2`` steps it would have held (weight), every other one for 1.
  Without it, the approach makes up two thirds of the demonstrations' occupancy, and a policy that
  hovers 20 cm from the goal matches it better than one that gets there (measured: GAIL on reach).

The store must hold the task and the action representation the policy acts in; a store of
``joint_pos`` demonstrations for an ``ee7`` policy is refused with the conversion to run.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from demo.errors import DemoError
from demo.policies.normalizer import MinMaxNormalizer
from demo.policies.observation import ObsSpec
from demo.policies.relative import RelativeActions
from demo.rl.rewards import TaskReward
from demo.store import ActionSpec, EpisodeStore


@dataclass
class ExpertData:
    obs: np.ndarray  # [M, D]
    actions: np.ndarray  # [M, A] normalised, clipped
    next_obs: np.ndarray  # [M, D]
    features: np.ndarray  # [M, F] of next_obs's states
    episode: np.ndarray  # [M] episode of each transition (0-based among those used)
    frames: dict[str, np.ndarray]  # every low-dim obs.* key of s_t, [M, ...]
    next_frames: dict[str, np.ndarray]  # ... and of s_{t+1}
    weights: np.ndarray  # [M] share of the occupancy over the horizon (module docstring)
    seeds: list[int]  # the episodes' reset seeds (demo eval checks its own against them)
    frame_count: int  # frames of the episodes used (every one an expert label)

    @property
    def episodes(self) -> int:
        return int(self.episode.max()) + 1 if len(self.episode) else 0

    def record(self, path: str) -> dict[str, Any]:
        """What a run's ``data`` section says of the demonstrations."""
        return {"path": path, "episodes": self.episodes, "transitions": int(len(self.obs)),
                "expert_labels": self.frame_count, "seeds": self.seeds}


def demonstrations(store: EpisodeStore, path: str, task: str, obs_spec: ObsSpec, action: ActionSpec,
                   demos: int | None = None) -> np.ndarray:
    """The indices of the first ``demos`` (default all) successful episodes of ``store``, refusing a store of
    another task, action representation or observations in one line."""
    meta = store.meta
    have = (meta.task or {}).get("name")
    if have != task:
        raise DemoError(path, f"holds {have!r} demonstrations, not {task!r}")
    if meta.action.name != action.name or meta.action.dim != action.dim:
        hint = f" (demo convert {path} --to {action.name} --out ...)" if action.name != "joint_pos" else ""
        raise DemoError(path, f"holds {meta.action.name} actions ({meta.action.dim}); the policy acts in "
                              f"{action.name} ({action.dim}){hint}")
    obs_spec.check_against(meta.features, str(path))
    chosen = np.flatnonzero(store.column("success").astype(bool))
    if demos is not None:
        if demos < 1 or demos > len(chosen):
            raise DemoError("--demos", f"{path} has {len(chosen)} successful episodes; asked for {demos}")
        chosen = chosen[:demos]
    if len(chosen) == 0:
        raise DemoError(path, "has no successful episodes to learn from")
    return chosen


def load_expert(path: str, task: str, options: dict[str, Any], obs_spec: ObsSpec, action: ActionSpec,
                action_norm: MinMaxNormalizer, relative: RelativeActions | None, reward: TaskReward,
                demos: int | None = None, horizon: int | None = None) -> ExpertData:
    """The first ``demos`` (default all) successful episodes of the store at ``path`` as transitions;
    ``horizon``: the RL episodes' length, which weights each episode's last transition (default: no padding)."""
    with EpisodeStore.open(path) as store:
        meta = store.meta
        chosen = demonstrations(store, path, task, obs_spec, action, demos)
        keys = [*obs_spec.source_keys, *(k for k in _reward_keys(meta.features) if k not in obs_spec.source_keys)]
        if relative is not None and relative.obs_key not in keys:
            keys.append(relative.obs_key)
        parts: dict[str, list[np.ndarray]] = {k: [] for k in ("obs", "actions", "next_obs", "features", "episode",
                                                               "weights")}
        frames: list[dict[str, np.ndarray]] = []
        next_frames: list[dict[str, np.ndarray]] = []
        labels = 0
        seeds = store.column("seed")
        for j, index in enumerate(chosen):
            data = store.read_episode(int(index), [*keys, "action"])
            n = len(data["action"])
            labels += n
            if n < 2:
                continue
            vec = obs_spec.concat(data)
            act = np.asarray(data["action"], np.float32)
            if relative is not None:
                act = act - relative.base(data, act.shape[1])
            after = {k: data[k][1:] for k in keys}
            parts["obs"].append(vec[:-1])
            parts["next_obs"].append(vec[1:])
            parts["actions"].append(np.clip(action_norm.normalize(act[:-1]), -1.0, 1.0))
            parts["features"].append(reward.features(after, None, options))
            parts["episode"].append(np.full(n - 1, j))
            parts["weights"].append(np.r_[np.ones(n - 2), max(1, (horizon or 0) - n + 2)])
            frames.append({k: data[k][:-1] for k in keys})
            next_frames.append(after)
    if not parts["obs"]:
        raise DemoError(path, "its episodes are too short to hold a transition")
    out = {k: np.concatenate(v) for k, v in parts.items()}
    return ExpertData(**out, frames=_concat(frames), next_frames=_concat(next_frames),
                      seeds=[int(seeds[i]) for i in chosen if int(seeds[i]) >= 0], frame_count=labels)


def _concat(frames: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    return {k: np.concatenate([f[k] for f in frames]) for k in frames[0]}


def _reward_keys(features: dict[str, Any]) -> list[str]:
    """The observation keys the task features read (every ``obs.*`` state key the store has)."""
    return [k for k in features if k.startswith("obs.") and not k.startswith("obs.image_")]
