"""Duplicates and near-duplicates: episodes recorded twice (same seed replayed, a file merged twice).

Each episode gets a fingerprint: its actions and low-dim observations, each dimension divided by
its typical range (see :mod:`demo.curate.frames`), sampled at ``samples`` evenly spaced instants. Two episodes are
duplicates when the RMS difference of their fingerprints (``dup_distance``, in range units) is at
most ``tol`` and their lengths differ by at most ``length_tol`` (relative). Duplicates form groups
(a chain a~b~c is one group); the first episode of a group is the original, the others are
flagged with ``dup_of`` = that original.

Cost: one [E, E] distance pass over the fingerprints in blocks (E = episodes, not frames), about a
second for 5,000 episodes; pairs under the tolerance are re-measured exactly (the block pass uses
the fast ``|a|^2 + |b|^2 - 2ab`` form, which loses precision near zero).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from demo.curate.frames import FrameData
from demo.curate.signals import Signal

SIGNALS = (
    Signal("dup_distance", "range units", "RMS fingerprint difference to the most similar other episode"),
    Signal("dup_of", "episode index", "original this episode duplicates (-1 if none)"),
)
BLOCK = 1024


@dataclass(frozen=True)
class DuplicateParams:
    tol: float = 0.003  # range units (RMS over the fingerprint)
    length_tol: float = 0.05  # relative length difference allowed between duplicates
    samples: int = 16  # instants per fingerprint


def fingerprints(fd: FrameData, samples: int) -> np.ndarray:
    """[E, samples * (A + D)] float32, centred (smaller norms keep the block pass precise)."""
    frac = (np.arange(samples) + 0.5) / samples
    idx = (fd.starts[:, None] + np.minimum((frac[None, :] * fd.lengths[:, None]).astype(np.int64), fd.lengths[:, None] - 1)).ravel()
    inv = 1.0 / np.concatenate([fd.action_range, fd.obs_range])
    inv[~np.isfinite(inv)] = 0.0
    x = np.concatenate([fd.action[idx], fd.obs[idx]], axis=1) * inv.astype(np.float32)
    f = x.reshape(fd.num_episodes, -1)
    return (f - f.mean(axis=0)).astype(np.float32)


def _rms(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = a.astype(np.float64) - b.astype(np.float64)
    return np.sqrt((d * d).mean(axis=-1))


def compute(fd: FrameData, params: DuplicateParams = DuplicateParams()) -> dict[str, np.ndarray]:
    e = fd.num_episodes
    f = fingerprints(fd, params.samples)
    m = f.shape[1]
    sq = np.einsum("ij,ij->i", f, f)
    nearest = np.full(e, -1, dtype=np.int64)
    nearest_d = np.full(e, np.inf)
    log_len = np.log(fd.lengths.astype(np.float64))
    # Screen generously: the float32 block pass's absolute error is ~1e-6 * |f|^2 per element.
    screen = (params.tol * 1.5) ** 2 * m + 1e-4 * (sq.max() if e else 0.0)
    pairs: list[np.ndarray] = []
    for a in range(0, e, BLOCK):
        b = min(e, a + BLOCK)
        d2 = sq[a:b, None] + sq[None, :] - 2.0 * (f[a:b] @ f.T)
        d2[np.arange(b - a), np.arange(a, b)] = np.inf
        j = np.argmin(d2, axis=1)
        nearest[a:b] = j
        nearest_d[a:b] = d2[np.arange(b - a), j]
        close = np.argwhere(d2 <= screen)
        if len(close):
            pairs.append(np.stack([close[:, 0] + a, close[:, 1]], axis=1))
    if e > 1:
        nearest_d = _rms(f, f[nearest])
    else:
        nearest_d[:] = np.nan

    parent = np.arange(e)

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    if pairs:
        cand = np.concatenate(pairs)
        cand = cand[cand[:, 0] < cand[:, 1]]
        ok = (_rms(f[cand[:, 0]], f[cand[:, 1]]) <= params.tol) & (
            np.abs(log_len[cand[:, 0]] - log_len[cand[:, 1]]) <= np.log1p(params.length_tol)
        )
        for i, j in cand[ok]:
            ri, rj = root(int(i)), root(int(j))
            if ri != rj:
                parent[max(ri, rj)] = min(ri, rj)  # the earliest episode stays the root
    dup_of = np.array([root(i) for i in range(e)], dtype=np.int64)
    dup_of[dup_of == np.arange(e)] = -1
    return {"dup_distance": nearest_d, "dup_of": dup_of.astype(np.float64)}
