"""What every format converter shares: staged output, the report, episode-table columns, progress.

Converters never write into ``--out`` directly: holding ``--out``'s writer lock (the store's,
:mod:`demo.store.writer_lock`) from the start, they build the result in a hidden sibling
(``.NAME.tmp-PID``) and swap it into place at the end (:mod:`demo.store.swap`), so a failed or
interrupted export/import leaves no half-written dataset, a store another process is writing is
never replaced, and an existing ``--out`` is replaced only with ``overwrite=True`` and only when it
looks like the kind of thing being written.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import pyarrow as pa

from demo.errors import DemoError
from demo.progress import Progress, Tick, or_silent
from demo.store import EpisodeStore, swap
from demo.store.episode_table import FIXED_COLUMNS, MASK_PREFIX
from demo.store.location import StorePath, same_store
from demo.store.writer_lock import WriterLock

T = TypeVar("T")

# Episode-table columns a store derives itself (from lengths and fps); never carried.
DERIVED_COLUMNS = ("episode_index", "start", "length", "duration_s", "crc32")
# Fixed columns passed to ``append_episodes``; every other column is restored with its arrow type.
APPEND_COLUMNS = ("success", "seed", "source", "operator", "task")


@dataclass
class VideoReport:
    """One camera feature carried as MP4 video, and the pixel error of its round trip."""

    key: str  # store key (obs.image_<camera>)
    feature: str  # the dataset's feature name
    codec: str
    pix_fmt: str | None
    frames: int
    files: int
    # Mean and max absolute difference decoded - source over every pixel channel, 0-255 units;
    # None where there is no source to compare with (a foreign dataset).
    mean_abs_error: float | None
    max_abs_error: int | None
    # How the error was measured, in words: the export decodes the files it wrote; an import reports
    # the export's figure, saying whether it decoded the very frames that were measured.
    measured: str

    def to_json(self) -> dict[str, Any]:
        return dict(self.__dict__)


@dataclass
class InteropReport:
    """What an export or import did, for the CLI to print and tests to check."""

    format: str
    direction: str  # "export" | "import"
    source: Path
    path: Path
    episodes: int = 0
    frames: int = 0
    files: list[str] = field(default_factory=list)
    # Carried, but only in demo-specific metadata that the other tool ignores.
    extras: list[str] = field(default_factory=list)
    # What the target format cannot carry (or what could not be imported): the warning.
    dropped: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    videos: list[VideoReport] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        return {
            "format": self.format,
            "direction": self.direction,
            "source": str(self.source),
            "path": str(self.path),
            "episodes": self.episodes,
            "frames": self.frames,
            "files": list(self.files),
            "extras": list(self.extras),
            "dropped": list(self.dropped),
            "notes": list(self.notes),
            "videos": [v.to_json() for v in self.videos],
        }


def short_name(key: str) -> str:
    """``obs.joint_pos`` -> ``joint_pos``; keys without a prefix stay as they are."""
    return key.split(".", 1)[1] if "." in key else key


def camera_name(key: str) -> str:
    """``obs.image_front`` -> ``front`` (the store's camera naming convention)."""
    name = short_name(key)
    return name[len("image_"):] if name.startswith("image_") and len(name) > len("image_") else name


def now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())


# ---------------------------------------------------------------------------------------------- output
def _occupied(path: Path) -> bool:
    if path.is_dir():
        return any(path.iterdir())
    return path.exists() or path.is_symlink()


@contextlib.contextmanager
def staged_output(
    out: Path, *, overwrite: bool, looks_like: Callable[[Path], bool], kind: str, is_dir: bool
) -> Iterator[Path]:
    """Yield a temporary path next to ``out``; on success it replaces ``out`` by an atomic swap.

    ``out``'s writer lock is held throughout (refused with one line while another process holds
    it). ``looks_like(out)`` guards ``overwrite``: an existing ``out`` that is not a ``kind`` is
    never deleted. On any exception the temporary is removed and ``out`` is left untouched.
    """
    out = Path(out)
    lock = WriterLock.acquire(out)
    try:
        swap.recover(out)
        if _occupied(out):
            if not overwrite:
                raise DemoError(out, "already exists (pass --overwrite to replace it, or choose another --out)")
            if not looks_like(out):
                raise DemoError(out, f"exists and is not a {kind}; refusing to overwrite it")
        tmp = swap.staging_path(out)
        if is_dir:
            tmp.mkdir()
        try:
            yield tmp
        except BaseException:
            swap.remove(tmp)
            raise
        swap.publish(tmp, out)
    finally:
        lock.release()


def check_not_same(src: StorePath, out: StorePath) -> None:
    if same_store(src, out):
        raise DemoError(out, "is the input; write the output elsewhere")


# ---------------------------------------------------------------------------------------------- episode table
def carried_columns(store: EpisodeStore) -> list[tuple[str, pa.DataType]]:
    """Per-episode columns a converter must carry (everything but the derived ones), in table order."""
    schema = store.table.schema
    return [(f.name, f.type) for f in schema if f.name not in DERIVED_COLUMNS]


def append_info(row: dict[str, Any]) -> dict[str, Any]:
    """The fixed-column part of an episode row, for ``append_episodes``."""
    info = {k: row[k] for k in APPEND_COLUMNS if k in row and row[k] is not None}
    return info


def restore_columns(store: EpisodeStore, columns: Sequence[tuple[str, pa.Array]]) -> None:
    """Set extra per-episode columns with their exact arrow types, in the given order.

    ``append_episodes`` infers types from Python values; setting the columns afterwards from arrow
    arrays keeps int32/float32/null-bearing columns exactly as they were.
    """
    for name, array in columns:
        if name in FIXED_COLUMNS:
            continue
        if name.startswith(MASK_PREFIX):
            array = array.fill_null(False) if array.null_count else array
        # A list of arrow scalars: EpisodeStore.set_column rebuilds it with pa.array, type intact.
        store.set_column(name, [array[i] for i in range(len(array))])


def type_name(t: pa.DataType) -> str:
    return str(t)


def type_from_name(name: str) -> pa.DataType | None:
    try:
        return pa.type_for_alias(name)
    except (ValueError, KeyError):
        return None


# ---------------------------------------------------------------------------------------------- progress
def track(items: Iterable[T], total: int, stage: str, progress: Progress | None) -> Iterator[T]:
    """Yield ``items``, reporting each one done to ``progress`` (stage ``stage``, ``total`` episodes)."""
    report = or_silent(progress)
    report(Tick(stage, 0, total))
    for done, item in enumerate(items, 1):
        yield item
        report(Tick(stage, done, total))


def batches(
    items: Iterable[tuple[dict[str, np.ndarray], dict[str, Any]]], max_bytes: int = 128 * 2**20
) -> Iterator[list[tuple[dict[str, np.ndarray], dict[str, Any]]]]:
    """Group ``(data, info)`` episodes so each ``append_episodes`` commit holds about ``max_bytes``."""
    batch: list[tuple[dict[str, np.ndarray], dict[str, Any]]] = []
    size = 0
    for data, info in items:
        batch.append((data, info))
        size += sum(int(v.nbytes) for v in data.values())
        if size >= max_bytes:
            yield batch
            batch, size = [], 0
    if batch:
        yield batch
