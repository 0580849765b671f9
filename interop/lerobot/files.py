"""Reading a LeRobotDataset v3.0 folder's files as untrusted input, for the import: ``meta/info.json``
(:func:`read_info`, sizes and path templates bounded), the ``meta/episodes`` and ``meta/tasks``
parquet, the data parquet files (each refused if it leads outside the folder), list columns as numpy
arrays and embedded images. Every problem is a :class:`~demo.errors.DemoError` naming the file.
"""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from demo.errors import DemoError, first_line
from demo.interop.lerobot.layout import CODEBASE_VERSION, INFO_PATH, TASKS_PATH
from demo.interop.untrusted import MAX_EPISODE_FRAMES, check_count, check_fps, check_template, inside

MAX_JSON_BYTES = 64 * 2**20  # meta/info.json is a few kB; a bigger one is not metadata
DATA_FIELDS = ("chunk_index", "file_index")
VIDEO_FIELDS = ("video_key", "chunk_index", "file_index", "episode_chunk", "episode_index")
VIDEO_LOCATORS = ("/chunk_index", "/file_index")  # of videos/<feature>/..., integers like the data's
# Integer columns of meta/episodes and what bounds them.
EPISODE_INTEGERS = ("episode_index", "length", "data/chunk_index", "data/file_index", "dataset_from_index",
                    "dataset_to_index")


def _read_json(path: Path) -> dict[str, Any]:
    try:
        if path.stat().st_size > MAX_JSON_BYTES:
            raise DemoError(path, f"is larger than {MAX_JSON_BYTES // 2**20} MiB: not dataset metadata")
        value = json.loads(path.read_bytes().decode("utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as exc:
        raise DemoError(path, f"is not valid JSON ({first_line(exc)})") from None
    if not isinstance(value, dict):
        raise DemoError(path, "is not a JSON object")
    return value


def read_parquet(root: Path, path: Path) -> pa.Table:
    """A parquet file of the dataset at ``root`` (refused if it leads outside it)."""
    inside(root, path)
    if not path.is_file():
        raise DemoError(path, "is missing")
    try:
        return pq.read_table(path)
    except (pa.ArrowException, OSError, ValueError) as exc:
        raise DemoError(path, f"corrupted parquet ({first_line(exc)})") from None


def read_info(root: Path) -> dict[str, Any]:
    """``meta/info.json`` of a LeRobot v3.0 folder, its numbers bounded and its path templates
    checked (:mod:`demo.interop.untrusted`); clear errors for anything else."""
    root = Path(root)
    if not root.exists():
        raise DemoError(root, "no such dataset")
    if not root.is_dir():
        raise DemoError(root, "is not a LeRobot dataset folder (not a directory)")
    info_path = inside(root, root / INFO_PATH)
    if not info_path.is_file():
        raise DemoError(root, f"is not a LeRobot dataset (no {INFO_PATH})")
    info = _read_json(info_path)
    version = info.get("codebase_version")
    if version != CODEBASE_VERSION:
        raise DemoError(
            info_path,
            f"unsupported LeRobot dataset version {version!r} (this demo reads {CODEBASE_VERSION}; "
            "convert it with LeRobot's v2.1 -> v3.0 conversion script first)",
        )
    for key in ("fps", "features", "total_episodes", "total_frames"):
        if key not in info:
            raise DemoError(info_path, f"has no {key!r}")
    if not isinstance(info["features"], dict) or "action" not in info["features"]:
        raise DemoError(info_path, "has no 'action' feature")
    if not all(isinstance(f, dict) for f in info["features"].values()):
        raise DemoError(info_path, "features must map names to {dtype, shape, names} objects")
    info["fps"] = check_fps(info["fps"], info_path)
    for key in ("total_episodes", "total_frames"):
        info[key] = check_count(info[key], info_path, key)
    if info.get("data_path") is not None:
        check_template(info["data_path"], info_path, "data_path", DATA_FIELDS)
    if info.get("video_path") is not None:
        check_template(info["video_path"], info_path, "video_path", VIDEO_FIELDS)
    return info


def episodes_table(root: Path, info: dict[str, Any]) -> pa.Table:
    folder = inside(root, root / "meta" / "episodes")
    files = sorted(folder.glob("chunk-*/file-*.parquet"))
    if not files:
        raise DemoError(folder, "has no episodes parquet files")
    tables = [read_parquet(root, f) for f in files]
    try:
        table = pa.concat_tables(tables, promote_options="permissive")
    except pa.ArrowException as exc:
        raise DemoError(files[0].parent, f"episodes parquet files do not agree ({first_line(exc)})") from None
    for column in ("episode_index", "length"):
        if column not in table.column_names:
            raise DemoError(files[0], f"has no column {column!r}")
    for column in table.column_names:
        if column in EPISODE_INTEGERS or (column.startswith("videos/") and column.endswith(VIDEO_LOCATORS)):
            _integers(table.column(column), f"{folder}: {column}")
    order = np.argsort(table.column("episode_index").to_numpy(), kind="stable")
    table = table.take(pa.array(order))
    indices = table.column("episode_index").to_numpy()
    if not np.array_equal(indices, np.arange(len(indices))):
        raise DemoError(files[0].parent, "episode_index is not 0..N-1")
    if len(indices) != info["total_episodes"]:
        raise DemoError(root / INFO_PATH, f"total_episodes is {info['total_episodes']} but meta/episodes lists {len(indices)}")
    lengths = table.column("length").to_numpy()
    if int(lengths.sum()) != info["total_frames"]:
        raise DemoError(
            root / INFO_PATH, f"total_frames is {info['total_frames']} but the episode lengths add up to {int(lengths.sum())}"
        )
    return table


def _integers(column: pa.ChunkedArray, where: str) -> None:
    """An integer column of counts or indices: no missing values, each within 0..MAX_EPISODE_FRAMES
    (so that sums cannot overflow and no range built from them is larger than the data)."""
    if not pa.types.is_integer(column.type):
        raise DemoError(where, f"has type {column.type}, expected integers")
    if column.null_count:
        raise DemoError(where, "has missing values")
    values = column.to_numpy()
    if len(values) and (values.min() < 0 or values.max() > MAX_EPISODE_FRAMES):
        raise DemoError(where, f"has values outside 0..{MAX_EPISODE_FRAMES}")


def read_tasks(root: Path) -> dict[int, str]:
    path = inside(root, root / TASKS_PATH)
    if not path.exists():
        return {}
    table = read_parquet(root, path)
    names = [n for n in ("task", "__index_level_0__") if n in table.column_names]
    if "task_index" not in table.column_names or not names:
        raise DemoError(path, "has no task / task_index columns")
    _integers(table.column("task_index"), f"{path}: task_index")
    return {int(i): str(t) for i, t in zip(table.column("task_index").to_pylist(), table.column(names[0]).to_pylist())}


def column_to_numpy(array: pa.Array | pa.ChunkedArray, where: str) -> np.ndarray:
    """A (nested) list column -> ``[T, *shape]``; a plain column -> ``[T]``."""
    if isinstance(array, pa.ChunkedArray):
        array = array.combine_chunks()
    if isinstance(array, pa.ExtensionArray):
        array = array.storage
    if array.null_count:
        raise DemoError(where, "has missing values")
    n = len(array)
    shape: list[int] = []
    while pa.types.is_fixed_size_list(array.type) or pa.types.is_list(array.type) or pa.types.is_large_list(array.type):
        if pa.types.is_fixed_size_list(array.type):
            width = array.type.list_size
        else:
            lengths = array.value_lengths().to_numpy(zero_copy_only=False)
            if len(lengths) and (lengths != lengths[0]).any():
                raise DemoError(where, f"has rows of mismatched lengths ({int(lengths.min())} to {int(lengths.max())})")
            width = int(lengths[0]) if len(lengths) else 0
        shape.append(width)
        array = array.flatten()
        if array.null_count:
            raise DemoError(where, "has missing values")
    return array.to_numpy(zero_copy_only=False).reshape(n, *shape)


def decode_images(array: pa.Array | pa.ChunkedArray, shape: tuple[int, ...], where: str) -> np.ndarray:
    """PNG/JPEG bytes -> uint8 ``[T, H, W, C]``; each image's size is checked against the declared
    ``shape`` from its header, before it is decoded."""
    from PIL import Image  # deferred: loaded only when a dataset embeds images

    if isinstance(array, pa.ChunkedArray):
        array = array.combine_chunks()
    if not pa.types.is_struct(array.type) or array.type.get_field_index("bytes") < 0:
        raise DemoError(where, f"image column has type {array.type}, expected struct<bytes, path>")
    if not pa.types.is_binary(array.type.field("bytes").type) and not pa.types.is_large_binary(array.type.field("bytes").type):
        raise DemoError(where, f"image bytes have type {array.type.field('bytes').type}, expected binary")
    frames = []
    for i, blob in enumerate(array.field("bytes").to_pylist()):
        if blob is None:
            raise DemoError(where, f"frame {i} has no embedded image bytes")
        try:
            image = Image.open(io.BytesIO(blob))
            if (image.height, image.width) != tuple(shape[:2]):
                raise DemoError(where, f"frame {i} is {image.width}x{image.height} pixels, the feature declares "
                                       f"{shape[1]}x{shape[0]}")
            if image.mode not in ("L", "RGB", "RGBA"):
                image = image.convert("RGB")
            img = np.asarray(image)
        except DemoError:
            raise
        except Exception as exc:  # PIL raises many types for bad image data
            raise DemoError(where, f"frame {i} is not a readable image ({first_line(exc)})") from None
        frames.append(img[:, :, None] if img.ndim == 2 else img)
    shapes = {f.shape for f in frames}
    if len(shapes) > 1:
        raise DemoError(where, f"images of different sizes: {sorted(shapes)}")
    return np.stack(frames)


def concat_data(where: Path, tables: list[pa.Table]) -> pa.Table:
    try:
        return pa.concat_tables(tables, promote_options="permissive")
    except pa.ArrowException as exc:
        raise DemoError(where, f"data files do not agree ({first_line(exc)})") from None
