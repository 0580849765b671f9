"""`demo bench collect`: recorded frames/s of scripted collection against the raw physics rate.

Figure: control steps recorded per second by ``collect_scripted`` (expert, IK, observation and
store writes included) with 1 and with 2 simulation worker processes (the calling process is the
store's writer in both, as in ``demo collect``), and with everything in one process (workers=0). Rates are steady-state: timed from the
first committed episode to the last, so worker start-up (importing MuJoCo, building the scene) is
reported separately and not counted.

Reference, same run: bare ``mj_step(model, data, nstep=n_substeps)`` on the same scene, in control
steps per second, the physical limit of a simulator-bound collector.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import Any

import mujoco

from demo.bench.common import machine
from demo.collect.scripted import CollectConfig, collect_scripted, make_env_for

TARGET_RATIO_TO_PHYSICS = 0.5
TARGET_TWO_WORKER_SPEEDUP = 1.7


def raw_physics_rate(config: CollectConfig, seconds: float) -> dict[str, float]:
    env = make_env_for(config)
    try:
        env.reset(0)
        model, data = env.model, env.data
        n = env.n_substeps
        steps, start = 0, time.perf_counter()
        while time.perf_counter() - start < seconds:
            for _ in range(100):
                mujoco.mj_step(model, data, nstep=n)
            steps += 100
        elapsed = time.perf_counter() - start
    finally:
        env.close()
    return {"control_steps_per_s": steps / elapsed, "mj_step_per_s": steps * n / elapsed, "n_substeps": n}


def timed_collection(config: CollectConfig, workers: int, workdir: Path) -> dict[str, float]:
    stamps: list[tuple[float, int]] = []
    start = time.perf_counter()
    result = collect_scripted(
        config,
        workdir / f"w{workers}.zarr",
        workers=workers,
        overwrite=True,
        on_episode=lambda i, info, n: stamps.append((time.perf_counter(), n)),
    )
    total = time.perf_counter() - start
    first_t = stamps[0][0]
    steady_frames = sum(n for _, n in stamps[1:])
    steady_s = stamps[-1][0] - first_t
    return {
        "workers": workers,
        "episodes": result.episodes,
        "frames": result.frames,
        "success_rate": result.success_rate,
        "wall_s": total,
        "startup_and_first_episode_s": first_t - start,
        "frames_per_s": steady_frames / steady_s if steady_s > 0 else float("nan"),
        "frames_per_s_incl_startup": result.frames / total,
    }


def run(task: str = "pick", episodes: int = 40, seconds: float = 3.0, seed: int = 0) -> dict[str, Any]:
    config = CollectConfig(task=task, episodes=episodes, seed=seed)
    physics = raw_physics_rate(config, seconds)
    with tempfile.TemporaryDirectory() as tmp:
        inline = timed_collection(config, 0, Path(tmp))
        one = timed_collection(config, 1, Path(tmp))
        two = timed_collection(config, 2, Path(tmp))
    ratio = one["frames_per_s"] / physics["control_steps_per_s"]
    speedup = two["frames_per_s"] / one["frames_per_s"]
    return {
        "benchmark": "collect",
        "task": task,
        "single_process": inline,
        "one_worker": one,
        "two_workers": two,
        "reference": "bare mj_step(m, d, nstep=n_substeps) on the same scene, control steps/s",
        "reference_physics": physics,
        "ratio_to_physics": ratio,
        "two_worker_speedup": speedup,
        "target_ratio_to_physics": TARGET_RATIO_TO_PHYSICS,
        "target_two_worker_speedup": TARGET_TWO_WORKER_SPEEDUP,
        "meets_targets": bool(ratio >= TARGET_RATIO_TO_PHYSICS and speedup >= TARGET_TWO_WORKER_SPEEDUP),
        "machine": machine(),
    }
