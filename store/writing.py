"""Writing a store: appending episodes (validated, then frames, ``meta/episode_ends`` and last the
episode table: the commit), per-episode columns and masks, metadata edits, and growing or trimming
the arrays' spare capacity. A mixin of :class:`~demo.store.episode_store.EpisodeStore`, whose module
docstring describes the commit protocol.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import zarr

from demo.errors import DemoError, first_line
from demo.store import episode_table
from demo.store.chunk_writer import RowWriter
from demo.store.layout import TABLE_FILE
from demo.store.location import Remote, StorePath, remote_problem
from demo.store.spec import StoreMeta
from demo.store.zarr_io import run_concurrently


class StoreWriting:
    """Everything that writes into an open store (see :class:`~demo.store.episode_store.EpisodeStore`)."""

    path: StorePath
    meta: StoreMeta
    _dir: StorePath
    _table: pa.Table
    _root: zarr.Group
    _staged: bool
    _atomic: bool
    _wrote: bool
    _row_writers: dict[str, RowWriter | None]

    # ------------------------------------------------------------------ masks, per-episode columns, metadata
    def set_mask(self, name: str, values: Sequence[bool] | np.ndarray) -> None:
        values = np.asarray(values, dtype=bool)
        if values.shape != (self.num_episodes,):
            raise DemoError(self.path, f"mask {name!r} has {values.size} entries for {self.num_episodes} episodes")
        self.set_column(episode_table.MASK_PREFIX + name, values)

    def set_column(self, name: str, values: Sequence[Any] | np.ndarray) -> None:
        """Add or replace a per-episode column (scores, flags, ...); fixed columns are read-only."""
        self._require_writable()
        if name in episode_table.FIXED_COLUMNS and name not in ("success", "operator", "source"):
            raise DemoError(self.path, f"column {name!r} is managed by the store")
        values = list(values) if not isinstance(values, np.ndarray) else values
        if len(values) != self.num_episodes:
            raise DemoError(self.path, f"column {name!r} has {len(values)} values for {self.num_episodes} episodes")
        table = episode_table.set_column(self._table, name, values)
        self._commit(table)
        self._table = table

    def update_meta(self, **changes: Any) -> None:
        """Replace root metadata fields (``provenance``, ``extra``, ``task``, ``robot``)."""
        self._require_writable()
        for key, value in changes.items():
            if key not in ("provenance", "extra", "task", "robot"):
                raise ValueError(f"metadata field {key!r} cannot be changed after creation")
            setattr(self.meta, key, value)
        self._root.attrs["demo"] = self.meta.to_json()

    # ------------------------------------------------------------------ writing
    def _require_writable(self) -> None:
        if not self.writable:
            raise DemoError(self.path, "is open read-only")

    def _validate(self, data: dict[str, np.ndarray], where: object) -> tuple[dict[str, np.ndarray], int]:
        """The episode's arrays in the store's dtypes, and its length; DemoError naming ``where`` if unfit."""
        expected = set(self.meta.features)
        given = set(data)
        if given != expected:
            missing, unknown = sorted(expected - given), sorted(given - expected)
            parts = ([f"missing {', '.join(missing)}"] if missing else []) + (
                [f"unknown {', '.join(unknown)}"] if unknown else []
            )
            raise DemoError(where, f"episode keys do not match the store's features: {'; '.join(parts)}")
        lengths = {k: len(v) for k, v in data.items()}
        if len(set(lengths.values())) != 1:
            raise DemoError(where, f"episode arrays have mismatched lengths: {lengths}")
        length = next(iter(lengths.values()))
        if length == 0:
            raise DemoError(where, "episode is empty")
        out = {}
        for key, spec in self.meta.features.items():
            arr = np.asarray(data[key])
            if arr.shape[1:] != spec.shape:
                raise DemoError(where, f"{key}: frame shape {arr.shape[1:]} does not match {spec.shape}")
            if arr.dtype.kind == "f" and not np.isfinite(arr).all():
                bad = int(np.flatnonzero(~np.isfinite(arr.reshape(length, -1)).all(axis=1))[0])
                raise DemoError(where, f"{key}: non-finite value (NaN or inf) at frame {bad}")
            if arr.dtype != spec.np_dtype:
                if not np.can_cast(arr.dtype, spec.np_dtype, casting="same_kind"):
                    raise DemoError(where, f"{key}: dtype {arr.dtype} cannot be stored as {spec.dtype}")
                arr = arr.astype(spec.np_dtype)
            out[key] = arr
        return out, length

    def _trim_to_committed(self) -> None:
        """Shrink every array to the committed frames (drops spare capacity and uncommitted tails)."""
        total, n = self.num_frames, self.num_episodes
        resizes = [(self.array(k), (total, *self.array(k).shape[1:])) for k in self.meta.features]
        resizes.append((self._ends_array(), (n,)))
        run_concurrently([a.async_array.resize(shape) for a, shape in resizes if a.shape != shape])

    def _ensure_capacity(self, frames: int, episodes: int) -> None:
        """Grow arrays geometrically so most appends rewrite no array metadata."""
        resizes = []
        for key in self.meta.features:
            arr = self.array(key)
            if arr.shape[0] < frames:
                resizes.append((arr, (max(frames, arr.shape[0] * 3 // 2, 1024), *arr.shape[1:])))
        ends = self._ends_array()
        if ends.shape[0] < episodes:
            resizes.append((ends, (max(episodes, ends.shape[0] * 3 // 2, 64),)))
        self._wrote = True
        run_concurrently([a.async_array.resize(shape) for a, shape in resizes])

    def append_episode(self, data: dict[str, np.ndarray], **info: Any) -> int:
        """Append one episode atomically and return its index.

        ``data`` maps every feature key to an array ``[length, *shape]``. ``info`` fills the
        episode table: ``success``, ``seed``, ``source``, ``operator``, ``task`` and any extra
        scalar columns (``mask.<name>``, ``score.<name>``, ...).
        """
        return self.append_episodes([(data, info)])[0]

    def append_episodes(
        self,
        episodes: Sequence[tuple[dict[str, np.ndarray], dict[str, Any]]],
        origin: Sequence[object] | None = None,
    ) -> list[int]:
        """Append several episodes with one commit (all or none of them become visible).

        ``origin``: what each episode was read from, named in errors about its data (a copy or a
        conversion names its input's episode, not the store it writes); default: this store.
        """
        self._require_writable()
        if not episodes:
            return []
        where = list(origin) if origin is not None else [self.path] * len(episodes)
        checked = [self._validate(data, at) for (data, _), at in zip(episodes, where)]
        infos = [info for _, info in episodes]
        total = self.num_frames
        lengths = [n for _, n in checked]
        new_total = total + sum(lengths)
        n_before = self.num_episodes
        table, indices = self._table_with(checked, infos, total)
        try:
            self._ensure_capacity(new_total, n_before + len(checked))
            writes = []  # to zarr, for arrays a RowWriter cannot write: one event-loop round trip for all
            for key in self.meta.features:
                block = checked[0][0][key] if len(checked) == 1 else np.concatenate([d[key] for d, _ in checked])
                writes.append(self._write_rows(key, self.array(key), total, block))
            new_ends = total + np.cumsum(lengths, dtype=np.int64)
            writes.append(self._write_rows("episode_ends", self._ends_array(), n_before, new_ends))
            run_concurrently([w for w in writes if w is not None])
            self._commit(table)
        except Exception as exc:  # disk full, quota, permissions, an unreachable object store
            problem = self._write_problem(exc)
            if problem is None:
                raise
            raise DemoError(self.path, f"cannot write ({problem}); these {len(checked)} "
                                       f"episode(s) were not committed, the {n_before} before them are kept") from None
        self._table = table
        if self._staged and not self._atomic:
            self._publish()  # the first episode is committed: the store replaces what was at its path
        return indices

    def _commit(self, table: pa.Table) -> None:
        """Write ``table`` as the episode table: the commit. On object storage the table's existence
        is what makes a store present, so a store not yet published keeps it for :meth:`_publish`."""
        if not (self._staged and isinstance(self._dir, Remote)):
            episode_table.write_atomic(table, self._dir / TABLE_FILE)

    def _write_problem(self, exc: Exception) -> str | None:
        """Why a write failed, in words, when it is the storage's fault (else None: a bug, re-raised)."""
        if isinstance(self.path, Remote) and (problem := remote_problem(exc, self.path)) is not None:
            return problem
        return (exc.strerror or first_line(exc)) if isinstance(exc, OSError) else None

    def _table_with(self, checked: list[tuple[dict[str, np.ndarray], int]], infos: list[dict[str, Any]],
                    start: int) -> tuple[pa.Table, list[int]]:
        """The episode table with rows for ``checked`` episodes whose frames begin at ``start``, and their indices."""
        table = self._table
        indices = []
        for (data, length), info in zip(checked, infos):
            index = table.num_rows
            row = {
                "episode_index": index,
                "start": start,
                "length": length,
                "success": bool(info.get("success", False)),
                "seed": int(info["seed"]) if info.get("seed") is not None else -1,
                "source": str(info.get("source", "unknown")),
                "operator": str(info.get("operator", "")),
                "task": str(info.get("task", (self.meta.task or {}).get("name", ""))),
                "duration_s": length / self.meta.fps,
                "crc32": self._checksum(data),
            }
            row.update({k: v for k, v in info.items() if k not in row})
            table = episode_table.append_row(table, episode_table.make_row(row))
            indices.append(index)
            start += length
        return table, indices

    def _write_rows(self, key: str, array: zarr.Array, start: int, rows: np.ndarray) -> Any:
        """Write ``rows`` at ``start`` now (RowWriter), or return zarr's coroutine that will."""
        if key not in self._row_writers:
            directory = self._dir / ("meta" if key == "episode_ends" else "data") / key
            # An object cannot be patched in place: on object storage zarr PUTs each chunk whole.
            self._row_writers[key] = RowWriter.for_array(array, directory) if isinstance(directory, Path) else None
        writer = self._row_writers[key]
        if writer is None:
            return array.async_array.setitem(slice(start, start + len(rows)), rows)
        writer.write(start, rows)
        return None
