"""`demo bench render`: collection frames/s with cameras against bare ``mujoco.Renderer`` renders.

Figure: steady-state frames/s of scripted collection with cameras (default ``front@64x64`` and
``wrist@64x64`` on ``pick``) through :func:`~demo.collect.scripted.collect_scripted`, what
``demo collect --camera ...`` runs: the expert and its IK, physics, observations, one render per
camera per frame, zstd compression and the store's writes. Timed from the first committed episode
to the last (start-up, GL contexts included, is not counted), with one simulation worker process
by default as ``demo collect`` (it simulates and renders while this process compresses and
writes), or all in this process (``workers=0``: every cost of a frame in one process).

Reference, same run, same model (the collection env's, so the same scene, cameras, sizes and
offscreen buffer): for each frame of the expert's episodes, the control step's physics (``ctrl``
as the episode set it, then ``mj_step(nstep=n_substeps)``) and, for each camera,
``Renderer.update_scene(data, camera)`` + ``Renderer.render()`` on a plain ``mujoco.Renderer`` per
camera: what a frame costs at least. Resets are left out of its time.

As in ``demo bench collect``, a shared machine drifts from one run to the next, so the run measures
in ``rounds`` (reference, then collection), one last reference closes it, and each figure is the
best of its samples, the reference included. All samples are in the JSON. With ``workers=0`` the
JSON also holds ``cpu_ratio``: the same ratio in frames per CPU second of this process (the GL
rasteriser's threads included), which other jobs on a shared machine disturb far less than the
wall clock.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from demo.bench.collect import collection_store, timed_collection
from demo.bench.common import machine
from demo.collect.scripted import CollectConfig, make_env_for, start_seed
from demo.errors import DemoError
from demo.executor import ExecutorConfig
from demo.sim.benchmark import expert_actions
from demo.sim.render import parse_camera
from demo.store import EpisodeStore

DEFAULT_CAMERAS = ("front@64x64", "wrist@64x64")
TARGET_RATIO = 0.8
REFERENCE_EPISODES = 8

Controls = list[tuple[np.ndarray, list[np.ndarray]]]  # per episode: state after reset, ctrl of each control step


def expert_controls(config: CollectConfig, episodes: int = REFERENCE_EPISODES) -> Controls:
    """The expert's first ``episodes`` episodes of ``config`` (same start states) as (integration
    state after reset, ``ctrl`` of each control step); recorded without cameras (they change no
    dynamics), so nothing renders."""
    env = make_env_for(replace(config, cameras=()))
    seeds = [start_seed(config, i) for i in range(episodes)]
    try:
        out: Controls = []
        for seed, actions in expert_actions(env, seeds).items():
            env.reset(seed)
            start, ctrls = env.get_state(), []
            for action in actions:
                env.step(action)
                ctrls.append(env.data.ctrl.copy())
            out.append((start, ctrls))
        return out
    finally:
        env.close()


def bare_render_rate(config: CollectConfig, controls: Controls, seconds: float) -> dict[str, float]:
    """Frames/s of physics + ``update_scene`` + ``render`` per camera on the collection's model,
    replaying ``controls`` until ``seconds`` of timed frames have passed."""
    env = make_env_for(config)
    m, d = env.model, env.data
    renderers = [(name, mujoco.Renderer(m, height=h, width=w)) for name, h, w in env.cameras.specs]
    frames, busy, cpu = 0, 0.0, 0.0
    try:
        while busy < seconds:
            for start, ctrls in controls:
                env.set_state(start)
                t0, c0 = time.perf_counter(), time.process_time()
                for ctrl in ctrls:
                    d.ctrl[:] = ctrl
                    mujoco.mj_step(m, d, nstep=env.n_substeps)
                    for name, renderer in renderers:
                        renderer.update_scene(d, camera=name)
                        renderer.render()
                busy += time.perf_counter() - t0
                cpu += time.process_time() - c0
                frames += len(ctrls)
    finally:
        for _, renderer in renderers:
            renderer.close()
        env.close()
    return {"frames_per_s": frames / busy, "cpu_frames_per_s": frames / cpu, "frames": frames, "seconds": busy}


def run(
    task: str = "pick",
    cameras: Sequence[str] = DEFAULT_CAMERAS,
    episodes: int = 20,
    seconds: float = 3.0,
    seed: int = 0,
    rounds: int = 2,
    workers: int = 1,
) -> dict[str, Any]:
    """Collection frames/s with ``cameras`` (``NAME@WxH``) against bare renders of the same scene."""
    specs = tuple(parse_camera(c, "--camera") for c in cameras)
    if not specs:
        raise DemoError("--camera", "give at least one camera (e.g. front@64x64)")
    if episodes < 2:
        raise DemoError("--episodes", "must be at least 2 (the rate is timed from the first committed episode)")
    if rounds < 1 or seconds <= 0 or workers < 0:
        raise DemoError("bench render", "needs rounds >= 1, seconds > 0 and workers >= 0")
    config = CollectConfig(task=task, episodes=episodes, seed=seed, cameras=specs)
    controls = expert_controls(config, min(episodes, REFERENCE_EPISODES))
    samples: dict[str, list[dict[str, float]]] = {"reference": [], "collection": []}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(rounds):
            samples["reference"].append(bare_render_rate(config, controls, seconds))
            samples["collection"].append(timed_collection(config, workers, Path(tmp)))
        with EpisodeStore.open(collection_store(Path(tmp), ExecutorConfig("process", workers))) as store:
            sizes = store.summary()["camera_bytes"]
    samples["reference"].append(bare_render_rate(config, controls, seconds))
    if workers == 0:  # all the collection's work is this process's: its CPU time is comparable
        for sample in samples["collection"]:
            sample["cpu_frames_per_s"] = sample["steady_frames"] / sample["steady_cpu_s"]
    figure = max(samples["collection"], key=lambda r: r["frames_per_s"])
    reference = max(samples["reference"], key=lambda r: r["frames_per_s"])
    ratio = figure["frames_per_s"] / reference["frames_per_s"]
    cpu_ratio = (max(r["cpu_frames_per_s"] for r in samples["collection"])
                 / max(r["cpu_frames_per_s"] for r in samples["reference"])) if workers == 0 else None
    return {
        "benchmark": "render",
        "task": task,
        "cameras": [f"{name}@{w}x{h}" for name, w, h in specs],
        "workers": workers,
        "rounds": rounds,
        "figure": figure,
        "reference": reference,
        "reference_method": "per frame: mj_step(m, d, nstep=n_substeps) with the expert's ctrl, then per camera "
                            "mujoco.Renderer.update_scene + render, same model (best of all samples)",
        "ratio": ratio,
        "cpu_ratio": cpu_ratio,
        "target_ratio": TARGET_RATIO,
        "meets_target": bool(ratio >= TARGET_RATIO),
        "samples": {k: [round(r["frames_per_s"], 1) for r in v] for k, v in samples.items()},
        "cpu_samples": {k: [round(r["cpu_frames_per_s"], 1) for r in v] for k, v in samples.items()} if workers == 0 else None,
        "camera_bytes": sizes,
        "machine": machine(),
    }
