"""The episode store: the one dataset abstraction that every stage of `demo` reads and writes.

A store is a directory::

    pick.zarr/
      zarr.json            zarr v3 root group; attributes["demo"] = StoreMeta (format, fps, ...)
      data/<key>/          one array per feature, all episodes concatenated along time (axis 0)
      meta/episode_ends/   int64 cumulative end index per episode (Diffusion Policy ReplayBuffer)
      episodes.parquet     the episode table (see demo.store.episode_table): the commit record
      robot/               the robot's MJCF and asset files when it is not the built-in arm
                           (see demo.store.robot_files; meta.robot lists them with their sha256)

Appending is atomic per episode. The frames are written first (zarr writes each chunk to a
temporary file and renames it, so a chunk holding committed frames is always either its old or its
new version), then ``meta/episode_ends``, and last the episode table, renamed into place: that
rename is the commit. Frames beyond the table's last episode belong to an append that never
committed; readers ignore them and a writer overwrites them. While a writer holds the store, arrays
carry spare capacity past the committed frames (so most appends rewrite no array metadata); closing
the writer trims them to the committed length. A crash or SIGKILL at any point
therefore leaves every finished episode readable. ``robot/`` is written once, at creation, before
the first episode table: staged in ``.robot.tmp/`` and renamed into place, so a store's robot folder
is either complete or absent (a reader then names the missing file), never half-copied.

One process writes a store's path at a time, and it takes the path's writer lock (an advisory
``flock`` on ``.NAME.lock`` beside the store, :mod:`demo.store.writer_lock`) before it creates,
replaces, removes or appends anything; a second writer, ``--overwrite`` included, is refused with
one line naming the owner's pid. Parallel collectors send finished episodes to a single writer
(see demo.collect). Opening for reading takes no lock.

A new store is never built in place: :meth:`EpisodeStore.create` builds it in ``.NAME.tmp-PID``
beside ``NAME`` and swaps it in by rename (:mod:`demo.store.swap`: an atomic exchange where an old
store is replaced, which is deleted only after), so at every instant ``NAME`` holds the old store
or the new one, never a half-made or a missing one. It appears with its first committed episode
(a collection: finished episodes are visible and kept as it goes) or, with ``atomic=True``, only
when it is closed after everything was written (a copy, a conversion, an import: all or nothing).
A failure before then (:meth:`EpisodeStore.abandon`, or leaving a ``with`` block by an exception)
removes the staged store and leaves the old one untouched; the leftovers of a killed writer are
removed by the next holder of the lock. A writer that fails or is refused writes nothing more
(it does not even trim spare capacity); only a clean :meth:`EpisodeStore.close` of a writer that
appended trims.

Opening checks the store against the schema its root ``zarr.json`` declares: every feature's array
must exist with the declared dtype and per-frame shape, and hold at least the committed frames.

A store may also live on object storage (``s3://bucket/pick.zarr``, see :mod:`demo.store.location`):
the same objects under a prefix, read and written through zarr's ``FsspecStore``. Objects are written
whole, each PUT atomic, and cannot be renamed, so there the protocol is:

- an append PUTs the chunk objects it touches, whole (a chunk holding committed frames is rewritten
  with those frames unchanged: a reader sees its old or its new version), then
  ``meta/episode_ends``, and last the episode table, PUT whole: that PUT is the commit (S3 and GCS
  are strongly read-after-write consistent), so a crash or SIGKILL still keeps every finished
  episode, and frames past the table's last episode are ignored as locally;
- a new store is built in place, not swapped in: it is present once its episode table exists,
  which is written with the first committed episode (a collection) or when it is closed (a copy,
  a conversion: all or nothing). Until then readers are told there is no store; a failure removes
  what was written, and objects without a table that a killed creation left are removed by the
  next creation of that path;
- ``overwrite`` deletes the old store first (its episode table, then the rest), so unlike locally
  the replacement is not atomic: from then until the new store's first commit there is no store at
  the path, and a failure in between leaves none;
- the writer lock is an object beside the store (:class:`~demo.store.writer_lock.RemoteWriterLock`);
- a robot other than the built-in arm cannot be stored there (its files must be local for MuJoCo).
"""

from __future__ import annotations

import asyncio
import json
import os
import sys
import time
import zlib
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import zarr
from zarr.api.asynchronous import create_array
from zarr.core.sync import sync
from zarr.storage import StorePath as ZarrPath

from demo.errors import DemoError
from demo.store import episode_table, swap, writer_lock
from demo.store.chunk_writer import RowWriter
from demo.store.image_bytes import camera_bytes
from demo.store.location import Remote, StorePath, remote_errors, remote_problem, same_store, store_path, zarr_store
from demo.store.robot_files import ROBOT_DIR, copy_robot_files
from demo.store.spec import FORMAT_NAME, SCHEMA_VERSION, StoreMeta
from demo.store.writer_lock import RemoteWriterLock, WriterLock

TABLE_FILE = "episodes.parquet"
IMAGE_PREFIX = "obs.image_"  # camera images: the only compressed features
CHUNK_BYTES = 64 * 1024  # small enough that an append re-compresses little, big enough for fast reads
EpisodeSelection = None | str | Sequence[int] | np.ndarray


def _chunk_rows(frame_shape: tuple[int, ...], dtype: np.dtype) -> int:
    frame_bytes = max(1, int(np.prod(frame_shape, dtype=np.int64)) * dtype.itemsize)
    return int(np.clip(CHUNK_BYTES // frame_bytes, 16, 16384))


class EpisodeStore:
    """A directory of episodes. Open with :meth:`create` or :meth:`open`; use as a context manager."""

    def __init__(self, path: StorePath, root: zarr.Group, meta: StoreMeta, table: pa.Table, writable: bool,
                 lock: WriterLock | RemoteWriterLock | None = None, staged: StorePath | None = None,
                 atomic: bool = False):
        self.path = path  # the store's name; its files are in self._dir (a staging folder until published)
        self._dir = staged or path
        self._root = root
        self.meta = meta
        self._table = table
        self.writable = writable
        self._lock = lock
        self._staged = staged is not None
        self._atomic = atomic
        self._wrote = False  # appended anything: only then does close() trim spare capacity
        self._arrays: dict[str, zarr.Array] = {}
        self._row_writers: dict[str, RowWriter | None] = {}

    # ------------------------------------------------------------------ opening and creating
    @classmethod
    def create(
        cls,
        path: str | StorePath,
        meta: StoreMeta,
        *,
        overwrite: bool = False,
        robot_from: str | Path | None = None,
        atomic: bool = False,
    ) -> "EpisodeStore":
        """Create an empty store at ``path`` (refuses to replace an existing one unless ``overwrite``).

        Takes ``path``'s writer lock first (refused with one line while another process holds it),
        then builds the store beside ``path`` (see the module docstring). It replaces what is at
        ``path`` when its first episode is committed, or, with ``atomic``, when it is closed; until
        then ``path`` is untouched, and :meth:`abandon` removes the staged store.

        The robot files ``meta.robot`` lists are copied into ``path/robot/`` from ``robot_from`` (a
        store or run directory holding them in its ``robot/``), else from the record's source folder.
        ``path`` may be a URL on object storage (see the module docstring for what changes there).
        """
        path = store_path(path)
        with remote_errors(path):
            lock = writer_lock.acquire(path)
            # Object storage cannot rename a prefix: the store is built in place (see the module docstring).
            staged = path if isinstance(path, Remote) else swap.staging_path(path)
            try:
                _recover(path)
                _check_replaceable(path, overwrite)
            except BaseException:
                lock.release()
                raise
            try:
                root = _build(staged, meta, robot_from, path)
            except BaseException:
                _remove_quietly(staged)
                lock.release()
                raise
        return cls(path, root, meta, episode_table.empty_table(), writable=True, lock=lock, staged=staged,
                   atomic=atomic)

    @classmethod
    def open(cls, path: str | StorePath, mode: str = "r") -> "EpisodeStore":
        """Open an existing store (a local path or a URL), ``mode="r"`` to read or ``"a"`` to append and edit."""
        if mode not in ("r", "a"):
            raise ValueError(f"mode must be 'r' or 'a', not {mode!r}")
        path = store_path(path)
        if mode == "a" and isinstance(path, Path) and not path.parent.is_dir():
            raise DemoError(path, "no such store")  # and no folder to create its lock file in
        with remote_errors(path):
            lock = writer_lock.acquire(path) if mode == "a" else None
            try:
                if lock is not None:
                    _recover(path)
                store = cls._read_existing(path, mode, lock)
            except BaseException:
                if lock is not None:
                    lock.release()
                raise
        return store

    @classmethod
    def _read_existing(cls, path: StorePath, mode: str, lock: WriterLock | RemoteWriterLock | None) -> "EpisodeStore":
        if isinstance(path, Remote):
            _check_present(path)
        elif not path.exists():
            aside = swap.interrupted(path)
            raise DemoError(path, "no such store" + (
                f" (a replacement killed halfway left the previous one at {aside.name}; "
                "the next write to this path restores it)" if aside else ""))
        elif not path.is_dir() or not (path / "zarr.json").is_file():
            raise DemoError(path, "not a demo episode store (no zarr.json in a directory)")
        try:
            root = zarr.open_group(zarr_store(path, read_only=mode == "r"), mode="r+" if mode == "a" else "r",
                                   zarr_format=3)
            attrs = dict(root.attrs)
        except Exception as exc:  # zarr raises several types for unreadable metadata
            raise DemoError(path / "zarr.json", f"unreadable zarr metadata ({_first_line(exc)})") from None
        raw = attrs.get("demo")
        if not isinstance(raw, dict) or raw.get("format") != FORMAT_NAME:
            raise DemoError(path, f"not a demo episode store (root attribute 'demo.format' is not {FORMAT_NAME!r})")
        if raw.get("schema_version") != SCHEMA_VERSION:
            raise DemoError(
                path, f"schema version {raw.get('schema_version')!r} is not supported (this demo reads {SCHEMA_VERSION})"
            )
        try:
            meta = StoreMeta.from_json(raw)
        except (KeyError, TypeError, ValueError) as exc:
            raise DemoError(path / "zarr.json", f"malformed store metadata ({_first_line(exc)})") from None
        table = episode_table.read(path / TABLE_FILE)
        store = cls(path, root, meta, table, writable=(mode == "a"), lock=lock)
        store._check_consistency()
        return store

    def close(self) -> None:
        """Finish writing: trim spare capacity (if this writer appended), publish a staged store, unlock."""
        if self._lock is None:
            return
        try:
            if self._wrote:
                self._trim_to_committed()
            if self._staged:
                self._publish()
        except BaseException:
            self.abandon()
            raise
        self._release_lock()

    def abandon(self) -> None:
        """Stop writing after a failure, writing nothing more: a store not yet published is removed
        (``path`` keeps what it held before); a published one keeps its committed episodes."""
        if self._lock is None:
            return
        try:
            if self._staged:
                _remove_quietly(self._dir)
        finally:
            self._release_lock()

    def _publish(self) -> None:
        """Swap the staged store in at ``path`` (replacing the old one there, then deleting it)."""
        if isinstance(self.path, Remote):  # built in place: its episode table's PUT makes it present
            with remote_errors(self.path):
                episode_table.write_atomic(self._table, self.path / TABLE_FILE)
            self._staged = False
            return
        swap.publish(self._dir, self.path)
        self._dir, self._staged = self.path, False
        self._root = zarr.open_group(str(self.path), mode="r+", zarr_format=3)
        self._arrays, self._row_writers = {}, {}

    def _release_lock(self) -> None:
        if self._lock is not None:
            self._lock.release()
            self._lock = None

    def __enter__(self) -> "EpisodeStore":
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *exc: object) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abandon()

    def __del__(self) -> None:
        # No zarr I/O here: during interpreter shutdown zarr cannot start its event loop. A store
        # that was never closed keeps spare capacity past the committed frames, which is harmless;
        # one never published stays staged, and the next writer of its path removes it. An
        # object-storage lock needs the network: left during shutdown (then stale: the next writer
        # on this machine takes it over), deleted otherwise.
        lock = getattr(self, "_lock", None)  # None: __init__ failed before it held one
        if lock is None or isinstance(lock, RemoteWriterLock) and sys.is_finalizing():
            return
        try:
            self._release_lock()
        except Exception:
            pass

    # ------------------------------------------------------------------ structure
    @property
    def robot_dir(self) -> StorePath:
        """Where the store keeps its robot's files (absent for the built-in arm and on object storage)."""
        return self._dir / ROBOT_DIR

    def array(self, key: str) -> zarr.Array:
        if key not in self.meta.features:
            raise DemoError(self.path, f"has no feature {key!r} (features: {', '.join(self.meta.features)})")
        if key not in self._arrays:
            self._open_arrays()
        if key not in self._arrays:  # missing or unreadable: say which
            self._arrays[key] = _member(self._root, "data", key, self.path)
        return self._arrays[key]

    def _open_arrays(self) -> None:
        """Open every feature's array at once, concurrently: on object storage one round trip instead
        of one per feature. A key that fails is left to :meth:`array`, which names the problem."""
        todo = [k for k in self.meta.features if k not in self._arrays]
        if not todo:
            return
        store = self._root.store
        opened = sync(_gather(*(zarr.AsyncArray.open(ZarrPath(store, f"data/{k}"), zarr_format=3) for k in todo)))
        for key, array in zip(todo, opened):
            if isinstance(array, zarr.AsyncArray):
                self._arrays[key] = zarr.Array(array)

    def _ends_array(self) -> zarr.Array:
        if "meta/episode_ends" not in self._arrays:  # a group lookup reads metadata from disk: keep the array
            self._arrays["meta/episode_ends"] = _member(self._root, "meta", "episode_ends", self.path)
        return self._arrays["meta/episode_ends"]

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

    def _check_schema(self) -> None:
        """Every array has the dtype and per-frame shape the root metadata declares for it."""
        for key, spec in self.meta.features.items():
            try:
                expected = spec.np_dtype
            except TypeError:
                raise DemoError(self.path / "zarr.json", f"feature {key!r} declares an unknown dtype {spec.dtype!r}") from None
            arr = self.array(key)
            if np.dtype(arr.dtype) != expected or tuple(arr.shape[1:]) != spec.shape:
                raise DemoError(
                    self.path / "data" / key / "zarr.json",
                    f"array holds {arr.dtype} frames of shape {tuple(arr.shape[1:])} but the store's schema declares "
                    f"{spec.dtype} {spec.shape}",
                )
        ends = self._ends_array()
        if np.dtype(ends.dtype) != np.int64 or ends.ndim != 1:
            raise DemoError(self.path / "meta" / "episode_ends" / "zarr.json",
                            f"array must be 1-D int64, not {ends.ndim}-D {ends.dtype}")

    def _check_consistency(self) -> None:
        self._check_schema()
        lengths = self._table.column("length").to_numpy()
        ends = np.cumsum(lengths, dtype=np.int64)
        if not np.array_equal(self._table.column("episode_index").to_numpy(), np.arange(len(lengths))):
            raise DemoError(self.path / TABLE_FILE, "episode_index is not 0..N-1")
        stored_ends = self._ends_array()
        if stored_ends.shape[0] < len(ends) or not np.array_equal(stored_ends[: len(ends)], ends):
            raise DemoError(
                self.path / "meta" / "episode_ends",
                f"does not match the episode table ({stored_ends.shape[0]} ends for {len(ends)} episodes)",
            )
        total = int(ends[-1]) if len(ends) else 0
        for key in self.meta.features:
            n = self.array(key).shape[0]
            if n < total:
                raise DemoError(self.path / "data" / key, f"is truncated: {n} frames, the episode table needs {total}")

    # ------------------------------------------------------------------ reading
    @property
    def num_episodes(self) -> int:
        return self._table.num_rows

    @property
    def num_frames(self) -> int:
        return int(self._table.column("length").to_numpy().sum()) if self.num_episodes else 0

    @property
    def episode_ends(self) -> np.ndarray:
        return np.cumsum(self._table.column("length").to_numpy(), dtype=np.int64)

    @property
    def episode_lengths(self) -> np.ndarray:
        return self._table.column("length").to_numpy().astype(np.int64)

    @property
    def table(self) -> pa.Table:
        """The episode table (read-only view; edit with :meth:`set_column` / :meth:`set_mask`)."""
        return self._table

    def episode_info(self, index: int) -> dict[str, Any]:
        self._check_index(index)
        return {k: v[0] for k, v in self._table.slice(index, 1).to_pydict().items()}

    def column(self, name: str) -> np.ndarray:
        if name not in self._table.column_names:
            raise DemoError(self.path / TABLE_FILE, f"has no column {name!r}")
        return self._table.column(name).to_numpy(zero_copy_only=False)

    def _check_index(self, index: int) -> None:
        if not 0 <= index < self.num_episodes:
            raise DemoError(self.path, f"has no episode {index} (it has {self.num_episodes})")

    def _read(self, key: str, start: int, stop: int) -> np.ndarray:
        return self._read_keys([key], start, stop)[key]

    def _read_keys(self, keys: Sequence[str], start: int, stop: int) -> dict[str, np.ndarray]:
        """Frames ``[start, stop)`` of each key, read concurrently (on object storage: one round trip)."""
        arrays = [self.array(k) for k in keys]
        values = sync(_gather(*(a.async_array.getitem(slice(start, stop)) for a in arrays)))
        out = {}
        for key, value in zip(keys, values):
            if isinstance(value, BaseException):
                raise DemoError(self.path / "data" / key, f"cannot be read, corrupted chunk? ({_first_line(value)})")
            out[key] = np.asarray(value)
        return out

    def read_episode(self, index: int, keys: Sequence[str] | None = None) -> dict[str, np.ndarray]:
        """All frames of one episode: ``{key: array[length, ...]}``."""
        self._check_index(index)
        start = int(self._table.column("start")[index].as_py())
        stop = start + int(self._table.column("length")[index].as_py())
        return self._read_keys(keys or list(self.meta.features), start, stop)

    def iter_episodes(
        self, keys: Sequence[str] | None = None, episodes: EpisodeSelection = None
    ) -> Iterator[tuple[int, dict[str, np.ndarray]]]:
        for index in self.select(episodes):
            yield int(index), self.read_episode(int(index), keys)

    def load(
        self, keys: Sequence[str] | None = None, episodes: EpisodeSelection = None
    ) -> tuple[dict[str, np.ndarray], np.ndarray]:
        """Frames of the selected episodes in memory, concatenated, with their episode ends."""
        keys = list(keys or self.meta.features)
        chosen = self.select(episodes)
        total = self.num_frames
        if len(chosen) == self.num_episodes:
            return self._read_keys(keys, 0, total), self.episode_ends
        starts = self.column("start")[chosen]
        lengths = self.episode_lengths[chosen]
        frames = np.concatenate([np.arange(s, s + n) for s, n in zip(starts, lengths)]) if len(chosen) else np.zeros(0, int)
        data = {}
        for k in keys:
            full = self._read(k, 0, total)
            data[k] = full[frames]
        return data, np.cumsum(lengths, dtype=np.int64)

    def select(self, episodes: EpisodeSelection = None) -> np.ndarray:
        """Episode indices for ``None`` (all), a mask name, a boolean array or a list of indices."""
        if episodes is None:
            return np.arange(self.num_episodes)
        if isinstance(episodes, str):
            return np.flatnonzero(self.mask(episodes))
        arr = np.asarray(episodes)
        if arr.dtype == bool:
            if arr.shape != (self.num_episodes,):
                raise DemoError(self.path, f"episode mask has {arr.size} entries for {self.num_episodes} episodes")
            return np.flatnonzero(arr)
        arr = arr.astype(np.int64).reshape(-1)
        bad = arr[(arr < 0) | (arr >= self.num_episodes)]
        if bad.size:
            raise DemoError(self.path, f"has no episode {int(bad[0])} (it has {self.num_episodes})")
        return arr

    # ------------------------------------------------------------------ masks and per-episode columns
    def mask_names(self) -> list[str]:
        p = episode_table.MASK_PREFIX
        return [c[len(p):] for c in self._table.column_names if c.startswith(p)]

    def mask(self, name: str) -> np.ndarray:
        column = episode_table.MASK_PREFIX + name
        if column not in self._table.column_names:
            raise DemoError(self.path, f"has no mask {name!r} (masks: {', '.join(self.mask_names()) or 'none'})")
        return self._table.column(column).to_numpy(zero_copy_only=False).astype(bool)

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
        _run_concurrently([a.async_array.resize(shape) for a, shape in resizes if a.shape != shape])

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
        _run_concurrently([a.async_array.resize(shape) for a, shape in resizes])

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
            _run_concurrently([w for w in writes if w is not None])
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
        return (exc.strerror or _first_line(exc)) if isinstance(exc, OSError) else None

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

    def _checksum(self, data: dict[str, np.ndarray]) -> int:
        crc = 0
        for key in self.meta.features:
            crc = zlib.crc32(np.ascontiguousarray(data[key]).view(np.uint8).reshape(-1), crc)
        return crc

    def verify(self) -> list[str]:
        """Read every committed frame and compare it with the episode's checksum; returns the problems."""
        problems = []
        for index in range(self.num_episodes):
            try:
                data = self.read_episode(index)
            except DemoError as exc:
                problems.append(f"episode {index}: {exc}")
                continue
            if self._checksum(data) != int(self._table.column("crc32")[index].as_py()):
                problems.append(f"episode {index}: data does not match its checksum (corrupted or missing chunk)")
        return problems

    # ------------------------------------------------------------------ copies
    def copy_to(
        self,
        path: str | StorePath,
        episodes: EpisodeSelection = None,
        *,
        frame_ranges: dict[int, tuple[int, int]] | None = None,
        provenance: dict[str, Any] | None = None,
        overwrite: bool = False,
        meta: StoreMeta | None = None,
    ) -> "EpisodeStore":
        """Write the selected episodes (optionally trimmed to ``frame_ranges[i] = (a, b)``) to a new store.

        The source is never modified. Per-episode columns, masks included, travel with their rows.
        The copy appears at ``path`` when the returned store is closed (all or nothing: a failure,
        or leaving a ``with`` block by an exception, leaves ``path`` as it was).
        """
        path = store_path(path)
        if same_store(path, self.path):
            raise DemoError(path, "is the source store; write the copy elsewhere")
        chosen = self.select(episodes)
        new_meta = meta or StoreMeta.from_json(self.meta.to_json())
        record = {"op": "copy", "from": str(self.path), "episodes": int(len(chosen)), "time": _now()}
        record.update(provenance or {})
        new_meta.provenance = [*new_meta.provenance, record]
        out = EpisodeStore.create(path, new_meta, overwrite=overwrite, robot_from=self.path, atomic=True)
        try:
            self._copy_episodes(out, chosen, frame_ranges)
        except BaseException:
            out.abandon()
            raise
        return out

    def _copy_episodes(self, out: "EpisodeStore", chosen: np.ndarray,
                       frame_ranges: dict[int, tuple[int, int]] | None) -> None:
        skip = {"episode_index", "start", "length", "duration_s", "crc32"}
        starts, lengths = self.column("start"), self.episode_lengths
        for block in _blocks(chosen, starts, lengths, max_frames=200_000):
            # One read per key for the whole span of the block, then slices: zarr reads are costly per call.
            lo = int(starts[block].min())
            hi = int((starts[block] + lengths[block]).max())
            span = self._read_keys(list(self.meta.features), lo, hi)
            batch: list[tuple[dict[str, np.ndarray], dict[str, Any]]] = []
            for index in block:
                a, b = int(starts[index]) - lo, int(starts[index] + lengths[index]) - lo
                if frame_ranges and int(index) in frame_ranges:
                    first, last = frame_ranges[int(index)]
                    a, b = a + first, a + last
                info = {k: v for k, v in self.episode_info(int(index)).items() if k not in skip}
                if frame_ranges and int(index) in frame_ranges:
                    info["trimmed_from"] = f"{int(index)}:{frame_ranges[int(index)][0]}:{frame_ranges[int(index)][1]}"
                info["source_episode"] = int(index)
                batch.append(({k: v[a:b] for k, v in span.items()}, info))
            out.append_episodes(batch, origin=[f"{self.path} episode {int(i)}" for i in block])

    # ------------------------------------------------------------------ summary
    def summary(self) -> dict[str, Any]:
        """What `demo info` shows, as plain JSON-able data."""
        t = self._table
        success = t.column("success").to_numpy(zero_copy_only=False) if self.num_episodes else np.zeros(0, bool)

        def counts(col: str) -> dict[str, int]:
            values, n = np.unique(np.asarray(t.column(col).to_pylist(), dtype=object).astype(str), return_counts=True)
            return {str(v): int(c) for v, c in zip(values, n)}

        return {
            "path": str(self.path),
            "format": self.meta.format,
            "schema_version": self.meta.schema_version,
            "episodes": self.num_episodes,
            "frames": self.num_frames,
            "fps": self.meta.fps,
            "task": self.meta.task,
            "robot": self.meta.robot,
            "action": self.meta.action.to_json(),
            "features": {k: v.to_json() for k, v in self.meta.features.items()},
            "success_rate": float(success.mean()) if len(success) else None,
            "mean_length": float(self.episode_lengths.mean()) if self.num_episodes else None,
            "sources": counts("source") if self.num_episodes else {},
            "operators": counts("operator") if self.num_episodes else {},
            "masks": {name: int(self.mask(name).sum()) for name in self.mask_names()},
            "camera_bytes": camera_bytes({k: (self.array(k), self._dir / "data" / k) for k in self.meta.features
                                          if k.startswith(IMAGE_PREFIX)}, self.num_frames),
            "provenance": self.meta.provenance,
        }


def _recover(path: StorePath) -> None:
    """Clean up after a killed writer of ``path`` (holding its lock): see :func:`demo.store.swap.recover`.
    On object storage nothing is staged aside; :func:`_clear_remote` removes a killed creation's objects."""
    if isinstance(path, Path):
        swap.recover(path)


def _check_replaceable(path: StorePath, overwrite: bool) -> None:
    """Refuse to replace ``path`` unless it is free (absent or an empty folder), or a store and ``overwrite``."""
    if isinstance(path, Remote):
        _clear_remote(path, overwrite)
        return
    if path.is_dir() and not path.is_symlink() and not any(path.iterdir()):
        return
    if not os.path.lexists(path):
        return
    if not overwrite:
        raise DemoError(path, "already exists (pass --overwrite to replace it, or choose another --out)")
    if path.is_symlink() or not path.is_dir() or not ((path / "zarr.json").exists() or (path / TABLE_FILE).exists()):
        raise DemoError(path, "exists and is not a demo store; refusing to overwrite it")


def _clear_remote(path: Remote, overwrite: bool) -> None:
    """Make ``path`` free on object storage: nothing there, or the objects of a creation that never
    committed (no episode table), or with ``overwrite`` a store. The old store is deleted, not
    swapped: its episode table first (from then on it is absent, not half-deleted), then the rest."""
    if not path.exists():
        return
    table = path / TABLE_FILE
    if table.exists():
        if not overwrite:
            raise DemoError(path, "already exists (pass --overwrite to replace it, or choose another --out)")
    elif not _unfinished_store(path):
        raise DemoError(path, "already exists and is not a demo store; refusing to " +
                        ("overwrite it" if overwrite else "write there"))
    table.remove()
    path.remove()


def _unfinished_store(path: Remote) -> bool:
    """Whether the objects at ``path`` are a demo store whose creation committed nothing (no episode table)."""
    try:
        raw = json.loads((path / "zarr.json").read_bytes())
        return raw["attributes"]["demo"]["format"] == FORMAT_NAME
    except (OSError, ValueError, KeyError, TypeError):
        return False


def _check_present(path: Remote) -> None:
    """Refuse to open what is not a store on object storage, saying what is there instead."""
    if (path / TABLE_FILE).exists():
        if not (path / "zarr.json").exists():
            raise DemoError(path, "not a demo episode store (no zarr.json)")
        return
    if path.exists():
        raise DemoError(path, "no such store (objects but no episode table: a store being created that has not "
                              "committed yet, or a creation killed before its first episode)")
    if not path.bucket.exists():
        raise DemoError(path, f"bucket {path.bucket} does not exist")
    raise DemoError(path, "no such store")


def _build(folder: StorePath, meta: StoreMeta, robot_from: str | Path | None, where: StorePath) -> zarr.Group:
    """An empty store with ``meta``'s arrays, robot files and episode table, written in ``folder``
    (the staging folder of the store at ``where``, which errors name)."""
    try:
        return _build_in(folder, meta, robot_from, where)
    except OSError as exc:  # disk full, permissions, read-only filesystem
        raise DemoError(where, f"cannot be created ({exc.strerror or _first_line(exc)})") from None


def _build_in(folder: StorePath, meta: StoreMeta, robot_from: str | Path | None, where: StorePath) -> zarr.Group:
    if isinstance(folder, Path):
        folder.mkdir(parents=True)
    root = zarr.open_group(zarr_store(folder, read_only=False), mode="w", zarr_format=3)
    root.attrs["demo"] = meta.to_json()
    root.create_group("data")
    root.create_group("meta")
    arrays = {("data", key): dict(shape=(0, *spec.shape), chunks=(_chunk_rows(spec.shape, spec.np_dtype), *spec.shape),
                                  dtype=spec.np_dtype,
                                  # Low-dimensional data barely compresses and is appended in place (see chunk_writer).
                                  compressors="auto" if key.startswith(IMAGE_PREFIX) else None)
              for key, spec in meta.features.items()}
    arrays["meta", "episode_ends"] = dict(shape=(0,), chunks=(8192,), dtype="int64", compressors=None)
    # Created together, as Group.create_array would one by one: on object storage one round of requests.
    created = sync(_gather(*(create_array(ZarrPath(root.store, group), name=key, **spec)
                             for (group, key), spec in arrays.items())))
    for (_, key), result in zip(arrays, created):
        if isinstance(result, ValueError):  # a name zarr cannot store as a path
            raise DemoError(where, f"feature name {key!r} cannot be stored ({_first_line(result)})")
        if isinstance(result, BaseException):
            raise result
    copy_robot_files(meta.robot, robot_from, folder)
    if isinstance(folder, Path):  # on object storage the table makes the store present: written at its first commit
        episode_table.write_atomic(episode_table.empty_table(), folder / TABLE_FILE)
    return root


def _member(root: zarr.Group, group: str, key: str, where: StorePath) -> zarr.Array:
    """``root[group][key]``, or DemoError naming the array's metadata file."""
    try:
        return root[group][key]
    except KeyError:
        raise DemoError(where / group / key, "array is missing") from None
    except Exception as exc:  # zarr raises several types for unreadable metadata
        raise DemoError(where / group / key / "zarr.json", f"unreadable array metadata ({_first_line(exc)})") from None


def _remove_quietly(path: StorePath) -> None:
    try:
        if isinstance(path, Remote):
            path.remove()
        else:
            swap.remove(path)
    except Exception:
        pass  # the next writer of this path removes leftovers


def _blocks(chosen: np.ndarray, starts: np.ndarray, lengths: np.ndarray, max_frames: int) -> Iterator[np.ndarray]:
    """Groups of the chosen episodes whose frames, and the span they lie in, stay near ``max_frames``."""
    block: list[int] = []
    frames, lo = 0, 0
    for index in chosen:
        end = int(starts[index] + lengths[index])
        if block and (frames + lengths[index] > max_frames or end - lo > 2 * max_frames or starts[index] < lo):
            yield np.asarray(block)
            block, frames = [], 0
        if not block:
            lo = int(starts[index])
        block.append(int(index))
        frames += int(lengths[index])
    if block:
        yield np.asarray(block)


def _run_concurrently(coroutines: list[Any]) -> None:
    """Run zarr coroutines together; the first failure is raised."""
    for result in sync(_gather(*coroutines)) if coroutines else ():
        if isinstance(result, BaseException):
            raise result


async def _gather(*coroutines: Any) -> list[Any]:
    """Every coroutine's result or exception (none is left running when another fails)."""
    return await asyncio.gather(*coroutines, return_exceptions=True)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip() or type(exc).__name__
    return text.splitlines()[0][:200]


def _now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())


