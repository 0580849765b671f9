"""`demo bench train --nproc N`: data-parallel training throughput against one process, same run.

Figure: global training samples/s of ``demo train STORE --nproc N --threads 1`` (torchrun, N gloo
processes with one thread each, DistributedDataParallel; ``--batch-size`` per process, so a step
consumes ``N x batch`` windows). Reference, same store, same model and the same cores: ``demo train
STORE --threads N`` in one process; also reported, ``--threads 1`` in one process (what one of the N
processes does alone). All are the real command, run as a subprocess, BC at its
defaults; the rate is the trainer's own (``metrics.json``'s ``samples_per_s``: windows per second
over each logging interval, the first interval of a run left out as warm-up: process-group set-up
and DDP's first bucket allocation). Runs alternate figure and reference for ``rounds`` rounds so a
noisy neighbour hits both alike, and each side's figure is its best interval over all its rounds.

On a CPU the processes share the machine's cores with each other: N processes with one thread each
against one process with N threads measures what data parallelism costs or gains over torch's own
intra-op threads, not a speed-up from more hardware; and N threads of one process slow down badly
when other jobs take cores from them (each step waits for its slowest thread), N processes far
less. On a GPU node (one process per GPU) the same command measures scaling.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

from demo.bench.common import machine
from demo.bench.load import build_store
from demo.errors import DemoError
from demo.policies.checkpoint import METRICS_FILE
from demo.training.config import TrainConfig

EPISODE_LENGTH = 200  # frames per synthetic episode
LOG_EVERY = TrainConfig.log_every  # optimiser steps per throughput interval (the trainer's logging)


def run_parallel(
    nproc: int = 2,
    data: Path | None = None,
    steps: int = 600,
    batch_size: int = 256,
    rounds: int = 2,
    frames: int = 50_000,
    seed: int = 0,
    device: str = "auto",
) -> dict[str, Any]:
    """Samples/s of ``nproc`` data-parallel processes vs one process with ``nproc`` threads."""
    if nproc < 2:
        raise DemoError("--nproc", f"compares N >= 2 processes with one, got {nproc}")
    if steps < 3 * LOG_EVERY:
        raise DemoError("--steps", f"needs at least {3 * LOG_EVERY} steps (3 throughput intervals), got {steps}")
    with tempfile.TemporaryDirectory() as tmp:
        store = Path(data) if data else Path(tmp) / "bench.zarr"
        if data is None:
            build_store(store, frames, EPISODE_LENGTH, 40, seed).close()
        common = [str(store), "--steps", str(steps), "--batch-size", str(batch_size), "--eval-episodes", "0",
                  "--seed", str(seed), "--device", device, "--include-failures"]
        sides = {"parallel": ["--nproc", str(nproc), "--threads", "1"], "one_process": ["--threads", str(nproc)],
                 "one_thread": ["--threads", "1"]}
        rates: dict[str, list[float]] = {side: [] for side in sides}
        for r in range(rounds):
            for side, flags in sides.items():
                out = Path(tmp) / f"{side}-{r}"
                rates[side] += _interval_rates([*common, "--out", str(out), *flags], out)
    best = {side: max(values) for side, values in rates.items()}
    return {
        "benchmark": "train_parallel",
        "data": str(data) if data else f"synthetic store, {frames} frames, 40-dim obs, 8-dim actions",
        "nproc": nproc,
        "batch_per_process": batch_size,
        "steps": steps,
        "rounds": rounds,
        "device": device,
        "figure": f"demo train --nproc {nproc} --threads 1 (DDP, gloo on CPU): global windows/s",
        "reference": f"demo train --threads {nproc} (one process): windows/s",
        "samples_per_s": best["parallel"],
        "reference_samples_per_s": best["one_process"],
        "ratio_to_reference": best["parallel"] / best["one_process"],
        "one_thread_samples_per_s": best["one_thread"],
        "ratio_to_one_thread": best["parallel"] / best["one_thread"],
        "intervals": rates,
        "machine": machine(),
    }


def _interval_rates(args: list[str], out: Path) -> list[float]:
    """Run ``demo train ARGS`` and return its logged samples/s, the first interval left out."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    done = subprocess.run([sys.executable, "-m", "demo", "train", *args, "--json", str(out) + ".json"],
                          capture_output=True, text=True, env=env, check=False)
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or ["no output"])[-1]
        raise DemoError("demo train", f"failed in the benchmark ({last})")
    metrics = json.loads((out / METRICS_FILE).read_text())
    return [float(rate) for _, rate in metrics["samples_per_s"][1:]]
