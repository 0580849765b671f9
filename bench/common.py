"""Shared benchmark plumbing: repeat-until-time-budget timing and machine facts for the JSON."""

from __future__ import annotations

import contextlib
import os
import platform
import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np


def interleaved_ms(calls: dict[str, Callable[[], Any]], seconds: float, min_rounds: int = 5, block: int = 1
                   ) -> dict[str, np.ndarray]:
    """Per-call wall time (ms) of each of ``calls``, called in turn round after round, for ``seconds`` and at
    least ``min_rounds`` rounds, after two untimed warm-up calls each.

    Interleaving makes every figure see the same machine: on a shared 2-core machine the load of
    other processes changes by 2-5x within a minute, which would skew figures measured one after
    the other.

    ``block > 1``: each turn calls one of them ``block`` times in a row and times all but the first
    call, which pays for reloading what the others evicted from the CPU's caches (a deployed policy
    is queried alone, its weights warm).
    """
    for fn in calls.values():
        fn()
        fn()
    times: dict[str, list[float]] = {name: [] for name in calls}
    start, rounds = time.perf_counter(), 0
    while rounds < min_rounds or time.perf_counter() - start < seconds:
        for name, fn in calls.items():
            for call in range(block):
                t0 = time.perf_counter()
                fn()
                if call > 0 or block == 1:
                    times[name].append(time.perf_counter() - t0)
        rounds += 1
    return {name: np.array(ts) * 1e3 for name, ts in times.items()}


def rate(fn: Callable[[], Any], items_per_call: float, min_seconds: float = 1.0, warmup: int = 2) -> dict[str, float]:
    """Call ``fn`` until ``min_seconds`` have passed; items per second over the timed calls.

    Reports the best of three equal slices as well as the mean, because a shared 2-core machine is
    noisy and the best slice is the closer estimate of what the code can do.
    """
    for _ in range(warmup):
        fn()
    calls, start = 0, time.perf_counter()
    slices: list[float] = []
    slice_start, slice_calls = start, 0
    while True:
        fn()
        calls += 1
        slice_calls += 1
        now = time.perf_counter()
        if now - slice_start >= min_seconds / 3:
            slices.append(slice_calls * items_per_call / (now - slice_start))
            slice_start, slice_calls = now, 0
        if now - start >= min_seconds and len(slices) >= 3:
            break
    elapsed = time.perf_counter() - start
    return {"per_s": calls * items_per_call / elapsed, "best_slice_per_s": max(slices), "seconds": elapsed, "calls": calls}


@contextlib.contextmanager
def one_core() -> Iterator[int | None]:
    """Pin this process to one CPU (the lowest it may run on) while measuring, where the OS allows it.

    Yields the CPU number, or None where affinity cannot be set (the figure is then unpinned).
    """
    if not hasattr(os, "sched_setaffinity"):
        yield None
        return
    before = os.sched_getaffinity(0)
    cpu = min(before)
    os.sched_setaffinity(0, {cpu})
    try:
        yield cpu
    finally:
        os.sched_setaffinity(0, before)


def machine() -> dict[str, Any]:
    return {
        "python": platform.python_version(),
        "platform": platform.platform(),
        "cpu_count": os.cpu_count(),
        "numpy": np.__version__,
        "torch_threads": _torch_threads(),
    }


def _torch_threads() -> int:
    import torch  # deferred: torch stays out of demo --help

    return torch.get_num_threads()
