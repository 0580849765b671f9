"""A store's episodes as trajectories for trajectory libraries (the ``imitation`` library's ``Trajectory``,
d3rlpy, Minari): observations as a :class:`demo.gym.env.DemoEnv` gives them, *including the final one*.

A store keeps, for each of an episode's T frames, the observation an action was taken in, so its
observation after the last action is not stored. It is reconstructible: every frame also records the
simulator's state (``sim.state``), so the final observation is one physics step of the last action from
the last frame's state, in an env like the one that collected it. That is checked: the episode's reset
seed must give its recorded first frame in the env given, bit for bit, or the env is not the one the
store was collected in (another robot, task option or camera) and nothing is returned.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from demo.errors import DemoError
from demo.store import EpisodeStore


@dataclass(frozen=True)
class Trajectory:
    """One episode: ``obs[key]`` [T + 1, ...] keyed and shaped as ``env.reset`` / ``env.step`` return them
    (the last one after the last action), ``actions`` [T, A] as ``env.step`` takes them, ``terminal``: it ended by the task's
    own end (success held, or a failure), not by reaching the horizon; ``seed`` its reset seed."""

    obs: dict[str, np.ndarray]
    actions: np.ndarray
    terminal: bool
    seed: int


def trajectories(store: EpisodeStore, env: Any, episodes: Sequence[int] | None = None) -> Iterator[Trajectory]:
    """The episodes of ``store`` (all, or ``episodes``) as :class:`Trajectory` s in the Gymnasium env ``env``
    (``gymnasium.make("demo/<Task>-v0", ...)`` or its ``unwrapped``): its observation keys and layout, its
    action space (``normalize_actions`` included). The store's action representation must be the env's,
    and absolute (``joint_pos``, ``ee_abs``): the last action is executed from the last frame's state,
    where a delta action would need the command executed before it."""
    env = getattr(env, "unwrapped", env)
    meta = store.meta
    fmt = env.codec.fmt
    if fmt.rep.delta or meta.action.name != fmt.name or meta.action.dim != env.action_space.shape[0]:
        raise DemoError(store.path, f"its {meta.action.name} actions are not this env's absolute {fmt.name} action "
                                    "(make the env with action=the store's, which must be joint_pos or ee_abs)")
    if "sim.state" not in meta.features:
        raise DemoError(store.path, "records no simulator states (sim.state), from which final observations are "
                                    "reconstructed (a store imported from another format)")
    task = (meta.task or {}).get("name")
    if task != env.sim.task_name:
        raise DemoError(store.path, f"holds {task!r} episodes, not {env.sim.task_name!r}")
    missing = [k for k in env.obs_keys if k not in meta.features]
    if missing:
        raise DemoError(store.path, f"does not record {', '.join(missing)}, which the env observes")
    keys = [*env.obs_keys, "action", "sim.state"]
    for index in range(store.num_episodes) if episodes is None else episodes:
        yield _trajectory(store, env, index, store.read_episode(index, keys))


def _trajectory(store: EpisodeStore, env: Any, index: int, frames: dict[str, np.ndarray]) -> Trajectory:
    info = store.episode_info(index)
    seed = int(info["seed"])
    first, _ = env.reset(seed=seed)  # the episode's start in this env: its recorded first frame, bit for bit
    names = env.obs_names
    for key in env.obs_keys:
        if not np.array_equal(first[names[key]], frames[key][0].reshape(first[names[key]].shape)):
            raise DemoError(store.path, f"episode {index}: its seed does not give its recorded first {key} in this "
                                        "env (collected with another robot, task option or camera?)")
    sim = env.sim
    sim.set_state(frames["sim.state"][-1])
    env.codec.reset(sim)
    actions = np.stack([env.normalized(a) for a in frames["action"]]).astype(np.float32)  # as env.step takes them
    final, *_ = env.step(actions[-1])  # through the env's codec, as a policy's action would be
    obs = {names[k]: np.concatenate([frames[k].reshape(len(actions), *final[names[k]].shape), final[names[k]][None]])
           for k in env.obs_keys}
    if env.state_keys:
        state, seed_key = env.state_keys
        obs[state] = np.concatenate([frames["sim.state"], final[state][None]])
        obs[seed_key] = np.full((len(actions) + 1, 1), seed, dtype=np.int64)
    terminal = bool(info["success"]) or len(actions) < env.horizon  # ended by success held or a failure
    return Trajectory(obs, actions, terminal, seed)
