"""`demo bench resume`: training killed at random moments resumes to the weights of an uninterrupted run.

For each policy kind (``bc``: BC from state with ``demo train``'s defaults; ``diffusion``: the diffusion
policy from state; ``images``: BC from a 64x64 front camera and proprioception), on ``reach``
demonstrations collected here:

1. one uninterrupted ``demo train`` process (the reference): its wall time ``T`` and final train state;
2. ``kills`` trials in turn over the kinds: the same command, SIGKILLed (process group) at a time drawn
   uniformly from ``[0, T]`` s (start-up included), then ``demo train --resume`` (or the same command
   again where the kill came before the run's first save) until it finishes;
3. the trial's final weights (every tensor of the policy and its EMA) compared with the reference's,
   bit for bit, and the training lost to the kill: the seconds from the last train-state save to the kill.

Train states are saved every ``checkpoint_every`` s (``demo train --checkpoint-every``); the figure to
read is the most training one kill lost against that bound, and ``identical`` must be every trial.
"""

from __future__ import annotations

import os
import random
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from demo.bench.common import machine
from demo.collect.scripted import CollectConfig, collect_scripted
from demo.progress import Progress, Tick, or_silent

STATE_FILE = "train_state.pt"  # demo.policies.checkpoint.STATE_FILE (that module imports torch)
KINDS: dict[str, tuple[list[str], tuple[tuple[str, int, int], ...]]] = {
    # kind: (demo train flags, cameras of its data)
    "bc": ([], ()),
    "diffusion": (["--algo", "diffusion"], ()),
    "images": ([], (("front", 64, 64),)),
}


@dataclass
class ResumeConfig:
    out: str = "bench_resume"
    kinds: tuple[str, ...] = ("bc", "diffusion", "images")
    kills: int = 20  # trials, taken in turn over the kinds
    steps: int = 1500  # training steps of every run
    demos: int = 20  # reach demonstrations per store
    checkpoint_every: float = 2.0  # seconds between train-state saves
    seed: int = 0  # seed of the data, the training and the kill times


def train_command(c: ResumeConfig, kind: str, store: Path, out: Path) -> list[str]:
    flags, _ = KINDS[kind]
    return [sys.executable, "-m", "demo", "train", str(store), *flags, "--steps", str(c.steps), "--seed", str(c.seed),
            "--checkpoint-every", str(c.checkpoint_every), "--out", str(out)]


def run_to_end(command: list[str], kill_after: float | None = None) -> tuple[float, int | None]:
    """Run ``command`` (its own process group); SIGKILL it after ``kill_after`` s. Its wall time and exit code
    (None when killed)."""
    t0 = time.perf_counter()
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)
    try:
        process.wait(timeout=kill_after)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        process.wait()
        process.stderr.close()
        return time.perf_counter() - t0, None
    error = process.stderr.read().decode(errors="replace").strip().splitlines()
    process.stderr.close()
    if process.returncode != 0:
        raise RuntimeError(f"{' '.join(command[2:])} failed: {error[-1] if error else process.returncode}")
    return time.perf_counter() - t0, 0


def _train_state(run: Path) -> dict[str, Any]:
    from demo.policies.checkpoint import load_train_state  # deferred: it imports torch

    return load_train_state(run)


def same_weights(a: Path, b: Path) -> bool:
    """Whether two runs' final train states hold the same policy and EMA tensors, bit for bit."""
    import torch  # deferred: demo --help imports this module and no torch

    sa, sb = _train_state(a), _train_state(b)
    parts = [(sa["policy"], sb["policy"]), (sa.get("ema") or {}, sb.get("ema") or {})]
    return sa["step"] == sb["step"] and all(
        x.keys() == y.keys() and all(torch.equal(x[k], y[k]) for k in x) for x, y in parts)


def trial(c: ResumeConfig, kind: str, store: Path, reference: Path, out: Path, kill_at: float) -> dict[str, Any]:
    """Kill a run at ``kill_at`` s, resume it to the end, compare it with the reference."""
    shutil.rmtree(out, ignore_errors=True)  # a trial of an earlier run of the bench
    command = train_command(c, kind, store, out)
    _, code = run_to_end(command, kill_after=kill_at)
    state = out / STATE_FILE
    killed = code is None
    saved = _train_state(out)["step"] if killed and state.is_file() else None
    lost = time.time() - state.stat().st_mtime if killed and state.is_file() else None  # since the last save
    resumes = 0
    if killed:
        run_to_end(command + (["--resume"] if state.is_file() else []))
        resumes = 1
    return {"kind": kind, "kill_at_s": kill_at, "killed": killed, "saved_step": saved, "lost_s": lost,
            "resumes": resumes, "identical": same_weights(reference, out)}


def run(c: ResumeConfig, progress: Progress | None = None) -> dict[str, Any]:
    """Every kind's reference and the kill trials (module docstring); the JSON-able result."""
    tell = or_silent(progress)
    root = Path(c.out)
    rng = random.Random(c.seed)
    references: dict[str, tuple[Path, Path, float]] = {}
    for kind in c.kinds:
        tell(Tick("bench resume", 0, c.kills, {"info": f"{kind}: data and reference run"}))
        _, cameras = KINDS[kind]
        store = root / f"reach_{'images' if cameras else 'state'}.zarr"
        if not store.exists():
            collect_scripted(CollectConfig(task="reach", episodes=c.demos, seed=c.seed, cameras=cameras), store,
                             workers=0)
        reference = root / kind / "reference"
        seconds, _ = run_to_end(train_command(c, kind, store, reference) + ["--overwrite"])
        references[kind] = (store, reference, seconds)
    trials = []
    for i in range(c.kills):
        kind = c.kinds[i % len(c.kinds)]
        store, reference, seconds = references[kind]
        trials.append(trial(c, kind, store, reference, root / kind / f"trial_{i}", rng.uniform(0.0, seconds)))
        tell(Tick("bench resume", i + 1, c.kills, {"identical": f"{sum(t['identical'] for t in trials)}/{i + 1}"}))
    lost = [t["lost_s"] for t in trials if t["lost_s"] is not None]
    return {
        "bench": "resume",
        "trials": trials,
        "references_s": {k: v[2] for k, v in references.items()},
        "killed": sum(t["killed"] for t in trials),
        "identical": sum(t["identical"] for t in trials),
        "max_lost_s": max(lost, default=0.0),
        "ok": all(t["identical"] for t in trials),
        "configuration": asdict(c),
        "machine": machine(),
    }
