"""Outcome: success, and how narrowly a success was reached (near-miss).

- ``success``: the store's per-episode success flag (1/0), as recorded by the collector/importer.
- ``margin``: distance to the task's success threshold at the end of the episode, in the task's
  units (positive = inside, e.g. metres the cube is lifted above the success height). Read from a
  per-episode ``success_margin`` column or, failing that, the last frame of an ``info.success_margin``
  feature; NaN when the store records neither (the signal is then simply not available).
- ``time_left_s``: seconds between the end of a successful episode and the task's horizon. A
  success reached just before the time limit is a near-miss in time. The horizon is
  ``meta.task["horizon"]`` (control steps) when recorded, else the longest failed episode of the
  task (failures run to the horizon); NaN when neither is known or the episode failed.
"""

from __future__ import annotations

import numpy as np

from demo.curate.signals import Signal
from demo.store import EpisodeStore

SIGNALS = (
    Signal("success", "0/1", "task success flag recorded with the episode"),
    Signal("margin", "task units", "distance to the success threshold at the end (positive = inside); NaN if not recorded"),
    Signal("time_left_s", "s", "time between a successful episode's end and the task horizon; NaN if unknown or failed"),
)
MARGIN_COLUMN = "success_margin"
MARGIN_FEATURE = "info.success_margin"


def compute(store: EpisodeStore) -> dict[str, np.ndarray]:
    e = store.num_episodes
    success = store.column("success").astype(bool)
    lengths = store.episode_lengths
    margin = np.full(e, np.nan)
    if MARGIN_COLUMN in store.table.column_names:
        margin = np.asarray(store.table.column(MARGIN_COLUMN).to_numpy(zero_copy_only=False), dtype=np.float64)
    elif MARGIN_FEATURE in store.meta.features:
        data, ends = store.load([MARGIN_FEATURE])
        values = np.asarray(data[MARGIN_FEATURE], dtype=np.float64).reshape(len(data[MARGIN_FEATURE]), -1)
        margin = values[ends - 1, 0]

    tasks = store.column("task").astype(str)
    horizon = (store.meta.task or {}).get("horizon")
    time_left = np.full(e, np.nan)
    for task in np.unique(tasks):
        sel = tasks == task
        h = float(horizon) if isinstance(horizon, (int, float)) and horizon > 0 else None
        if h is None and (~success[sel]).any():
            h = float(lengths[sel & ~success].max())
        if h is not None:
            ok = sel & success
            time_left[ok] = np.maximum(h - lengths[ok], 0) / store.meta.fps
    return {"success": success.astype(np.float64), "margin": margin, "time_left_s": time_left}
