"""Shared benchmark plumbing: repeat-until-time-budget timing and machine facts for the JSON."""

from __future__ import annotations

import contextlib
import os
import platform
import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np


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
