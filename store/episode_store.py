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

import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import zarr

from demo.errors import DemoError, first_line
from demo.store import episode_table, swap, writer_lock
from demo.store.arrays import StoreArrays
from demo.store.chunk_writer import RowWriter
from demo.store.layout import IMAGE_PREFIX, TABLE_FILE, build, check_present, check_replaceable, recover, remove_quietly
from demo.store.location import Remote, StorePath, remote_errors, same_store, store_path, zarr_store
from demo.store.reading import EpisodeSelection, StoreReading
from demo.store.spec import FORMAT_NAME, SCHEMA_VERSION, StoreMeta
from demo.store.writer_lock import RemoteWriterLock, WriterLock
from demo.store.writing import StoreWriting

# What other modules import from here (IMAGE_PREFIX and TABLE_FILE are defined in demo.store.layout,
# EpisodeSelection in demo.store.reading).
__all__ = ["EpisodeStore", "EpisodeSelection", "IMAGE_PREFIX", "TABLE_FILE", "StoreMeta"]


class EpisodeStore(StoreWriting, StoreReading, StoreArrays):
    """A directory of episodes. Open with :meth:`create` or :meth:`open`; use as a context manager.

    This class holds the store's life cycle (create, open, close, abandon, publish) and copies; reading
    is :class:`~demo.store.reading.StoreReading`, writing :class:`~demo.store.writing.StoreWriting`,
    the arrays and their schema check :class:`~demo.store.arrays.StoreArrays`."""

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
                recover(path)
                check_replaceable(path, overwrite)
            except BaseException:
                lock.release()
                raise
            try:
                root = build(staged, meta, robot_from, path)
            except BaseException:
                remove_quietly(staged)
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
                    recover(path)
                store = cls._read_existing(path, mode, lock)
            except BaseException:
                if lock is not None:
                    lock.release()
                raise
        return store

    @classmethod
    def _read_existing(cls, path: StorePath, mode: str, lock: WriterLock | RemoteWriterLock | None) -> "EpisodeStore":
        if isinstance(path, Remote):
            check_present(path)
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
            raise DemoError(path / "zarr.json", f"unreadable zarr metadata ({first_line(exc)})") from None
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
            raise DemoError(path / "zarr.json", f"malformed store metadata ({first_line(exc)})") from None
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
                remove_quietly(self._dir)
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


def _now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
