"""`demo bench env RUN`: the generic environment path's overhead, ``demo eval`` against a bare loop.

Figure: environment steps per second of ``demo eval RUN`` in this process (:func:`demo.evaluation.
evaluate.evaluate`: the foreign-environment adapter, the rollout loop, success bookkeeping, the
policy actor). Reference, same run: a bare loop over the same Gymnasium environment and the same
policy actor, ``gymnasium.make`` then ``env.step(actor.act(obs))`` on the same reset seeds, with no
adapter and no rollout loop. Both are measured ``rounds`` times, interleaved, and the best round of
each is kept (a shared machine only ever slows a round down); the ratio is figure / reference
(target >= 0.9).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import torch

from demo.bench.common import machine
from demo.errors import DemoError
from demo.evaluation.evaluate import EvalConfig, evaluate, make_actor, single_thread
from demo.policies.checkpoint import PolicyBundle, load_bundle
from demo.seeds import eval_seeds
from demo.sim.foreign import ForeignEnv, is_foreign, success_of

TARGET = 0.9


def bare_loop(bundle: PolicyBundle, seeds: list[int]) -> tuple[int, float]:
    """Steps and seconds of the bare loop: the Gymnasium env stepped directly by the run's policy actor."""
    adapter = ForeignEnv(bundle.task["name"], **dict(bundle.task.get("options") or {}))  # only to read observations
    env, horizon = adapter.gym, adapter.horizon
    actor = make_actor(bundle, adapter)
    steps = 0
    with single_thread():
        start = time.perf_counter()
        for seed in seeds:
            obs, _ = env.reset(seed=seed)
            actor.reset(seed)
            for _ in range(horizon):
                frame = adapter.frame_of(obs)
                obs, _, terminated, truncated, info = env.step(actor.act(frame))
                steps += 1
                if terminated or truncated or success_of(info):
                    break
        seconds = time.perf_counter() - start
    env.close()
    return steps, seconds


def run(run_dir: str, episodes: int = 50, seed: int = 0, rounds: int = 3) -> dict[str, Any]:
    """Measure (module docstring); returns the JSON-able result."""
    run = Path(run_dir)
    bundle = load_bundle(run, "cpu")
    if not is_foreign(bundle.task.get("name")):
        raise DemoError(run, "was not trained on a Gymnasium environment (demo collect --env)")
    seeds = [int(s) for s in eval_seeds(seed, episodes)]
    torch.set_num_threads(1)
    ours, bare = [], []
    for _ in range(rounds):
        result = evaluate(EvalConfig(run=str(run), episodes=episodes, seed=seed, device="cpu"))
        ours.append(result["steps_per_s"])
        steps, seconds = bare_loop(bundle, seeds)
        bare.append(steps / max(seconds, 1e-9))
    figure, reference = max(ours), max(bare)
    return {
        "bench": "env",
        "run": str(run),
        "env": bundle.task["name"],
        "episodes": episodes,
        "rounds": rounds,
        "figure": {"what": "demo eval steps/s (adapter, rollout loop, actor)", "steps_per_s": figure,
                   "rounds": ours},
        "reference": {"what": "bare gymnasium loop, same env, policy and seeds", "steps_per_s": reference,
                      "rounds": bare},
        "ratio": figure / reference,
        "target": TARGET,
        "meets_target": figure / reference >= TARGET,
        "success_rate": result["success_rate"],  # the last round's (every round runs the same episodes)
        "machine": machine(),
    }
