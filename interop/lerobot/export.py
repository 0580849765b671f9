"""Store -> LeRobotDataset v3.0 folder: :func:`export_lerobot`.

The store's keys are mapped to LeRobot features by :func:`plan_columns` (see
:mod:`demo.interop.lerobot.layout`); frames go to the data parquet files, camera frames to MP4
(:mod:`demo.interop.lerobot.videos`) or embedded PNG, statistics to ``meta/stats.json`` and the
episodes' ``stats/*`` columns (:mod:`demo.interop.lerobot.stats`), and everything LeRobot has no
place for to info.json's ``demo`` block, so that the import restores the store bit-exact.
"""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from demo import __version__
from demo.errors import DemoError
from demo.interop.common import (
    InteropReport,
    camera_name,
    carried_columns,
    check_not_same,
    now,
    short_name,
    staged_output,
    track,
)
from demo.interop.lerobot import stats as lerobot_stats
from demo.interop.lerobot.layout import (
    CHUNKS_SIZE,
    CODEBASE_VERSION,
    DATA_FILE_MB,
    DATA_PATH,
    DONE,
    EPISODE_COLUMN_PREFIX,
    EPISODES_PATH,
    EXTRA_KEY,
    FRAME_COLUMNS,
    IMAGE_MODES,
    IMAGE_NAMES,
    INFO_PATH,
    REWARD,
    STATE,
    STATS_PATH,
    SUCCESS,
    TASKS_PATH,
    VIDEO_FILE_MB,
    VIDEO_PATH,
    Column,
    json_number,
)
from demo.interop.lerobot.videos import VideoWriter, video_info
from demo.interop.video import VideoSettings, unencodable
from demo.progress import Progress
from demo.store import EpisodeStore, StoreMeta
from demo.store.episode_store import EpisodeSelection
from demo.store.instructions import episode_instructions
from demo.store.location import store_path as locate_store
from demo.store.spec import is_image


def plan_columns(meta: StoreMeta, images: str = "video") -> list[Column]:
    """Map every store feature to a LeRobot feature (the table in :mod:`demo.interop.lerobot.layout`);
    cameras become videos with ``images="video"`` where frames can be encoded, else embedded PNG."""
    if images not in IMAGE_MODES:
        raise ValueError(f"images must be one of {IMAGE_MODES}, got {images!r}")
    taken = {STATE, DONE, SUCCESS, REWARD, *FRAME_COLUMNS}
    columns: list[Column] = []
    offset = 0

    def unique(name: str) -> str:
        candidate, n = name, 1
        while candidate in taken:
            n += 1
            candidate = f"{name}_{n}"
        taken.add(candidate)
        return candidate

    for key, spec in meta.features.items():
        shape = tuple(spec.shape)
        if key == "action":
            columns.append(Column(key, unique("action"), "array", shape, spec.dtype))
        elif key.startswith("obs.") and is_image(spec):
            kind = "video" if images == "video" and unencodable(shape) is None else "image"
            columns.append(Column(key, unique(f"observation.images.{camera_name(key)}"), kind, shape, spec.dtype))
        elif key.startswith("obs.") and spec.dtype == "float32":
            width = int(np.prod(shape, dtype=np.int64)) if shape else 1
            columns.append(Column(key, STATE, "state", shape, spec.dtype, offset, offset + width))
            offset += width
        else:  # other obs (float64/int/bool), sim.*, info.*: a column named like the store key
            columns.append(Column(key, unique(key), "array", shape, spec.dtype))
    return columns


def _state_names(meta: StoreMeta, columns: list[Column]) -> list[str]:
    names: list[str] = []
    for c in columns:
        if c.kind != "state":
            continue
        spec = meta.features[c.key]
        short = short_name(c.key)
        if spec.names is not None and len(spec.names) == c.width:
            names += [f"{short}.{n}" for n in spec.names]
        elif c.width == 1:
            names.append(short)
        else:
            names += [f"{short}.{i}" for i in range(c.width)]
    return names


def _features(meta: StoreMeta, columns: list[Column], settings: VideoSettings) -> dict[str, dict[str, Any]]:
    """info.json ``features``: name -> {dtype, shape, names} (and a video's ``info``), in data-column order."""
    features: dict[str, dict[str, Any]] = {}
    state_width = sum(c.width for c in columns if c.kind == "state")
    for c in columns:
        spec = meta.features[c.key]
        if c.kind == "state":
            if STATE not in features:
                features[STATE] = {"dtype": "float32", "shape": [state_width], "names": _state_names(meta, columns)}
        elif c.kind == "image":
            features[c.feature] = {"dtype": "image", "shape": list(c.shape), "names": list(IMAGE_NAMES)}
        elif c.kind == "video":
            features[c.feature] = {"dtype": "video", "shape": list(c.shape), "names": list(IMAGE_NAMES),
                                   "info": video_info(c.shape, float(meta.fps), settings)}
        else:
            names = list(spec.names) if spec.names is not None and len(spec.names) == c.width else None
            features[c.feature] = {"dtype": c.dtype, "shape": [c.width], "names": names}
    for name, dtype in (("timestamp", "float32"), *((n, "int64") for n in FRAME_COLUMNS[1:]), (DONE, "bool"),
                        (SUCCESS, "bool"), (REWARD, "float32")):
        features[name] = {"dtype": dtype, "shape": [1], "names": None}
    return features


def _hf_features(features: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """The Hugging Face ``datasets`` schema LeRobot would write into the parquet metadata (videos
    live in their own files, not in the parquet)."""
    out: dict[str, Any] = {}
    for name, f in features.items():
        if f["dtype"] == "video":
            continue
        if f["dtype"] == "image":
            out[name] = {"_type": "Image"}
        elif f["shape"] == [1]:
            out[name] = {"dtype": f["dtype"], "_type": "Value"}
        else:
            out[name] = {"feature": {"dtype": f["dtype"], "_type": "Value"}, "length": f["shape"][0], "_type": "Sequence"}
    return out


def _vector(values: np.ndarray) -> pa.Array:
    """``[T, *shape]`` -> a fixed-size-list column (flattened), or a plain column for one value a frame."""
    n = len(values)
    flat = np.ascontiguousarray(values).reshape(n, -1)
    if flat.shape[1] == 1:
        return pa.array(flat[:, 0])
    return pa.FixedSizeListArray.from_arrays(pa.array(flat.reshape(-1)), flat.shape[1])


def _png(image: np.ndarray) -> bytes:
    from PIL import Image  # deferred: loaded only when images are embedded

    buf = io.BytesIO()
    img = Image.fromarray(image[:, :, 0] if image.shape[2] == 1 else image)
    img.save(buf, format="PNG", compress_level=1)
    return buf.getvalue()


def _images(values: np.ndarray) -> pa.Array:
    data = pa.array([_png(frame) for frame in values], type=pa.binary())
    paths = pa.array([None] * len(values), type=pa.string())
    return pa.StructArray.from_arrays([data, paths], names=["bytes", "path"])


class _DataWriter:
    """Buffers frame tables and writes ``data/chunk-CCC/file-FFF.parquet`` files of ~``file_mb`` each."""

    def __init__(self, root: Path, hf_features: dict[str, Any], file_mb: float):
        self.root = root
        self.metadata = {b"huggingface": json.dumps({"info": {"features": hf_features}}).encode()}
        self.limit = file_mb * 2**20
        self.file_number = 0
        self.buffer: list[pa.Table] = []
        self.size = 0
        self.files: list[str] = []

    @property
    def location(self) -> tuple[int, int]:
        return divmod(self.file_number, CHUNKS_SIZE)

    def add(self, table: pa.Table) -> tuple[int, int]:
        """Buffer one episode's frames; return the (chunk_index, file_index) they land in."""
        where = self.location
        self.buffer.append(table)
        self.size += table.nbytes
        if self.size >= self.limit:
            self.flush()
        return where

    def flush(self) -> None:
        if not self.buffer:
            return
        chunk, file = self.location
        rel = DATA_PATH.format(chunk_index=chunk, file_index=file)
        path = self.root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        table = pa.concat_tables(self.buffer)
        table = table.replace_schema_metadata({**(table.schema.metadata or {}), **self.metadata})
        pq.write_table(table, path)
        self.files.append(rel)
        self.buffer, self.size = [], 0
        self.file_number += 1


def _tasks_table(tasks: list[str]) -> pa.Table:
    """tasks.parquet as pandas writes a frame indexed by ``task`` (``pd.read_parquet`` restores it)."""
    table = pa.table({"task_index": pa.array(range(len(tasks)), pa.int64()), "task": pa.array(tasks, pa.string())})
    pandas_meta = {
        "index_columns": ["task"],
        "column_indexes": [{"name": None, "field_name": None, "pandas_type": "unicode", "numpy_type": "object",
                            "metadata": {"encoding": "UTF-8"}}],
        "columns": [
            {"name": "task_index", "field_name": "task_index", "pandas_type": "int64", "numpy_type": "int64", "metadata": None},
            {"name": "task", "field_name": "task", "pandas_type": "unicode", "numpy_type": "object", "metadata": None},
        ],
        "creator": {"library": "pyarrow", "version": pa.__version__},
        "pandas_version": "2.2.3",
    }
    return table.replace_schema_metadata({b"pandas": json.dumps(pandas_meta).encode()})


def _is_lerobot_dir(path: Path) -> bool:
    return (path / INFO_PATH).is_file()


def export_lerobot(
    store_path: str | Path,
    out: str | Path,
    *,
    overwrite: bool = False,
    episodes: EpisodeSelection = None,
    images: str = "video",
    video: VideoSettings = VideoSettings(),
    data_file_mb: float = DATA_FILE_MB,
    video_file_mb: float = VIDEO_FILE_MB,
    progress: Progress | None = None,
) -> InteropReport:
    """Write the store's (selected) episodes as a LeRobotDataset v3.0 folder at ``out``.

    ``images``: ``"video"`` (MP4 files encoded with ``video``, LeRobot's default layout) or
    ``"embed"`` (PNG in the data parquet, lossless). ``progress``: a tick per episode written
    (stage ``export lerobot``)."""
    store_path, out = locate_store(store_path), Path(out)
    check_not_same(store_path, out)
    src = EpisodeStore.open(store_path)
    meta = src.meta
    chosen = src.select(episodes)
    if len(chosen) == 0:
        raise DemoError(store_path, "has no episodes to export")
    columns = plan_columns(meta, images)
    features = _features(meta, columns, video)
    carried = carried_columns(src)
    report = InteropReport("lerobot", "export", store_path, out, episodes=int(len(chosen)))

    # LeRobot's task is the episode's language: its instruction where it has one, else the task's name
    told = episode_instructions([src])
    task_column = [told[i] or str(name) for i, name in enumerate(src.column("task"))]
    success_column = src.column("success")
    tasks: dict[str, int] = {}
    for i in chosen:
        tasks.setdefault(task_column[i], len(tasks))

    accumulators = {name: lerobot_stats.StatsAccumulator(f["dtype"] in ("image", "video"))
                    for name, f in features.items()}
    episode_rows: list[dict[str, Any]] = []
    fps = float(meta.fps)
    with staged_output(out, overwrite=overwrite, looks_like=_is_lerobot_dir, kind="LeRobot dataset", is_dir=True) as tmp:
        writer = _DataWriter(tmp, _hf_features(features), data_file_mb)
        videos = {c.feature: VideoWriter(tmp, c, fps, video, video_file_mb,
                                          lambda i, key=c.key: src.read_episode(i, keys=[key])[key])
                  for c in columns if c.kind == "video"}
        index = 0
        try:
            for new_index, src_index in enumerate(track(chosen, len(chosen), "export lerobot", progress)):
                data = src.read_episode(int(src_index))
                length = len(data["action"])
                task_index = tasks[task_column[src_index]]
                values = _frame_values(columns, data, new_index, index, task_index, fps, bool(success_column[src_index]))
                table = pa.table({name: _arrow(features[name], v) for name, v in values.items() if name not in videos})
                chunk, file = writer.add(table)
                row: dict[str, Any] = {
                    "episode_index": new_index,
                    "tasks": [task_column[src_index]],
                    "length": length,
                    "data/chunk_index": chunk,
                    "data/file_index": file,
                    "dataset_from_index": index,
                    "dataset_to_index": index + length,
                    "meta/episodes/chunk_index": 0,
                    "meta/episodes/file_index": 0,
                }
                for feature, video in videos.items():
                    row.update(video.add(int(src_index), values[feature]))
                for name, v in values.items():
                    for stat, value in lerobot_stats.to_json(accumulators[name].add(v)).items():
                        row[f"stats/{name}/{stat}"] = value
                episode_rows.append(row)
                index += length
            writer.flush()
            for v in videos.values():
                v.flush()
        except BaseException:
            for v in videos.values():
                v.abandon()
            raise

        episode_table = pa.Table.from_pylist(episode_rows)
        for name, dtype in carried:
            values = src.table.column(name).take(pa.array(chosen))
            episode_table = episode_table.append_column(pa.field(EPISODE_COLUMN_PREFIX + name, dtype), values)
        episodes_rel = EPISODES_PATH.format(chunk_index=0, file_index=0)
        (tmp / episodes_rel).parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(episode_table, tmp / episodes_rel)
        pq.write_table(_tasks_table(list(tasks)), tmp / TASKS_PATH)
        stats = {name: lerobot_stats.to_json(acc.result()) for name, acc in accumulators.items()}
        (tmp / STATS_PATH).write_text(json.dumps(stats, indent=2) + "\n")

        store_meta = meta.to_json()
        store_meta["provenance"] = [*meta.provenance, {
            "op": "export", "format": "lerobot", "codebase_version": CODEBASE_VERSION, "from": str(store_path),
            "episodes": int(len(chosen)), "time": now(), "demo": __version__,
        }]
        extras = {
            "format": meta.format,
            "schema_version": meta.schema_version,
            "store_meta": store_meta,
            "columns": [c.to_json() for c in columns],
            "episode_columns": [name for name, _ in carried],
            "source_episodes": [int(i) for i in chosen] if len(chosen) != src.num_episodes else None,
            "images": images,
            "videos": {feature: v.extras() for feature, v in videos.items()},
        }
        info = {
            "codebase_version": CODEBASE_VERSION,
            "robot_type": (meta.robot or {}).get("name"),
            "total_episodes": int(len(chosen)),
            "total_frames": index,
            "total_tasks": len(tasks),
            "chunks_size": CHUNKS_SIZE,
            "data_files_size_in_mb": data_file_mb,
            "video_files_size_in_mb": video_file_mb,
            "fps": json_number(fps),
            "splits": {"train": f"0:{len(chosen)}"},
            "data_path": DATA_PATH,
            "video_path": VIDEO_PATH if videos else None,
            "features": features,
            EXTRA_KEY: extras,
        }
        (tmp / INFO_PATH).write_text(json.dumps(info, indent=2) + "\n")
        report.files = [INFO_PATH, STATS_PATH, TASKS_PATH, episodes_rel, *writer.files,
                        *(f for v in videos.values() for f in v.files)]
    report.frames = index
    report.extras = _extras_list(meta, carried)
    report.videos = [v.report() for v in videos.values()]
    for c in columns:
        if c.kind == "image":
            why = "embedding was asked for" if images == "embed" else unencodable(c.shape)
            report.notes.append(f"{c.key}: PNG embedded in the data parquet (dtype image, lossless), not MP4: {why}")
    own = [f"{c.key} ({c.dtype})" for c in columns if c.key.startswith("obs.") and c.kind == "array"]
    if own:
        report.notes.append("not float32, so kept out of observation.state (columns named like the store key, "
                            "which LeRobot policies do not read): " + ", ".join(own))
    flattened = [c.key for c in columns if c.kind == "array" and len(c.shape) > 1]
    if flattened:
        report.notes.append(f"flattened to 1-D for LeRobot (shape kept in the extras): {', '.join(flattened)}")
    return report


def _extras_list(meta: StoreMeta, carried: list[tuple[str, pa.DataType]]) -> list[str]:
    params = f", params {', '.join(meta.action.params)}" if meta.action.params else ""
    items = [
        f"action representation '{meta.action.name}' (frame {meta.action.frame}, units){params}",
        "feature units and descriptions, robot and task metadata, provenance",
        "the split of observation.state into obs.* keys",
    ]
    if carried:
        items.append("per-episode columns " + ", ".join(name for name, _ in carried) + " (episodes parquet demo/*)")
    return items


def _frame_values(
    columns: list[Column], data: dict[str, np.ndarray], episode: int, start: int, task_index: int, fps: float,
    success: bool = False,
) -> dict[str, np.ndarray]:
    """One episode's LeRobot columns as numpy arrays (images stay uint8 [T, H, W, C])."""
    length = len(data["action"])
    values: dict[str, np.ndarray] = {}
    state = [data[c.key].reshape(length, -1) for c in columns if c.kind == "state"]
    for c in columns:
        if c.kind == "state":
            if STATE not in values:
                values[STATE] = np.concatenate(state, axis=1) if len(state) > 1 else state[0]
        else:
            values[c.feature] = data[c.key]
    frame_index = np.arange(length, dtype=np.int64)
    values["timestamp"] = (frame_index / fps).astype(np.float32)
    values["frame_index"] = frame_index
    values["episode_index"] = np.full(length, episode, dtype=np.int64)
    values["index"] = start + frame_index
    values["task_index"] = np.full(length, task_index, dtype=np.int64)
    values[DONE] = frame_index == length - 1
    values[SUCCESS] = values[DONE] & success  # the episode's outcome on its last frame (layout: SUCCESS)
    values[REWARD] = values[SUCCESS].astype(np.float32)
    return values


def _arrow(feature: dict[str, Any], values: np.ndarray) -> pa.Array:
    return _images(values) if feature["dtype"] == "image" else _vector(values)
