"""`demo bench load`: training-window sampling throughput on a 1M-frame store.

Figure: samples/s of :class:`WindowSampler` (batch 256, n_obs 2, horizon 16) on arrays loaded from a
store. Reference, same run: a raw contiguous memory copy of the same number of bytes per batch, the
speed limit of any sampler that has to gather those bytes.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from demo.bench.common import machine, rate
from demo.store import ActionSpec, EpisodeStore, FeatureSpec, StoreMeta, WindowSampler

TARGET_SAMPLES_PER_S = 50_000


def build_store(path: Path, frames: int, episode_length: int, obs_dim: int, seed: int = 0) -> EpisodeStore:
    meta = StoreMeta(
        fps=20.0,
        features={"obs.state": FeatureSpec((obs_dim,), "float32", "synthetic low-dim state")},
        action=ActionSpec("joint_pos", tuple(f"a{i}" for i in range(8)), ("rad",) * 8),
        task={"name": "bench"},
    )
    store = EpisodeStore.create(path, meta, overwrite=True)
    rng = np.random.default_rng(seed)
    n_episodes = frames // episode_length
    for first in range(0, n_episodes, 500):
        batch = []
        for _ in range(first, min(first + 500, n_episodes)):
            batch.append(
                (
                    {
                        "obs.state": rng.standard_normal((episode_length, obs_dim), dtype=np.float32),
                        "action": rng.standard_normal((episode_length, 8), dtype=np.float32),
                    },
                    {"success": True, "source": "synthetic"},
                )
            )
        store.append_episodes(batch)
    return store


def run(
    frames: int = 1_000_000,
    batch: int = 256,
    n_obs: int = 2,
    horizon: int = 16,
    obs_dim: int = 40,
    episode_length: int = 200,
    seconds: float = 3.0,
    seed: int = 0,
    workdir: Path | None = None,
) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        t0 = time.perf_counter()
        store = build_store(Path(tmp) / "bench.zarr", frames, episode_length, obs_dim, seed)
        build_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        data, ends = store.load(["obs.state", "action"])
        load_s = time.perf_counter() - t0
        store.close()
    sampler = WindowSampler(data, ends, ["obs.state"], n_obs=n_obs, horizon=horizon)
    rng = np.random.default_rng(seed)
    sampled = rate(lambda: sampler.sample(batch, rng), batch, seconds)

    obs, act = data["obs.state"], data["action"]
    starts = rng.integers(0, len(obs) - batch * horizon, size=64)
    counter = iter(range(10**12))

    def raw_copy() -> None:
        s = starts[next(counter) % len(starts)]
        np.copy(obs[s : s + batch * n_obs])
        np.copy(act[s : s + batch * horizon])

    reference = rate(raw_copy, batch, seconds)
    bytes_per_sample = (n_obs * obs.shape[1] + horizon * act.shape[1]) * 4
    return {
        "benchmark": "load",
        "frames": int(len(obs)),
        "episodes": int(len(ends)),
        "batch": batch,
        "n_obs": n_obs,
        "horizon": horizon,
        "bytes_per_sample": bytes_per_sample,
        "store_build_s": build_s,
        "store_load_s": load_s,
        "store_load_mb_per_s": (obs.nbytes + act.nbytes) / 1e6 / load_s,
        "samples_per_s": sampled["per_s"],
        "samples_per_s_best": sampled["best_slice_per_s"],
        "reference": "raw contiguous memory copy of the same bytes per batch (np.copy)",
        "reference_samples_per_s": reference["per_s"],
        "ratio_to_reference": sampled["per_s"] / reference["per_s"],
        "target_samples_per_s": TARGET_SAMPLES_PER_S,
        "meets_target": sampled["per_s"] >= TARGET_SAMPLES_PER_S,
        "machine": machine(),
    }
