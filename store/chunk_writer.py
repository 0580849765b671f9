"""Writing rows of a zarr v3 array by writing its chunk files directly, as zarr itself would.

zarr-python 3 sends every write through asyncio tasks and thread hops: about 1 ms per array per
call, whatever the size. An episode append touches every feature array (15 for ``pick``), so
zarr's own ``setitem`` made the store's writer cost ~25 ms per episode, more than simulating a
short episode, and the writer a bottleneck for parallel collection.

:class:`RowWriter` handles the layouts :class:`~demo.store.EpisodeStore` creates: a regular chunk
grid split along axis 0 only, default chunk-key encoding, codecs ``bytes`` (little endian),
optionally followed by ``zstd``. A chunk file is exactly what zarr writes for the same values.

- Uncompressed chunks are raw C-order bytes, so appending rows is writing their bytes at their
  offset in the file: rows already committed are never rewritten, and a crash mid-write can only
  tear rows that no commit refers to. A missing chunk (or one left short by such a crash, which
  then holds no committed rows) is written whole, the fill value around the new rows.
- zstd chunks must be re-encoded whole. A chunk that already holds rows is rewritten through a
  temporary file renamed over it (a reader never sees half a chunk); renaming over a file makes
  ext4 flush it first, about a millisecond, which is why the store keeps low-dimensional features
  uncompressed and compresses only images.

Any other layout (an array written by another tool) is left to zarr: :meth:`RowWriter.for_array`
returns None for it. The store has one writer (an exclusive lock), so the writer keeps the last
chunk it wrote in memory instead of reading it back.
"""

from __future__ import annotations

import os
from pathlib import Path

import numcodecs
import numpy as np
import zarr
from zarr.codecs import BytesCodec, ZstdCodec

from demo.jsonio import replace_atomically


class RowWriter:
    """Writes rows ``[start, start + len(rows))`` along axis 0 of one zarr array."""

    def __init__(self, array: zarr.Array, directory: Path, zstd: ZstdCodec | None):
        meta = array.metadata
        self.directory = directory
        self.chunk_shape = tuple(int(n) for n in meta.chunk_grid.chunk_shape)
        self.dtype = np.dtype(array.dtype).newbyteorder("<")
        self.row_bytes = int(np.prod(self.chunk_shape[1:], dtype=np.int64)) * self.dtype.itemsize
        self.chunk_bytes = self.row_bytes * self.chunk_shape[0]
        self.fill_value = meta.fill_value
        self._key = meta.encode_chunk_key
        self._compressor = numcodecs.Zstd(level=zstd.level, checksum=zstd.checksum) if zstd else None
        self._tail: tuple[int, np.ndarray] | None = None  # last compressed chunk written: (index, values)
        self._paths: dict[int, Path] = {}

    @classmethod
    def for_array(cls, array: zarr.Array, directory: Path) -> "RowWriter | None":
        """A writer for ``array`` stored in ``directory``, or None when its layout is not one it knows."""
        meta = array.metadata
        if getattr(meta, "zarr_format", None) != 3 or type(meta.chunk_grid).__name__ != "RegularChunkGrid":
            return None
        if tuple(meta.chunk_grid.chunk_shape[1:]) != tuple(array.shape[1:]) or meta.storage_transformers:
            return None
        codecs = list(meta.codecs)
        if not codecs or not isinstance(codecs[0], BytesCodec):
            return None
        if getattr(codecs[0].endian, "value", codecs[0].endian) not in ("little", None):
            return None
        if len(codecs) == 1:
            return cls(array, directory, None)
        if len(codecs) == 2 and isinstance(codecs[1], ZstdCodec):
            return cls(array, directory, codecs[1])
        return None

    def write(self, start: int, rows: np.ndarray) -> None:
        """Store ``rows`` (``[n, *shape]``) at row ``start``."""
        rows = np.ascontiguousarray(rows, dtype=self.dtype)
        per_chunk = self.chunk_shape[0]
        stop = start + len(rows)
        for c in range(start // per_chunk, (stop - 1) // per_chunk + 1 if stop > start else 0):
            lo, hi = max(start, c * per_chunk), min(stop, (c + 1) * per_chunk)
            part = rows[lo - start : hi - start]
            if self._compressor is None:
                self._patch_raw(c, lo - c * per_chunk, part)
            else:
                self._rewrite_compressed(c, lo - c * per_chunk, part)

    def _path(self, c: int) -> Path:
        path = self._paths.get(c)
        if path is None:
            path = self.directory / self._key((c,) + (0,) * (len(self.chunk_shape) - 1))
            path.parent.mkdir(parents=True, exist_ok=True)
            self._paths = {c: path}  # appends move on chunk by chunk: only the newest is needed again
        return path

    def _full_chunk(self) -> np.ndarray:
        return np.full(self.chunk_shape, self.fill_value, self.dtype)

    def _read_compressed(self, path: Path) -> np.ndarray | None:
        """The chunk's values, or None when a crash left it undecodable (then it held no committed rows)."""
        try:
            raw = self._compressor.decode(path.read_bytes())  # type: ignore[union-attr]
            return np.frombuffer(raw, self.dtype).reshape(self.chunk_shape).copy()
        except (RuntimeError, ValueError):
            return None

    def _patch_raw(self, c: int, row: int, part: np.ndarray) -> None:
        path = self._path(c)
        try:
            fd = os.open(path, os.O_WRONLY)
        except FileNotFoundError:
            fd = -1
        if fd >= 0:
            try:
                if os.fstat(fd).st_size == self.chunk_bytes:
                    os.pwrite(fd, part.tobytes(), row * self.row_bytes)
                    return
            finally:
                os.close(fd)
        chunk = self._full_chunk()
        chunk[row : row + len(part)] = part
        path.write_bytes(chunk.tobytes())

    def _rewrite_compressed(self, c: int, row: int, part: np.ndarray) -> None:
        assert self._compressor is not None
        path = self._path(c)
        holds_rows = path.exists()
        if self._tail is not None and self._tail[0] == c:
            chunk = self._tail[1]
        else:
            chunk = self._read_compressed(path) if holds_rows else None
            chunk = self._full_chunk() if chunk is None else chunk
        chunk[row : row + len(part)] = part
        data = self._compressor.encode(chunk.tobytes())
        if holds_rows:
            replace_atomically(path, lambda tmp: tmp.write_bytes(data))
        else:
            path.write_bytes(data)
        self._tail = (c, chunk)
