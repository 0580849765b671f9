"""The episode table: one parquet row per episode, rewritten atomically on every change.

Fixed columns (always present):

=============  =======  ===========================================================
episode_index  int64    0-based, equals the row number
start          int64    first frame of the episode in the concatenated arrays
length         int64    frames in the episode
success        bool     task success predicate at the end of the episode
seed           int64    seed of the episode's initial state (-1 when unknown)
source         string   scripted / kinesthetic / vr / dagger / imported / ...
operator       string   who or what produced it (expert, good, okay, poor, a name)
task           string   task name
duration_s     float64  length / fps, in seconds of robot time
crc32          int64    CRC-32 of the episode's bytes, features in metadata order
=============  =======  ===========================================================

Any other column is allowed: ``mask.<name>`` (bool) columns are named subsets, like robomimic's
filter keys; ``score.<name>`` (float64) columns hold curation signals; anything else is free
per-episode info (for example ``dagger_round``; ``instruction``, what the episode was told to do in
words: :mod:`demo.store.instructions`). Rewriting a few thousand rows takes milliseconds.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from demo.errors import DemoError
from demo.jsonio import replace_atomically
from demo.store.location import Remote, StorePath

FIXED_COLUMNS: dict[str, pa.DataType] = {
    "episode_index": pa.int64(),
    "start": pa.int64(),
    "length": pa.int64(),
    "success": pa.bool_(),
    "seed": pa.int64(),
    "source": pa.string(),
    "operator": pa.string(),
    "task": pa.string(),
    "duration_s": pa.float64(),
    "crc32": pa.int64(),
}
MASK_PREFIX = "mask."
SCORE_PREFIX = "score."
REASONS_COLUMN = "curate.reasons"  # why curation dropped each episode ("" = kept), written by `demo curate --mask`


def empty_table() -> pa.Table:
    return pa.table({k: pa.array([], type=t) for k, t in FIXED_COLUMNS.items()})


def make_row(info: dict[str, Any]) -> pa.Table:
    """One-row table from an info dict; fixed columns get their declared types."""
    columns: dict[str, pa.Array] = {}
    for key, value in info.items():
        if key in FIXED_COLUMNS:
            columns[key] = pa.array([value], type=FIXED_COLUMNS[key])
        elif key.startswith(MASK_PREFIX):
            columns[key] = pa.array([bool(value)], type=pa.bool_())
        elif key.startswith(SCORE_PREFIX):
            columns[key] = pa.array([float(value)], type=pa.float64())
        else:
            if isinstance(value, np.generic):
                value = value.item()
            if not isinstance(value, (bool, int, float, str, type(None))):
                raise DemoError(None, f"episode info {key!r} must be a scalar, got {type(value).__name__}")
            columns[key] = pa.array([value])
    return pa.table(columns)


def append_row(table: pa.Table, row: pa.Table) -> pa.Table:
    """Append a row, adding missing columns on either side as nulls (False for masks)."""
    merged = pa.concat_tables([table, row], promote_options="permissive")
    for name in merged.column_names:
        if name.startswith(MASK_PREFIX) and merged.column(name).null_count:
            merged = set_column(merged, name, merged.column(name).fill_null(False))
    return merged


def set_column(table: pa.Table, name: str, values: Any) -> pa.Table:
    array = values if isinstance(values, (pa.Array, pa.ChunkedArray)) else pa.array(values)
    if name in table.column_names:
        return table.set_column(table.column_names.index(name), name, array)
    return table.append_column(name, array)


def write_atomic(table: pa.Table, path: StorePath) -> None:
    """Write the table next to ``path`` and rename it over (:func:`demo.jsonio.replace_atomically`), or
    on object storage PUT it whole: either way readers see the old or the new table, and a failed
    write leaves the old one."""
    if isinstance(path, Remote):
        sink = pa.BufferOutputStream()
        _write(table, sink)
        path.write_bytes(sink.getvalue().to_pybytes())
        return
    replace_atomically(path, lambda tmp: _write(table, tmp))


def _write(table: pa.Table, where: Any) -> None:
    # Rewritten at every commit: plain encoding writes it in ~half the time, and it stays small.
    pq.write_table(table, where, compression="none", use_dictionary=False, write_statistics=False)


def read(path: StorePath) -> pa.Table:
    try:
        # One file, read as one: pq.read_table would import pyarrow.dataset (0.1 s of `demo info`) to find it.
        with pq.ParquetFile(pa.BufferReader(path.read_bytes()) if isinstance(path, Remote) else path) as file:
            table = file.read()
    except FileNotFoundError:
        raise DemoError(path, "episode table is missing") from None
    except (pa.ArrowInvalid, OSError) as exc:
        raise DemoError(path, f"episode table is corrupted ({str(exc).splitlines()[0]})") from None
    missing = [c for c in FIXED_COLUMNS if c not in table.column_names]
    if missing:
        raise DemoError(path, f"episode table lacks column(s) {', '.join(missing)}")
    wrong = [f"{c} is {table.schema.field(c).type}" for c, t in FIXED_COLUMNS.items() if table.schema.field(c).type != t]
    if wrong:
        raise DemoError(path, f"episode table column types differ from the format's: {', '.join(wrong)}")
    empty = [c for c in ("episode_index", "start", "length", "success", "crc32") if table.column(c).null_count]
    if empty:
        raise DemoError(path, f"episode table has missing values in {', '.join(empty)}")
    lengths, starts = table.column("length").to_numpy(), table.column("start").to_numpy()
    if len(lengths) and (lengths.min() < 0 or not np.array_equal(starts, np.cumsum(lengths) - lengths)):
        raise DemoError(path, "episode table is inconsistent: a negative length, or a start that is not the end of "
                              "the episode before")
    return table
