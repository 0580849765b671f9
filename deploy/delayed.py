"""Asynchronous chunk execution with an inference delay counted in control steps, simulated without a clock.

``demo bench realtime`` runs the real loop (server, client thread, a simulator stepping on the wall clock)
and takes minutes per 100 episodes at 20 Hz. This runs the same client logic, :class:`ChunkMerger`'s merge
and anchoring and the committed prefix of :mod:`demo.policies.prefix`, against the simulator stepped as fast
as it goes, with the delay made exact: a request sent from the observation of step ``s`` is answered at
step ``s + delay`` (one request in flight, as the client's thread), so a sweep over delays takes seconds and
replays bit for bit (``demo bench delay``). What it leaves out is what the real loop adds: jitter in the
round trips, and the client's safety limits.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from demo.deploy.controller import ChunkMerger
from demo.evaluation.evaluate import wilson_interval
from demo.policies.checkpoint import load_bundle
from demo.progress import Progress, Tick, or_silent
from demo.seeds import eval_seeds
from demo.sim import make_env
from demo.sim.rollout import HOLD_SUCCESS_S, SuccessHold


@dataclass
class DelayConfig:
    run: str
    delay_steps: int = 0  # control steps between a request and its answer
    episodes: int = 100
    seed: int = 0
    ensemble: float = 0.01  # ACT's m, as the client's (demo.deploy.controller.ControlConfig)
    # The episode's first chunk starts when it is first executed (the client's rule); False: at the step of the
    # observation it answered, the rule before it, kept to measure what it costs
    anchor: bool = True
    prefix: bool = True  # send the committed actions to a policy that continues them (demo.policies.prefix)


def run_delayed(config: DelayConfig, progress: Progress | None = None) -> dict[str, Any]:
    """``episodes`` episodes of the run's task on its evaluation seeds with the delay; success (95% interval)."""
    if config.delay_steps < 0:
        raise ValueError(f"the delay must be >= 0 control steps, got {config.delay_steps}")
    bundle = load_bundle(config.run)
    task = bundle.run["task"]
    env = make_env(task["name"], **dict(task.get("options") or {}))
    actor = bundle.actor()
    told = config.prefix and bundle.policy.spec.prefix > 0
    tell = or_silent(progress)
    successes, lengths = 0, []
    try:
        for i, seed in enumerate(eval_seeds(config.seed, config.episodes)):
            success, length = _episode(env, actor, config, int(seed), told)
            successes += success
            lengths.append(length)
            tell(Tick(f"delay {config.delay_steps}", i + 1, config.episodes, {"success": f"{successes}/{i + 1}"}))
    finally:
        env.close()
    return {"run": config.run, "task": task["name"], "delay_steps": config.delay_steps, "anchor": config.anchor,
            "prefix_steps": bundle.policy.spec.prefix if told else 0, "episodes": config.episodes,
            "successes": successes, "success_rate": successes / max(config.episodes, 1),
            "ci95": list(wilson_interval(successes, config.episodes)), "episode_lengths": lengths}


def _episode(env: Any, actor: Any, config: DelayConfig, seed: int, told: bool) -> tuple[bool, int]:
    """One episode: whether it succeeded (held as ``demo eval`` holds it) and its control steps."""
    obs = env.reset(seed)
    actor.reset(seed, env)
    merger = ChunkMerger(config.ensemble, anchor=config.anchor)
    hold = SuccessHold(HOLD_SUCCESS_S, env.fps)
    last = np.r_[obs["obs.joint_pos"], env.robot.home_gripper].astype(np.float64)
    in_flight: tuple[int, int, np.ndarray] | None = None  # (answered at, observation's step, chunk)
    for step in range(env.horizon):
        if in_flight is not None and in_flight[0] <= step:
            merger.add(in_flight[1], in_flight[2])
            in_flight = None
        if config.delay_steps == 0:  # answered at once: nothing is committed ahead of this step
            merger.add(step, actor.chunk(obs).astype(np.float64))
        action = merger.action(step)  # first, so the episode's first chunk is anchored before looking ahead
        if in_flight is None and config.delay_steps:
            prefix = merger.committed(step, config.delay_steps) if told else None
            in_flight = (step + config.delay_steps, step, actor.chunk(obs, prefix).astype(np.float64))
        command = last if action is None else action  # nothing yet: the robot holds
        last = command
        obs, _, success, truncated, _ = env.step(command)
        if hold.update(bool(success)):
            return True, step + 1
        if truncated:
            return False, step + 1
    return False, env.horizon
