"""Reading a store: the episode table's views, episodes' frames (concurrently per key), selections by
index, mask or boolean array, masks, checksums and the summary `demo info` shows. A mixin of
:class:`~demo.store.episode_store.EpisodeStore`; frames are ``{key: array[length, *shape]}``.
"""

from __future__ import annotations

import hashlib
import zlib
from collections import Counter
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
from zarr.core.sync import sync

from demo.errors import DemoError, first_line
from demo.store import episode_table
from demo.store.image_bytes import camera_bytes
from demo.store.instructions import episode_instructions
from demo.store.layout import IMAGE_PREFIX, TABLE_FILE
from demo.store.location import StorePath
from demo.store.spec import StoreMeta
from demo.store.zarr_io import gather
from demo.verify import verifying

# What :meth:`StoreReading.select` takes: None (all), a mask name, a boolean array or indices.
EpisodeSelection = None | str | Sequence[int] | np.ndarray


class StoreReading:
    """Everything that reads a store (see :class:`~demo.store.episode_store.EpisodeStore`)."""

    path: StorePath
    meta: StoreMeta
    _dir: StorePath
    _table: pa.Table

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

    def _read_keys(self, keys: Sequence[str], start: int, stop: int, check: bool | None = None) -> dict[str, np.ndarray]:
        """Frames ``[start, stop)`` of each key, read concurrently (on object storage: one round trip);
        ``check``: refuse frames whose chunk file is missing (default :func:`verifying`)."""
        check = verifying() if check is None else check
        arrays = [self.array(k) for k in keys]
        values = sync(gather(*(a.async_array.getitem(slice(start, stop)) for a in arrays)))
        out = {}
        for key, array, value in zip(keys, arrays, values):
            if isinstance(value, BaseException):
                raise DemoError(self.path / "data" / key, f"cannot be read, corrupted chunk? ({first_line(value)})")
            if check:
                self._check_chunks(key, array, start, stop)
            out[key] = np.asarray(value)
        return out

    def _check_chunks(self, key: str, array: Any, start: int, stop: int) -> None:
        """Refuse frames ``[start, stop)`` of ``key`` where a chunk file holding them is missing: zarr reads a
        missing chunk as its fill value (zeros), which would pass on as data. Local stores only: their writer
        writes every chunk it puts rows in (:mod:`demo.store.chunk_writer`), so a missing one is damage; on
        object storage zarr skips chunks of fill values, and ``demo info --check``'s checksums judge. One
        ``stat`` per chunk read (chunks hold thousands of low-dimensional frames)."""
        if not isinstance(self._dir, Path) or stop <= start:
            return
        rows = int(array.metadata.chunk_grid.chunk_shape[0])
        zeros = (0,) * (len(array.shape) - 1)
        folder = self._dir / "data" / key
        seen = self.__dict__.setdefault("_chunks_seen", set())  # chunks found once are not looked for again
        for chunk in range(start // rows, (stop - 1) // rows + 1):
            if (key, chunk) in seen:
                continue
            name = array.metadata.encode_chunk_key((chunk, *zeros))
            if (folder / name).is_file():
                seen.add((key, chunk))
            else:
                first = max(start, chunk * rows)
                episode = int(np.searchsorted(self.episode_ends, first, side="right"))
                raise DemoError(folder / name, f"is missing: episode {episode} (frames {first}-"
                                               f"{min(stop, (chunk + 1) * rows) - 1}) cannot be read; the store is "
                                               "damaged (demo info --check lists every damaged episode, demo "
                                               "--no-verify reads it anyway)")

    def read_episode(self, index: int, keys: Sequence[str] | None = None, check: bool | None = None
                     ) -> dict[str, np.ndarray]:
        """All frames of one episode: ``{key: array[length, ...]}``. Read whole (``keys`` None: what copies,
        conversions and exports read), it is checked against its checksum: damage is refused where it is
        read, not passed on under a fresh checksum (a CRC-32 of the bytes read, ~1% of the read's time).
        ``check``: whether to check (default :func:`verifying`: on unless ``demo --no-verify``)."""
        self._check_index(index)
        check = verifying() if check is None else check
        start = int(self._table.column("start")[index].as_py())
        stop = start + int(self._table.column("length")[index].as_py())
        data = self._read_keys(keys or list(self.meta.features), start, stop, check)
        if keys is None and check and self._checksum(data) != int(self._table.column("crc32")[index].as_py()):
            raise DemoError(self.path, f"episode {index}: its data does not match its checksum (a damaged chunk); "
                                       "demo info --check lists every damaged episode, demo --no-verify reads it anyway")
        return data

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

    # ------------------------------------------------------------------ checksums
    def content_hash(self) -> str:
        """A fingerprint of what the store holds (every episode's length and checksum, the features), from the
        episode table alone: a run records it, so a store replaced or grown under it is noticed."""
        digest = hashlib.sha256(",".join(self.meta.features).encode())
        if self.num_episodes:
            digest.update(np.ascontiguousarray(self.episode_lengths).tobytes())
            digest.update(np.asarray(self._table.column("crc32").to_pylist(), dtype=np.int64).tobytes())
        return digest.hexdigest()[:16]

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
                self.read_episode(index, check=True)  # read whole: checked against its checksum
            except DemoError as exc:
                problems.append(f"episode {index}: {exc}")
        return problems

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
            "tasks": counts("task") if self.num_episodes else {},  # per-episode task (several in a task set's store)
            # what the episodes were told to do, in words (demo.store.instructions; none: {})
            "instructions": dict(sorted(Counter(text for text in episode_instructions([self]) if text).items())),
            "masks": {name: int(self.mask(name).sum()) for name in self.mask_names()},
            "camera_bytes": camera_bytes({k: (self.array(k), self._dir / "data" / k) for k in self.meta.features
                                          if k.startswith(IMAGE_PREFIX)}, self.num_frames),
            "provenance": self.meta.provenance,
        }
