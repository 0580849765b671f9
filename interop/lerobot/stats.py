"""Feature statistics in LeRobot v3.0's layout (``meta/stats.json`` and the episodes' ``stats/*`` columns).

Per feature: ``min``, ``max``, ``mean``, ``std``, ``count`` and the quantiles ``q01 q10 q50 q90 q99``.
Low-dimensional features get one value per dimension (shape = the feature's shape; scalars ``[1]``).
Camera images get one value per channel, shaped ``[C, 1, 1]`` and scaled to ``[0, 1]`` as LeRobot
does. Dataset statistics are aggregated from the episodes' like LeRobot's ``aggregate_stats``:
min/max/mean/std are exact, low-dim quantiles are count-weighted means of the episodes' quantiles
(LeRobot's approximation); image statistics come from summed 256-bin histograms, so they are exact.
"""

from __future__ import annotations

from typing import Any

import numpy as np

QUANTILES: tuple[tuple[str, float], ...] = (("q01", 0.01), ("q10", 0.10), ("q50", 0.50), ("q90", 0.90), ("q99", 0.99))
STAT_NAMES: tuple[str, ...] = ("min", "max", "mean", "std", "count", *(name for name, _ in QUANTILES))


def lowdim_stats(values: np.ndarray) -> dict[str, np.ndarray]:
    """Statistics over frames of ``values[T, *shape]`` (float64, one entry per dimension)."""
    n = len(values)
    flat = values.reshape(n, -1).astype(np.float64)
    shape = values.shape[1:] or (1,)
    stats = {
        "min": flat.min(axis=0),
        "max": flat.max(axis=0),
        "mean": flat.mean(axis=0),
        "std": flat.std(axis=0),
    }
    quantiles = np.quantile(flat, [q for _, q in QUANTILES], axis=0)
    stats.update({name: quantiles[i] for i, (name, _) in enumerate(QUANTILES)})
    out = {k: v.reshape(shape) for k, v in stats.items()}
    out["count"] = np.array([n], dtype=np.int64)
    return out


def image_histogram(images: np.ndarray) -> np.ndarray:
    """Per-channel 256-bin histogram of uint8 images ``[T, H, W, C]`` -> int64 ``[C, 256]``."""
    channels = images.shape[-1]
    pixels = images.reshape(-1, channels)
    return np.stack([np.bincount(pixels[:, c], minlength=256) for c in range(channels)]).astype(np.int64)


def histogram_stats(hist: np.ndarray, frames: int) -> dict[str, np.ndarray]:
    """Image statistics from a ``[C, 256]`` histogram, in ``[0, 1]``, shaped ``[C, 1, 1]``.

    Quantiles use the same linear interpolation as ``np.quantile`` over the sorted pixel values.
    """
    levels = np.arange(256, dtype=np.float64)
    out: dict[str, list[float]] = {name: [] for name in STAT_NAMES if name != "count"}
    for h in hist:
        n = int(h.sum())
        present = np.flatnonzero(h)
        mean = float((h * levels).sum() / n)
        out["min"].append(float(present[0]))
        out["max"].append(float(present[-1]))
        out["mean"].append(mean)
        out["std"].append(float(np.sqrt((h * (levels - mean) ** 2).sum() / n)))
        cum = np.cumsum(h)
        for name, q in QUANTILES:
            pos = q * (n - 1)
            lo, hi = int(np.floor(pos)), int(np.ceil(pos))
            v_lo = float(np.searchsorted(cum, lo, side="right"))
            v_hi = float(np.searchsorted(cum, hi, side="right"))
            out[name].append(v_lo + (pos - lo) * (v_hi - v_lo))
    stats = {k: np.asarray(v, dtype=np.float64).reshape(-1, 1, 1) / 255.0 for k, v in out.items()}
    stats["count"] = np.array([frames], dtype=np.int64)
    return stats


class StatsAccumulator:
    """Collects one feature's statistics episode by episode; :meth:`result` gives the dataset's."""

    def __init__(self, image: bool):
        self.image = image
        self._episodes: list[dict[str, np.ndarray]] = []
        self._hist: np.ndarray | None = None
        self._frames = 0

    def add(self, values: np.ndarray) -> dict[str, np.ndarray]:
        """Add one episode's frames; return that episode's statistics."""
        if self.image:
            hist = image_histogram(values)
            self._hist = hist if self._hist is None else self._hist + hist
            self._frames += len(values)
            return histogram_stats(hist, len(values))
        stats = lowdim_stats(values)
        self._episodes.append(stats)
        return stats

    def result(self) -> dict[str, np.ndarray]:
        if self.image:
            assert self._hist is not None, "no episodes added"
            return histogram_stats(self._hist, self._frames)
        return aggregate(self._episodes)


def aggregate(episodes: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """Combine per-episode low-dim statistics (exact mean/std via the pooled variance)."""
    counts = np.array([int(s["count"][0]) for s in episodes], dtype=np.float64)
    total = counts.sum()
    w = counts.reshape(-1, *([1] * episodes[0]["mean"].ndim)) / total
    means = np.stack([s["mean"] for s in episodes])
    mean = (w * means).sum(axis=0)
    var = (w * (np.stack([s["std"] for s in episodes]) ** 2 + (means - mean) ** 2)).sum(axis=0)
    out = {
        "min": np.min(np.stack([s["min"] for s in episodes]), axis=0),
        "max": np.max(np.stack([s["max"] for s in episodes]), axis=0),
        "mean": mean,
        "std": np.sqrt(np.maximum(var, 0.0)),
        "count": np.array([int(total)], dtype=np.int64),
    }
    for name, _ in QUANTILES:
        out[name] = (w * np.stack([s[name] for s in episodes])).sum(axis=0)
    return out


def to_json(stats: dict[str, np.ndarray]) -> dict[str, Any]:
    """Plain lists in LeRobot's stat order."""
    return {k: np.asarray(stats[k]).tolist() for k in STAT_NAMES}
