"""Length outliers: episodes much longer or shorter than the others of the same task.

``length_z`` is a robust z-score of the log length, ``(log L - median) / (1.4826 * MAD)`` over the
episodes of the same task (log, so that twice as long and half as long are equally unusual;
median and MAD, so that the outliers do not hide themselves by inflating a standard deviation).
Dimensionless; |z| > 3.5 is the usual robust-outlier rule. A task whose lengths barely vary
(MAD of ~0) uses a floor of 5% of the length so that one frame of difference is not an outlier.
"""

from __future__ import annotations

import numpy as np

from demo.curate.signals import Signal

SIGNALS = (Signal("length_z", "robust z (MAD units)", "log-length distance from the task's median length"),)
MIN_SPREAD = 0.05  # log units: 5% of the length


def compute(lengths: np.ndarray, tasks: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """``length_z`` [E] per episode, grouped by ``tasks`` (one group when None)."""
    log_len = np.log(np.asarray(lengths, dtype=np.float64))
    groups = np.zeros(len(log_len), dtype=np.int64) if tasks is None else np.unique(np.asarray(tasks).astype(str), return_inverse=True)[1]
    z = np.zeros_like(log_len)
    for g in np.unique(groups):
        sel = groups == g
        med = np.median(log_len[sel])
        mad = 1.4826 * np.median(np.abs(log_len[sel] - med))
        z[sel] = (log_len[sel] - med) / max(mad, MIN_SPREAD)
    return {"length_z": z}
