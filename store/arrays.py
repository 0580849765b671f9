"""The store's zarr arrays (one per feature under ``data/``, and ``meta/episode_ends``): opening them,
all features concurrently, and checking them against the schema the root metadata declares and the
episode table. A mixin of :class:`~demo.store.episode_store.EpisodeStore`.
"""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import zarr
from zarr.core.sync import sync
from zarr.storage import StorePath as ZarrPath

from demo.errors import DemoError, first_line
from demo.store.layout import TABLE_FILE
from demo.store.location import StorePath
from demo.store.robot_files import ROBOT_DIR
from demo.store.spec import StoreMeta
from demo.store.zarr_io import gather


class StoreArrays:
    """Array access and the schema check at opening (see :class:`~demo.store.episode_store.EpisodeStore`)."""

    path: StorePath
    meta: StoreMeta
    _dir: StorePath
    _table: pa.Table
    _root: zarr.Group
    _arrays: dict[str, zarr.Array]

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
        opened = sync(gather(*(zarr.AsyncArray.open(ZarrPath(store, f"data/{k}"), zarr_format=3) for k in todo)))
        for key, array in zip(todo, opened):
            if isinstance(array, zarr.AsyncArray):
                self._arrays[key] = zarr.Array(array)

    def _ends_array(self) -> zarr.Array:
        if "meta/episode_ends" not in self._arrays:  # a group lookup reads metadata from disk: keep the array
            self._arrays["meta/episode_ends"] = _member(self._root, "meta", "episode_ends", self.path)
        return self._arrays["meta/episode_ends"]


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


def _member(root: zarr.Group, group: str, key: str, where: StorePath) -> zarr.Array:
    """``root[group][key]``, or DemoError naming the array's metadata file."""
    try:
        return root[group][key]
    except KeyError:
        raise DemoError(where / group / key, "array is missing") from None
    except Exception as exc:  # zarr raises several types for unreadable metadata
        raise DemoError(where / group / key / "zarr.json", f"unreadable array metadata ({first_line(exc)})") from None
