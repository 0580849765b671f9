"""Bytes per frame of a store's camera features: raw (H*W*3 uint8) against what their files hold.

Camera images are the only compressed features (zstd, see :mod:`demo.store.chunk_writer`), and the
bulk of an image store. The stored size is measured, not estimated: the sizes on disk of the chunk
files that hold the committed frames (a chunk never written holds fill values and has no file;
spare capacity past the committed frames is not counted). Files are ``lstat``-ed, never followed
or read, so an untrusted store cannot point this anywhere; on object storage the sizes come from one
listing of the array's objects.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np
import zarr

from demo.store.location import Remote, StorePath


def stored_bytes(array: zarr.Array, folder: StorePath, frames: int) -> int | None:
    """Bytes on disk of the chunk files of ``array`` (kept in ``folder``) that hold rows ``[0, frames)``.

    None for a layout split along other axes than time (written by another tool): no per-frame size.
    """
    grid = tuple(getattr(array.metadata.chunk_grid, "chunk_shape", ()))
    if not grid or tuple(grid[1:]) != tuple(array.shape[1:]):
        return None
    rest = (0,) * (array.ndim - 1)
    objects = folder.sizes() if isinstance(folder, Remote) else None
    total = 0
    for index in range(-(-frames // int(grid[0]))):
        key = array.metadata.encode_chunk_key((index, *rest))
        if objects is not None:
            total += objects.get(key, 0)
            continue
        try:
            total += os.lstat(folder / key).st_size
        except OSError:  # never written (all fill values), or not a file zarr could read either
            pass
    return total


def per_frame(raw: int, stored: int | None, frames: int) -> dict[str, Any]:
    """``raw`` bytes per frame and ``stored`` bytes for ``frames`` frames -> the JSON `demo info` shows."""
    stored_per_frame = stored / frames if stored is not None and frames else None
    return {
        "raw_bytes_per_frame": raw,
        "stored_bytes_per_frame": stored_per_frame,
        "compression_ratio": raw / stored_per_frame if stored_per_frame else None,
    }


def camera_bytes(arrays: dict[str, tuple[zarr.Array, StorePath]], frames: int) -> dict[str, Any]:
    """For camera features ``{key: (array, folder)}`` holding ``frames`` committed frames:
    ``{"per_camera": {key: {"shape", **per_frame}}, "total": per_frame}`` (``{}`` without cameras)."""
    if not arrays:
        return {}
    per_camera: dict[str, Any] = {}
    raw_sum, stored_sum = 0, 0
    for key, (array, folder) in arrays.items():
        raw = int(np.prod(array.shape[1:], dtype=np.int64)) * np.dtype(array.dtype).itemsize
        stored = stored_bytes(array, folder, frames)
        per_camera[key] = {"shape": list(array.shape[1:]), **per_frame(raw, stored, frames)}
        raw_sum += raw
        stored_sum = None if stored is None or stored_sum is None else stored_sum + stored
    return {"per_camera": per_camera, "total": per_frame(raw_sum, stored_sum, frames)}
