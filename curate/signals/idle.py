"""Idle frames: the operator hesitates and nothing moves.

A frame is *idle* when neither the robot/scene state nor the commanded action changes: its speed
(:func:`frame_speed`: the largest per-dimension rate of change, each dimension divided by its
typical range (:mod:`demo.curate.frames`), measured between short window averages) is below
``IdleParams.speed`` (range/s) for the low-dim observations and, for absolute action
representations, for the action too (a rate/delta action is not compared: a constant velocity
command is motion, and the state shows standing still anyway). Using the state makes the signal
representation-agnostic: a held joint target and a zero velocity command both read as idle.

Only idle *runs* of at least ``min_run_s`` count (a grasp that settles for two frames is not a
pause). Runs touching the first or last frame of an episode are the idle start/end that
``--trim-idle`` cuts; the others are mid-episode pauses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from demo.curate.frames import FrameData
from demo.curate.signals import Signal

SIGNALS = (
    Signal("idle_fraction", "fraction [0..1]", "share of frames in idle runs >= min_run_s, anywhere in the episode"),
    Signal("idle_start_s", "s", "idle time before the first motion"),
    Signal("idle_end_s", "s", "idle time after the last motion"),
    Signal("pause_s", "s", "total mid-episode idle (runs >= min_run_s not touching the start or end)"),
    Signal("pause_max_s", "s", "longest mid-episode pause"),
    Signal("pause_fraction", "fraction [0..1]", "mid-episode idle share of the frames left after trimming the idle start/end"),
)


@dataclass(frozen=True)
class IdleParams:
    speed: float = 0.02  # range/s: below this on every dimension a frame is idle
    min_run_s: float = 0.5  # s: shorter idle runs are ordinary settling, not pauses
    keep_start_s: float = 0.1  # s of an idle start kept when trimming (the robot at rest is data too)
    keep_end_s: float = 0.5  # s of an idle end kept (a settled final state shows the task is done)
    smooth_s: float = 0.15  # s: averaging window of the speed estimate


CHUNK = 32_768  # frames per block: keeps the window sums of all dims in cache


def _normalised_state(fd: FrameData, rows: slice | np.ndarray) -> np.ndarray:
    """Rows of the range-normalised state (low-dim obs + absolute action), moving dims only."""
    parts, ranges = [], []
    if fd.obs.shape[1]:
        parts.append(fd.obs)
        ranges.append(fd.obs_range)
    if not fd.action_is_delta or not parts:
        parts.append(fd.action)
        ranges.append(fd.action_range)
    out = []
    for x, r in zip(parts, ranges):
        keep = np.isfinite(r)
        if keep.all():
            out.append(x[rows] * (1.0 / r).astype(np.float32))
        elif keep.any():
            out.append(x[rows][:, keep] * (1.0 / r[keep]).astype(np.float32))
    return np.concatenate(out, axis=1) if out else np.zeros((len(np.arange(fd.num_frames)[rows]), 0), np.float32)


def frame_speed(fd: FrameData, smooth_s: float = 0.15) -> np.ndarray:
    """[N] float32 per-frame speed in range/s: the max over the low-dim state and absolute action
    dims of the rate of change, each dim divided by its typical range.

    The rate is taken two ways and the smaller wins: frame to frame (exact at the edges of a clean
    hold), and between the mean of the ``w = smooth_s * fps`` frames before ``t`` and the mean of
    the ``w`` frames from ``t`` on (so hand tremor or sensor noise during a pause, which averages
    out, does not read as motion; white noise shrinks by sqrt(w)). Windows are padded with the
    episode's first/last frame at its edges, never reaching into the neighbouring episode.
    """
    n = fd.num_frames
    w = max(1, int(round(smooth_s * fd.fps)))
    smooth_scale = np.float32(fd.fps / (w * w))  # window sums differ by w frames of w samples
    speed = np.empty(n, np.float32)
    # Interior frames: contiguous shifted sums, block by block (a block reads w frames either side),
    # dims x frames so that the max over dims is an elementwise maximum of contiguous rows.
    for c0 in range(0, n, CHUNK):
        c1 = min(n, c0 + CHUNK)
        lo, hi = max(0, c0 - w), min(n, c1 + w)
        x = np.ascontiguousarray(_normalised_state(fd, slice(lo, hi)).T)
        speed[c0:c1] = 0.0  # the first w frames of the store are episode-edge frames, set below
        if x.shape[0] == 0:
            continue
        box = x[:, : hi - lo - w + 1].copy()  # box[:, i] = x[:, i] + ... + x[:, i + w - 1]
        for k in range(1, w):
            box += x[:, k : hi - lo - w + 1 + k]
        s0, s1 = max(c0 - lo, w), min(c1 - lo, box.shape[1])
        if s1 <= s0:
            continue
        smooth = np.abs(box[:, s0:s1] - box[:, s0 - w : s1 - w]).max(axis=0) * smooth_scale
        raw = np.abs(x[:, s0:s1] - x[:, s0 - 1 : s1 - 1]).max(axis=0) * np.float32(fd.fps)
        speed[lo + s0 : lo + s1] = np.minimum(smooth, raw)
    # Frames within w of an episode boundary: exact, with edge padding inside the episode.
    first = np.repeat(fd.starts, fd.lengths)
    last = np.repeat(fd.ends - 1, fd.lengths)
    t = np.arange(n, dtype=np.int64)
    edge = np.flatnonzero((t - first < w) | (last - t < w))
    if len(edge):
        te, fe, le = t[edge], first[edge], last[edge]
        x_t = _normalised_state(fd, te)
        if x_t.shape[1]:
            before = np.zeros_like(x_t)
            after = np.zeros_like(x_t)
            for k in range(1, w + 1):
                before += _normalised_state(fd, np.maximum(te - k, fe))
                after += _normalised_state(fd, np.minimum(te + k - 1, le))
            prev = np.where(te > fe, te - 1, np.minimum(te + 1, le))  # a first frame: compare with the next
            smooth = np.abs(after - before).max(axis=1) * smooth_scale
            raw = np.abs(x_t - _normalised_state(fd, prev)).max(axis=1) * np.float32(fd.fps)
            speed[edge] = np.minimum(smooth, raw)
    return speed


def idle_runs(idle: np.ndarray, fd: FrameData) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Maximal idle runs that stay inside one episode: ``(start, stop, episode)`` frame indices."""
    n = len(idle)
    ep_start = np.zeros(n, dtype=bool)
    ep_start[fd.starts] = True
    ep_end = np.zeros(n, dtype=bool)
    ep_end[fd.ends - 1] = True
    prev_idle = np.concatenate([[False], idle[:-1]])
    next_idle = np.concatenate([idle[1:], [False]])
    run_start = np.flatnonzero(idle & (ep_start | ~prev_idle))
    run_stop = np.flatnonzero(idle & (ep_end | ~next_idle)) + 1
    episode = np.searchsorted(fd.ends, run_start, side="right")
    return run_start, run_stop, episode


def compute(fd: FrameData, params: IdleParams = IdleParams()) -> dict[str, np.ndarray]:
    """Idle signals per episode (see ``SIGNALS``) plus ``trim_start``/``trim_stop``: the frame range
    (episode-relative) that remains after cutting the idle start/end."""
    e = fd.num_episodes
    lengths = fd.lengths
    idle = frame_speed(fd, params.smooth_s) < params.speed
    rs, re, rep = idle_runs(idle, fd)
    rlen = re - rs
    min_run = max(1, int(round(params.min_run_s * fd.fps)))
    keep_start = int(round(params.keep_start_s * fd.fps))
    keep_end = int(round(params.keep_end_s * fd.fps))
    at_start = rs == fd.starts[rep]
    at_end = re == fd.ends[rep]
    long = rlen >= min_run
    mid = long & ~at_start & ~at_end

    idle_frames = np.bincount(rep, weights=rlen * long, minlength=e)
    start_frames = np.zeros(e, np.int64)
    start_frames[rep[at_start]] = rlen[at_start]
    end_frames = np.zeros(e, np.int64)
    end_frames[rep[at_end]] = rlen[at_end]
    pause_frames = np.bincount(rep, weights=rlen * mid, minlength=e)
    pause_max = np.zeros(e, np.int64)
    np.maximum.at(pause_max, rep[mid], rlen[mid])

    whole = start_frames >= lengths  # idle from the first to the last frame
    trim_start = np.where((start_frames >= min_run) & ~whole, np.maximum(start_frames - keep_start, 0), 0)
    trim_stop = np.where((end_frames >= min_run) & ~whole, lengths - np.maximum(end_frames - keep_end, 0), lengths)
    trim_stop = np.maximum(trim_stop, trim_start + 1)
    remaining = trim_stop - trim_start
    return {
        "idle_fraction": idle_frames / lengths,
        "idle_start_s": start_frames / fd.fps,
        "idle_end_s": end_frames / fd.fps,
        "pause_s": pause_frames / fd.fps,
        "pause_max_s": pause_max / fd.fps,
        "pause_fraction": np.where(whole, 1.0, pause_frames / remaining),
        "trim_start": trim_start.astype(np.int64),
        "trim_stop": trim_stop.astype(np.int64),
    }
