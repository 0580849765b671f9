"""Per-control-step cost of expert collection against bare physics on the same trajectories.

``step_cost(task)`` records the expert's actions for a few episodes, then times, interleaved and
best of ``reps`` (CPU time of this process, so other processes on a shared machine matter less):

- ``physics``: reset, then per recorded action set ``ctrl`` and ``mj_step(m, d, nstep=n_substeps)``
  (the reference: the simulator alone, same scene, same states);
- ``env_step``: ``env.step(action)`` (adds action mapping, observations, success);
- ``collect``: ``env.frame()`` + ``expert.act(env)`` + ``env.step`` (what a collector does per frame,
  without the store).

Reset time is measured separately and subtracted. Figures are microseconds per control step.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Sequence
from typing import Any

import mujoco
import numpy as np

from demo.sim.env import make_env


def expert_actions(env: Any, seeds: list[int]) -> dict[int, list[np.ndarray]]:
    """The expert's actions from each seed's reset until success (or the horizon)."""
    actions: dict[int, list[np.ndarray]] = {}
    for s in seeds:
        env.reset(s)
        expert = env.expert(np.random.default_rng(s))
        actions[s] = []
        for _ in range(env.horizon):
            a = expert.act(env)
            actions[s].append(a)
            if env.step(a)[2]:
                break
    return actions


def replay_physics(env: Any, episodes: Iterable[tuple[int, Sequence[np.ndarray]]]) -> None:
    """Bare physics on recorded actions: per ``(reset seed, actions)`` episode, ``env.reset(seed)``,
    then per action set ``ctrl`` and ``mj_step(nstep=n_substeps)``.

    The task's own rule between steps (``task.after_step``: ``stack`` with ``repeat`` moves its pad
    there; a no-op elsewhere) runs too, so that replaying a collected episode's executed actions
    from its reset seed goes through the very states the collection simulated (MuJoCo clamps
    ``ctrl`` to its range as ``env.step`` does; tested state for state)."""
    m, d = env.model, env.data
    after_step = env.task.after_step
    for seed, actions in episodes:
        env.reset(seed)
        for a in actions:
            d.ctrl[env.arm_act] = env._arm_ctrl(a[:-1])
            d.ctrl[env.grip_act] = env._gripper_ctrl(a[-1])
            mujoco.mj_step(m, d, nstep=env.n_substeps)
            after_step(env)


def step_cost(task: str = "pick", episodes: int = 4, reps: int = 3, **task_options: Any) -> dict[str, Any]:
    env = make_env(task, **task_options)
    seeds = list(range(episodes))
    actions = expert_actions(env, seeds)
    steps = sum(len(v) for v in actions.values())

    def physics() -> None:
        replay_physics(env, actions.items())

    def env_step() -> None:
        for s in seeds:
            env.reset(s)
            for a in actions[s]:
                env.step(a)

    def collect() -> None:
        for s in seeds:
            env.reset(s)
            expert = env.expert(np.random.default_rng(s))
            for _ in actions[s]:
                env.frame()
                env.step(expert.act(env))

    def resets() -> None:
        for s in seeds:
            env.reset(s)

    best = dict.fromkeys(("physics", "env_step", "collect", "reset"), float("inf"))
    fns = {"physics": physics, "env_step": env_step, "collect": collect, "reset": resets}
    for _ in range(reps):
        for name, fn in fns.items():
            t = time.process_time()
            fn()
            best[name] = min(best[name], time.process_time() - t)
    env.close()
    us = {k: 1e6 * (best[k] - best["reset"]) / steps for k in ("physics", "env_step", "collect")}
    return {
        "task": task,
        "task_options": task_options,
        "control_steps": steps,
        "n_substeps": env.n_substeps,
        "us_per_step": us,
        "overhead_us_per_step": us["collect"] - us["physics"],
        "ratio_collect_to_physics": us["physics"] / us["collect"],
        "reset_ms": 1e3 * best["reset"] / len(seeds),
        "reference": "bare mj_step(nstep=n_substeps) replaying the same actions from the same resets",
    }
