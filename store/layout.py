"""A store's files at its path: their names, building an empty store, and telling what is at a path.

Used by :class:`~demo.store.episode_store.EpisodeStore` (whose module docstring describes the layout
and the write protocol) while it holds the path's writer lock: :func:`check_replaceable` refuses to
replace what is not free or not a store, :func:`build` writes an empty store (arrays, robot files,
episode table) in its staging folder, :func:`recover` and :func:`remove_quietly` clear what a killed
or failed writer left, and :func:`check_present` says what is there instead of a store on object storage.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import zarr
from zarr.api.asynchronous import create_array
from zarr.core.sync import sync
from zarr.storage import StorePath as ZarrPath

from demo.errors import DemoError, first_line
from demo.store import episode_table, swap
from demo.store.location import Remote, StorePath, zarr_store
from demo.store.robot_files import copy_robot_files
from demo.store.spec import FORMAT_NAME, StoreMeta
from demo.store.zarr_io import gather

TABLE_FILE = "episodes.parquet"
# Why a store is not created at a path something is in the way of (demo.store.output adds --append).
EXISTS = "already exists (pass --overwrite to replace it, or choose another --out)"
IMAGE_PREFIX = "obs.image_"  # camera images: the only compressed features
CHUNK_BYTES = 64 * 1024  # small enough that an append re-compresses little, big enough for fast reads


def _chunk_rows(frame_shape: tuple[int, ...], dtype: np.dtype) -> int:
    frame_bytes = max(1, int(np.prod(frame_shape, dtype=np.int64)) * dtype.itemsize)
    return int(np.clip(CHUNK_BYTES // frame_bytes, 16, 16384))


def recover(path: StorePath) -> None:
    """Clean up after a killed writer of ``path`` (holding its lock): see :func:`demo.store.swap.recover`.
    On object storage nothing is staged aside; :func:`_clear_remote` removes a killed creation's objects."""
    if isinstance(path, Path):
        swap.recover(path)


def check_replaceable(path: StorePath, overwrite: bool) -> None:
    """Refuse to replace ``path`` unless it is free (absent or an empty folder), or a store and ``overwrite``."""
    if isinstance(path, Remote):
        _clear_remote(path, overwrite)
        return
    if path.is_dir() and not path.is_symlink() and not any(path.iterdir()):
        return
    if not os.path.lexists(path):
        return
    if not overwrite:
        raise DemoError(path, EXISTS)
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
            raise DemoError(path, EXISTS)
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


def check_present(path: Remote) -> None:
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


def build(folder: StorePath, meta: StoreMeta, robot_from: str | Path | None, where: StorePath) -> zarr.Group:
    """An empty store with ``meta``'s arrays, robot files and episode table, written in ``folder``
    (the staging folder of the store at ``where``, which errors name)."""
    try:
        return _build_in(folder, meta, robot_from, where)
    except OSError as exc:  # disk full, permissions, read-only filesystem
        raise DemoError(where, f"cannot be created ({exc.strerror or first_line(exc)})") from None


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
    created = sync(gather(*(create_array(ZarrPath(root.store, group), name=key, **spec)
                             for (group, key), spec in arrays.items())))
    for (_, key), result in zip(arrays, created):
        if isinstance(result, ValueError):  # a name zarr cannot store as a path
            raise DemoError(where, f"feature name {key!r} cannot be stored ({first_line(result)})")
        if isinstance(result, BaseException):
            raise result
    copy_robot_files(meta.robot, robot_from, folder)
    if isinstance(folder, Path):  # on object storage the table makes the store present: written at its first commit
        episode_table.write_atomic(episode_table.empty_table(), folder / TABLE_FILE)
    return root


def remove_quietly(path: StorePath) -> None:
    try:
        if isinstance(path, Remote):
            path.remove()
        else:
            swap.remove(path)
    except Exception:
        pass  # the next writer of this path removes leftovers
