"""Action consistency: does an episode do what the *other* demonstrators did in similar states?

Inconsistent labels pull a policy in conflicting directions, so this is the signal that matters
most for imitation learning. For a sample of query frames of every episode we find the closest
frame of each of the ``k`` nearest OTHER episodes in normalised observation space and compare what
the demonstrators were doing there.

*What the demonstrator was doing* (the "intent") is, for absolute targets, the rate at which the
target moves over the next quarter second (which way and how fast: two absolute targets in similar
states are nearly equal whatever the operator does, their motion is not), and the action itself for
rate/delta representations. Each intent dimension is divided by its typical range (how far it
moves within a typical episode, see :mod:`demo.curate.frames`).

Per query frame, the others' *consensus* is the mean intent of its neighbours, their *spread* the
sample standard deviation of their intents around it (RMS over dims; how much honest
demonstrators differ there, scaled by ``1 + 1/n`` so that a query drawn like the others has the
same expected squared deviation), and the query's *deviation* the RMS distance of its own intent
from the consensus. A frame is judged only with at least ``min_neighbours`` (3) neighbours within
``radius_factor`` (2) times the store's median distance to the ``min_neighbours``-th nearest
episode: where nobody else demonstrated a similar state, a different action is no contradiction.

- ``disagreement`` (range units, >= 0): mean deviation over the judged query frames.
  0 = does exactly what the others do.
- ``consistency`` (fraction [0..1]): share of judged query frames that *agree*: deviation at most
  ``agree_factor`` (3) times the local spread (floored at half the store's median spread, so
  that identical experts do not make every tiny difference a disagreement). For a demonstrator
  who behaves like the others, a frame disagrees by chance with probability <= 10% (1-D intent,
  3 neighbours) and far less with more neighbours or dimensions. Relative to the local
  spread, it adapts to sparse data (farther neighbours differ more) and to multimodal behaviour
  (where demonstrators split left/right, the spread is large and neither mode is flagged), while a
  demonstrator who contradicts a tight consensus is. 1 = agrees everywhere it can be judged.
- ``novelty`` (normalised obs units): mean distance from the query frames to the nearest frame
  of another episode, i.e. how far the episode strays from states the others visit.
- ``coverage`` (fraction [0..1]): share of query frames that could be judged.

Scaling: observations are projected on their top ``dims`` principal components, and the nearest
neighbours are searched in a grid over the top ``grid_dims`` components whose bins hold equal
shares of the frames (two grids, the second shifted by half a bin, so that a query near a bin edge
still sees both sides). Each query compares against at most ``max_candidates`` frames of its cell,
so the cost is O(N) in the frames plus O(Q * max_candidates) for Q queries, never O(N^2).
Numpy only; approximate: on a 200k-frame synthetic store the 3rd (8th) neighbour found is a median
13% (21%) farther than the true 3rd (8th) nearest episode (twice the cell size: 9% (16%), at twice
the cost); the tests compare it with brute force.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from demo.curate.frames import FrameData
from demo.curate.signals import Signal

SIGNALS = (
    Signal("consistency", "fraction [0..1]",
           "share of sampled frames whose action agrees with the other episodes' consensus in similar states"),
    Signal("disagreement", "range units",
           "mean RMS difference between the episode's action intent and the other episodes' consensus"),
    Signal("novelty", "normalised obs units", "mean distance from sampled frames to the nearest frame of another episode"),
    Signal("coverage", "fraction [0..1]", "share of sampled frames with other episodes' frames close enough to judge consistency"),
)


@dataclass(frozen=True)
class ConsistencyParams:
    k: int = 8  # neighbours per query frame
    queries: int = 24  # query frames per episode (evenly spaced, random phase from the seed)
    agree_factor: float = 3.0  # a query agrees when it deviates <= this x the others' own spread there
    min_neighbours: int = 3  # other episodes needed near a query frame to judge it
    dims: int = 8  # principal components of the observation kept for distances
    grid_dims: int = 3  # components the grid is built on
    cell_frames: int = 256  # target reference frames per grid cell
    max_candidates: int = 1024  # candidates per cell (a random subset of bigger cells)
    ref_step_s: float = 0.1  # s between the reference frames taken from each episode
    radius_factor: float = 2.0  # neighbours count within this x the store's median distance to the m-th nearest episode
    seed: int = 0


def intent(fd: FrameData, window_s: float = 0.25) -> np.ndarray:
    """[N, A] float32 per-frame action intent divided by its typical range (see module doc).

    For absolute targets: where the target is heading over the next ``window_s``,
    ``(a[t + w] - a[t]) * fps / w`` (clipped at the episode's last frame). Looking a quarter second
    ahead rather than one frame averages out jitter, which the jerk signal already measures, and
    keeps what the operator is *doing*.
    """
    if fd.action_is_delta:
        x = fd.action.copy()
    else:
        n = fd.num_frames
        w = max(1, int(round(window_s * fd.fps)))
        t = np.arange(n, dtype=np.int64)
        last = np.repeat(fd.ends - 1, fd.lengths)
        ahead = np.minimum(t + w, last)
        steps = np.maximum(ahead - t, 1).astype(np.float32)
        x = (fd.action[ahead] - fd.action) * (np.float32(fd.fps) / steps)[:, None]
    inv = 1.0 / fd.typical_range(x)
    return (x * inv.astype(np.float32)).astype(np.float32)


def embed(fd: FrameData, dims: int, rng: np.random.Generator) -> np.ndarray:
    """[N, p] float32: observations divided by their typical range, centred, on their top ``p``
    principal axes (the axes from a random sample of 20,000 frames)."""
    r = fd.obs_range
    keep = np.isfinite(r)
    if not keep.any():
        return np.zeros((fd.num_frames, 0), np.float32)
    inv = (1.0 / r[keep]).astype(np.float32)
    sample = fd.obs[np.sort(rng.choice(fd.num_frames, size=min(fd.num_frames, 20_000), replace=False))][:, keep] * inv
    mean = sample.mean(axis=0)
    _, _, vt = np.linalg.svd(sample - mean, full_matrices=False)
    p = min(dims, vt.shape[0])
    # Fold the normalisation into the projection: z = (obs * inv - mean) @ V = obs @ (inv V) - mean @ V.
    proj = (inv[:, None] * vt[:p].T).astype(np.float32)
    obs = fd.obs if keep.all() else fd.obs[:, keep]
    return obs @ proj - (mean @ vt[:p].T).astype(np.float32)


def sample_queries(fd: FrameData, per_episode: int, rng: np.random.Generator) -> np.ndarray:
    """Frame indices: up to ``per_episode`` evenly spaced frames per episode, random phase."""
    lengths = fd.lengths
    q = np.minimum(lengths, per_episode)
    ep = np.repeat(np.arange(fd.num_episodes), q)
    slot = np.arange(q.sum()) - np.repeat(np.cumsum(q) - q, q)
    step = lengths[ep] / q[ep]
    offset = (slot + rng.random(len(slot))) * step
    return fd.starts[ep] + np.minimum(offset.astype(np.int64), lengths[ep] - 1)


def _bin_edges(z: np.ndarray, bins: int, shift: float) -> np.ndarray:
    """Equal-frequency bin edges per column, optionally shifted by a fraction of a bin."""
    qs = (np.arange(1, bins) - shift) / bins
    qs = qs[(qs > 0) & (qs < 1)]
    return np.quantile(z[:: max(1, len(z) // 100_000)], qs, axis=0).T  # [g, bins-1]


def _cells(z: np.ndarray, edges: np.ndarray) -> np.ndarray:
    cell = np.zeros(len(z), dtype=np.int64)
    for j in range(edges.shape[0]):
        cell = cell * (edges.shape[1] + 1) + np.searchsorted(edges[j], z[:, j], side="right")
    return cell


def grid_knn(
    z: np.ndarray,
    episode: np.ndarray,
    queries: np.ndarray,
    params: ConsistencyParams,
    shift: float,
    rng: np.random.Generator,
    ref: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Approximate nearest frames of ``k`` *different* other episodes for each query frame (the
    closest frame of each), searched among the frames ``ref`` (all when None):
    ``(dist [Q,k], frame index [Q,k])``, ``inf`` / ``-1`` where a cell holds fewer episodes.

    One frame per episode, because the frames of a single nearby trajectory would otherwise fill
    all ``k`` places and one odd demonstration would decide the verdict."""
    ref = np.arange(len(z)) if ref is None else ref
    zr, er = z[ref], episode[ref]
    n, k = len(ref), params.k
    g = min(params.grid_dims, z.shape[1])
    bins = max(1, int(round((n / params.cell_frames) ** (1.0 / max(g, 1))))) if g else 1
    edges = _bin_edges(zr[:, :g], bins, shift) if g and bins > 1 else np.zeros((0, 0))
    cell = _cells(zr[:, :g], edges) if edges.size else np.zeros(n, np.int64)
    order = np.argsort(cell, kind="stable")  # within a cell: frame order, so episodes are contiguous
    sorted_cells = cell[order]
    zq_all, eq_all = z[queries], episode[queries]
    q_cell = _cells(zq_all[:, :g], edges) if edges.size else np.zeros(len(queries), np.int64)
    q_order = np.argsort(q_cell, kind="stable")
    uniq, q_first = np.unique(q_cell[q_order], return_index=True)
    q_bounds = np.append(q_first, len(queries))
    lo = np.searchsorted(sorted_cells, uniq, side="left")
    hi = np.searchsorted(sorted_cells, uniq, side="right")
    dist = np.full((len(queries), k), np.inf, dtype=np.float32)
    index = np.full((len(queries), k), -1, dtype=np.int64)
    sq = (zr * zr).sum(axis=1)
    for c in range(len(uniq)):
        cand = order[lo[c]:hi[c]]
        if len(cand) == 0:
            continue
        if len(cand) > params.max_candidates:
            cand = np.sort(cand[rng.choice(len(cand), size=params.max_candidates, replace=False)])
        qi = q_order[q_bounds[c]:q_bounds[c + 1]]
        zq = zq_all[qi]
        d2 = sq[cand][None, :] - 2.0 * (zq @ zr[cand].T)  # + |zq|^2, added after the selection
        # Per (query, episode): the closest frame of that episode.
        ce = er[cand]
        group = np.flatnonzero(np.r_[True, ce[1:] != ce[:-1]])
        size = np.diff(np.r_[group, len(cand)])
        gmin = np.minimum.reduceat(d2, group, axis=1)  # [q, G]
        gmin[eq_all[qi][:, None] == ce[group][None, :]] = np.inf  # never the query's own episode
        kk = min(k, len(group))
        part = np.argpartition(gmin, kk - 1, axis=1)[:, :kk] if kk < len(group) else np.broadcast_to(np.arange(kk), (len(qi), kk))
        pd = np.take_along_axis(gmin, part, axis=1)
        # The closest frame inside each chosen episode: a small gather over that group's columns.
        width = int(size[part].max())
        cols = group[part][:, :, None] + np.arange(width)  # [q, kk, width]
        inside = np.arange(width) < size[part][:, :, None]
        flat = np.minimum(cols, len(cand) - 1).reshape(len(qi), -1)
        vals = np.where(inside, np.take_along_axis(d2, flat, axis=1).reshape(cols.shape), np.inf)
        col = np.take_along_axis(cols, vals.argmin(axis=2)[:, :, None], axis=2)[:, :, 0]
        pd = pd + (zq * zq).sum(axis=1)[:, None]
        dist[qi, :kk] = np.sqrt(np.maximum(pd, 0.0))
        index[qi, :kk] = np.where(np.isfinite(pd), ref[cand[col]], -1)
    return dist, index


def merge_knn(
    a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray], k: int, episode: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` best of two neighbour lists per query, each episode once (its closer frame)."""
    dist = np.concatenate([a[0], b[0]], axis=1)
    index = np.concatenate([a[1], b[1]], axis=1)
    key = np.where(index >= 0, episode[np.maximum(index, 0)], -1)
    by_dist = np.argsort(dist, axis=1, kind="stable")
    dist, index, key = (np.take_along_axis(x, by_dist, axis=1) for x in (dist, index, key))
    by_key = np.argsort(key, axis=1, kind="stable")  # same episode: adjacent, closer first
    dist, index, key = (np.take_along_axis(x, by_key, axis=1) for x in (dist, index, key))
    dup = np.zeros_like(index, dtype=bool)
    dup[:, 1:] = (key[:, 1:] == key[:, :-1]) & (key[:, 1:] >= 0)
    dist[dup] = np.inf
    index[dup] = -1
    order = np.argsort(dist, axis=1, kind="stable")[:, :k]
    return np.take_along_axis(dist, order, axis=1), np.take_along_axis(index, order, axis=1)


def _rms(x: np.ndarray) -> np.ndarray:
    """RMS over the last axis."""
    return np.sqrt((x * x).mean(axis=-1))


def judge(own: np.ndarray, nb: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(deviation, spread)`` [Q] of each query's intent ``own`` [Q, A] from its neighbours'
    ``nb`` [Q, k, A] (``valid`` [Q, k] marks the ones that count); see the module doc."""
    c = valid.sum(axis=1)
    nb = np.where(valid[:, :, None], nb, 0.0)
    consensus = nb.sum(axis=1) / np.maximum(c, 1)[:, None]  # mean intent of the others
    dev = _rms(own - consensus)
    sq = np.where(valid, _rms(nb - consensus[:, None, :]) ** 2, 0.0).sum(axis=1)
    # Sample spread of the others, scaled so that a query drawn like them has E[dev^2] = spread^2.
    spread = np.sqrt(sq / np.maximum(c - 1, 1) * (1.0 + 1.0 / np.maximum(c, 1)))
    return dev, spread


def compute(fd: FrameData, params: ConsistencyParams = ConsistencyParams()) -> dict[str, np.ndarray]:
    """``consistency``, ``disagreement``, ``novelty``, ``coverage`` per episode; NaN where not
    computable (no low-dim observations, a single episode, or no frame could be judged). ``spread_floor`` (the
    same for every episode) is the floor of the local spread, in range units."""
    e = fd.num_episodes
    nan = np.full(e, np.nan)
    if fd.obs.shape[1] == 0 or e < 2:
        return {k: nan.copy() for k in ("consistency", "disagreement", "novelty", "coverage", "spread_floor")}
    rng = np.random.default_rng(params.seed)
    z = embed(fd, params.dims, rng)
    if z.shape[1] == 0:
        return {k: nan.copy() for k in ("consistency", "disagreement", "novelty", "coverage", "spread_floor")}
    episode = fd.episode_of_frame()
    queries = sample_queries(fd, params.queries, rng)
    # Neighbours come from every ``stride``-th frame: consecutive frames are nearly the same state,
    # and thinning them lets a cell of the same size span more of the state space.
    stride = max(1, int(round(params.ref_step_s * fd.fps)))
    ref = np.flatnonzero((np.arange(fd.num_frames) - np.repeat(fd.starts, fd.lengths)) % stride == 0)
    # ... and not from standing still: a held state repeated for seconds would crowd a cell with
    # copies of one frame. Keep a reference frame only if the state moved since the previous one.
    step = np.linalg.norm(z[ref[1:]] - z[ref[:-1]], axis=1)
    new_episode = episode[ref[1:]] != episode[ref[:-1]]
    moved = step > 0.05 * float(np.median(step[~new_episode])) if (~new_episode).any() else np.ones(len(step), bool)
    ref = ref[np.r_[True, moved | new_episode]]
    knn = grid_knn(z, episode, queries, params, 0.0, rng, ref)
    dist, index = merge_knn(knn, grid_knn(z, episode, queries, params, 0.5, rng, ref), params.k, episode)

    # Judge only where others demonstrated similar states: neighbours farther than ``radius_factor``
    # times the store's median distance to the m-th nearest other episode do not count (an unusual
    # goal has far neighbours and honestly different actions; novelty reports such episodes).
    found = index >= 0
    nearest = dist[:, 0]
    mth = dist[:, min(params.min_neighbours, params.k) - 1]  # distance to the m-th other episode
    radius = params.radius_factor * float(np.median(mth[np.isfinite(mth)])) if np.isfinite(mth).any() else 0.0
    close = found & (dist <= radius)
    c = close.sum(axis=1)
    act = intent(fd)
    dev, spread = judge(act[queries], act[np.where(close, index, 0)], close)
    judged = c >= params.min_neighbours
    floor = 0.5 * float(np.median(spread[judged])) if judged.any() else 0.0
    agree = dev <= params.agree_factor * np.maximum(spread, floor)

    q_ep = episode[queries]
    count = np.bincount(q_ep[judged], minlength=e).astype(np.float64)
    asked = np.bincount(q_ep, minlength=e).astype(np.float64)
    has_nn = np.isfinite(nearest)
    with np.errstate(invalid="ignore", divide="ignore"):
        disagreement = np.bincount(q_ep[judged], weights=dev[judged], minlength=e) / count
        consistency = np.bincount(q_ep[judged], weights=agree[judged], minlength=e) / count
        novelty = np.bincount(q_ep[has_nn], weights=nearest[has_nn], minlength=e) / np.bincount(q_ep[has_nn], minlength=e)
        coverage = count / asked
    return {"consistency": consistency, "disagreement": disagreement, "novelty": novelty, "coverage": coverage,
            "spread_floor": np.full(e, floor)}
