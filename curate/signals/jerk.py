"""Jerk: how smooth the commanded trajectory is.

Jerk is the third time-derivative of the commanded trajectory (the action for absolute targets,
its running sum for rate/delta actions, see :meth:`FrameData.trajectory`), by finite differences
over a fixed ``LAG_S`` = 50 ms (one frame at 20 fps, five at 100 Hz, so that the number does not
depend on the recording rate), divided per dimension by that dimension's typical range (how far it
moves within a typical episode, see :mod:`demo.curate.frames`). Gripper dimensions are left out: an
open/close step is a command, not shakiness.

Per frame the jerk is the RMS over dimensions. ``jerk`` is its 75th percentile over the episode's
frames: shakiness that lasts (jitter on a quarter of the frames or more) counts, while a few
corners where a scripted or planned motion switches phase (a velocity-limited move starting from
rest) do not; ``jerk_rms``, the RMS over all frames, counts those too. In range/s^3. A smooth
minimum-jerk reach over 2 s across the typical range has an RMS jerk of 60/2^3 * sqrt(1/5) = 3.4;
white noise of 1% of the range per frame at 20 fps reads ~ 0.01 * sqrt(20) * 20^3 = 360.
"""

from __future__ import annotations

import numpy as np

from demo.curate.frames import FrameData
from demo.curate.signals import Signal, episode_diff, episode_sum

SIGNALS = (
    Signal("jerk", "range/s^3",
           "75th percentile over frames of the commanded trajectory's jerk (RMS over non-gripper dims, each in its typical range)"),
    Signal("jerk_rms", "range/s^3", "RMS over frames of the same per-frame jerk (phase-switch corners included)"),
)
PERCENTILE = 75.0

LAG_S = 0.05  # s: the time step of the finite differences


def frame_jerk(fd: FrameData) -> tuple[np.ndarray, np.ndarray]:
    """``(j2, valid)``: [N] per-frame mean-over-dims squared normalised jerk, and where it is defined."""
    arm = ~fd.gripper_dims
    if not arm.any():
        arm = np.ones_like(arm)
    y = fd.trajectory()[:, arm]
    inv = (1.0 / fd.typical_range(y)).astype(np.float32)
    lag = max(1, int(round(LAG_S * fd.fps)))
    d, valid = episode_diff(y, fd.starts, order=3, lag=lag)
    d *= inv * np.float32(fd.fps / lag) ** 3
    j2 = np.einsum("ij,ij->i", d, d) / y.shape[1]
    return j2, valid


def compute(fd: FrameData) -> dict[str, np.ndarray]:
    """``jerk`` and ``jerk_rms`` [E] in range/s^3 (0 for episodes too short for a third difference)."""
    j2, valid = frame_jerk(fd)
    ep = fd.episode_of_frame()
    e = fd.num_episodes
    total = episode_sum(np.where(valid, j2, 0.0), ep, e)
    count = np.bincount(ep, weights=valid, minlength=e).astype(np.int64)
    # Per-episode percentile without a loop: sort frames by (episode, value), undefined frames last.
    order = np.lexsort((np.where(valid, j2, np.inf), ep))
    sorted_j = j2[order]
    pos = (count - 1) * (PERCENTILE / 100.0)
    lo = fd.starts + np.floor(pos).astype(np.int64).clip(0)
    hi = fd.starts + np.ceil(pos).astype(np.int64).clip(0)
    frac = pos - np.floor(pos)
    p = np.where(count > 0, sorted_j[lo] * (1 - frac) + sorted_j[np.minimum(hi, fd.ends - 1)] * frac, 0.0)
    return {"jerk": np.sqrt(np.maximum(p, 0.0)), "jerk_rms": np.sqrt(total / np.maximum(count, 1))}
