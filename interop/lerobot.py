"""LeRobotDataset v3.0 (lerobot >= 0.4.0) export and import.

Layout written by :func:`export_lerobot` (and read by :func:`import_lerobot`)::

    DIR/
      meta/info.json                             codebase_version "v3.0", fps, features, totals, paths
      meta/stats.json                            per feature: min max mean std count q01 q10 q50 q90 q99
      meta/tasks.parquet                         task (index) -> task_index
      meta/episodes/chunk-000/file-000.parquet   one row per episode (see below)
      data/chunk-000/file-000.parquet            one row per frame; a new file every ~100 MB
      videos/<camera feature>/chunk-000/file-000.mp4   the camera's frames, episodes one after another;
                                                 a new file every ~500 MB

How store keys become LeRobot features:

=====================  ==========================================================================
store                  LeRobot
=====================  ==========================================================================
``action``             ``action`` float32 [d], names = the action spec's names
float32 ``obs.*``      concatenated, in feature order, into ``observation.state`` float32; the
                       split is recorded in the feature's ``names`` (``joint_pos.j1``, ...)
uint8 [H,W,3] ``obs``  ``observation.images.<camera>``, ``dtype: video`` (the default): MP4 files in
                       LeRobot's ``videos/`` layout, AV1 ``yuv420p`` as LeRobot encodes them
                       (:mod:`demo.interop.video`; lossy: the export decodes what it wrote and
                       reports the pixel error); with ``images="embed"``, and for 1- or 4-channel
                       or tiny cameras, ``dtype: image``: PNG bytes embedded in the data parquet
                       (lossless)
other ``obs.*``,       extra columns named like the store key, dtype kept (``sim.state`` float64,
``sim.*``, ``info.*``  a float64/int/bool ``obs.*``): LeRobot reads every ``observation*`` feature
                       as a policy input, so only float32 obs go under ``observation.``
(structure)            ``timestamp`` float32 = frame_index / fps, ``frame_index``,
                       ``episode_index``, ``index``, ``task_index`` int64, ``next.done`` bool
=====================  ==========================================================================

Features of more than one dimension that are not images are flattened (LeRobot reads 1-D
sequences), their shape kept in the extras. Everything LeRobot has no place for (the store's
metadata: action representation name, params and units, robot, task options, provenance; the
exact key split) goes into ``meta/info.json`` under the ``"demo"`` key, which LeRobot ignores;
per-episode columns (success, seed, source, operator, masks, scores, ...) go into the episodes
parquet as ``demo/<column>`` with their arrow types. Together they make store -> LeRobot -> store
bit-exact. Episodes parquet columns: ``episode_index``, ``tasks``, ``length``,
``data/chunk_index``, ``data/file_index``, ``dataset_from_index``, ``dataset_to_index``,
``meta/episodes/chunk_index``, ``meta/episodes/file_index``, ``stats/<feature>/<stat>``,
``demo/<column>``, and per video feature ``videos/<feature>/chunk_index``, ``file_index``,
``from_timestamp``, ``to_timestamp`` (seconds into its file: frame ``k`` of the episode is presented
at ``from_timestamp + k / fps``).
"""

from __future__ import annotations

import io
import json
import math
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from demo import __version__
from demo.errors import DemoError
from demo.interop import lerobot_stats
from demo.interop.common import (
    InteropReport,
    VideoReport,
    append_info,
    batches,
    camera_name,
    carried_columns,
    check_not_same,
    first_line,
    is_image,
    now,
    restore_columns,
    short_name,
    staged_output,
    track,
)
from demo.interop.video import ClipWriter, PixelError, StreamInfo, VideoDecoder, VideoSettings, encode_clip, unencodable
from demo.interop.untrusted import (
    MAX_EPISODE_FRAMES,
    check_count,
    check_feature,
    check_fps,
    check_info,
    check_meta,
    check_template,
    contained,
    inside,
    store_key,
)
from demo.progress import Progress
from demo.store import ActionSpec, EpisodeStore, FeatureSpec, StoreMeta
from demo.store.episode_store import EpisodeSelection
from demo.store.location import store_path as locate_store

CODEBASE_VERSION = "v3.0"
CHUNKS_SIZE = 1000
DATA_FILE_MB = 100
VIDEO_FILE_MB = 500
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
VIDEO_PATH = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
EPISODES_PATH = "meta/episodes/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
INFO_PATH = "meta/info.json"
STATS_PATH = "meta/stats.json"
TASKS_PATH = "meta/tasks.parquet"
EXTRA_KEY = "demo"
EPISODE_COLUMN_PREFIX = "demo/"
STATE = "observation.state"
FRAME_COLUMNS = ("timestamp", "frame_index", "episode_index", "index", "task_index")
DONE = "next.done"
IMAGE_NAMES = ["height", "width", "channels"]
IMAGE_MODES = ("video", "embed")  # how camera features are exported: MP4 videos or PNG in the parquet


@dataclass(frozen=True)
class Column:
    """Where one store key lives in the LeRobot dataset."""

    key: str  # store key
    feature: str  # LeRobot feature name
    kind: str  # "state": a slice of observation.state | "image" (PNG in parquet) | "video" (MP4) | "array"
    shape: tuple[int, ...]  # store frame shape
    dtype: str
    start: int = 0  # slice of observation.state (kind "state")
    stop: int = 0

    @property
    def width(self) -> int:
        return int(np.prod(self.shape, dtype=np.int64)) if self.shape else 1

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["shape"] = list(self.shape)
        return d

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> "Column":
        return cls(
            key=str(d["key"]), feature=str(d["feature"]), kind=str(d["kind"]),
            shape=tuple(int(s) for s in d["shape"]), dtype=str(d["dtype"]),
            start=int(d.get("start", 0)), stop=int(d.get("stop", 0)),
        )


# ================================================================================================ export
def plan_columns(meta: StoreMeta, images: str = "video") -> list[Column]:
    """Map every store feature to a LeRobot feature (see the module docstring); cameras become
    videos with ``images="video"`` where frames can be encoded, else embedded PNG."""
    if images not in IMAGE_MODES:
        raise ValueError(f"images must be one of {IMAGE_MODES}, got {images!r}")
    taken = {STATE, DONE, *FRAME_COLUMNS}
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
                                   "info": _video_info(c.shape, float(meta.fps), settings)}
        else:
            names = list(spec.names) if spec.names is not None and len(spec.names) == c.width else None
            features[c.feature] = {"dtype": c.dtype, "shape": [c.width], "names": names}
    for name, dtype in (("timestamp", "float32"), *((n, "int64") for n in FRAME_COLUMNS[1:]), (DONE, "bool")):
        features[name] = {"dtype": dtype, "shape": [1], "names": None}
    return features


def _video_info(shape: tuple[int, ...], fps: float, settings: VideoSettings) -> dict[str, Any]:
    """A video feature's ``info`` block, as LeRobot describes the files it encodes."""
    return {
        "video.height": shape[0],
        "video.width": shape[1],
        "video.codec": "av1" if settings.codec == "libsvtav1" else settings.codec,
        "video.pix_fmt": settings.pix_fmt,
        "video.is_depth_map": False,
        "video.fps": _number(fps),
        "video.channels": shape[2],
        "has_audio": False,
    }


def _number(fps: float) -> int | float:
    return int(fps) if fps.is_integer() else fps


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
    from PIL import Image

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


class _VideoWriter:
    """One camera feature's ``videos/<feature>/chunk-CCC/file-FFF.mp4`` files: each episode is
    encoded on its own and appended to the current file (as LeRobot concatenates them); an episode
    that would bring a file to ``file_mb`` starts the next one.

    Each finished file is decoded again and compared with the source frames (``reference(episode)``,
    read from the store anew rather than kept in memory), giving the exact round-trip error."""

    def __init__(self, root: Path, column: Column, fps: float, settings: VideoSettings, file_mb: float,
                 reference: Callable[[int], np.ndarray]):
        self.root, self.column, self.fps, self.settings = root, column, fps, settings
        self.limit = file_mb * 2**20
        self.reference = reference
        self.file_number = 0
        self.writer: ClipWriter | None = None
        self.in_file: list[tuple[int, int, int]] = []  # (source episode, first frame in the file, length)
        self.files: list[str] = []
        self.error = PixelError()

    def _path(self, file_number: int) -> str:
        chunk, file = divmod(file_number, CHUNKS_SIZE)
        return VIDEO_PATH.format(video_key=self.column.feature, chunk_index=chunk, file_index=file)

    def add(self, source_episode: int, frames: np.ndarray) -> dict[str, Any]:
        """Encode one episode's frames; return its ``videos/<feature>/*`` episode columns."""
        clip = encode_clip(frames, self.fps, self.settings, self.root / self._path(self.file_number))
        if self.writer is not None and self.writer.bytes + len(clip) >= self.limit:
            self.flush()
        if self.writer is None:
            path = self.root / self._path(self.file_number)
            path.parent.mkdir(parents=True, exist_ok=True)
            self.writer = ClipWriter(path, self.fps)
        start = self.writer.frames
        self.writer.append(clip, len(frames))
        self.in_file.append((source_episode, start, len(frames)))
        chunk, file = divmod(self.file_number, CHUNKS_SIZE)
        prefix = f"videos/{self.column.feature}/"
        return {prefix + "chunk_index": chunk, prefix + "file_index": file,
                prefix + "from_timestamp": start / self.fps, prefix + "to_timestamp": (start + len(frames)) / self.fps}

    def flush(self) -> None:
        """Finish the current file and measure it against the source frames."""
        if self.writer is None:
            return
        self.writer.close()
        with VideoDecoder(self.writer.path, self.column.shape) as decoder:
            for episode, start, length in self.in_file:
                self.error.add(self.reference(episode), decoder.read(start / self.fps, length, self.fps))
        self.files.append(self._path(self.file_number))
        self.writer, self.in_file = None, []
        self.file_number += 1

    def abandon(self) -> None:
        """Close an unfinished file (the export failed; its folder is removed)."""
        if self.writer is not None:
            self.writer.abandon()
            self.writer = None

    def report(self) -> VideoReport:
        return VideoReport(self.column.key, self.column.feature, _video_info(self.column.shape, self.fps, self.settings)
                           ["video.codec"], self.settings.pix_fmt, self.error.frames, len(self.files),
                           self.error.mean_abs, self.error.max_abs, "decoded the written files")

    def extras(self) -> dict[str, Any]:
        """What info.json's ``demo`` block records of this video (the import reports it)."""
        return {"codec": self.settings.codec, "pix_fmt": self.settings.pix_fmt, "crf": self.settings.crf,
                "gop": self.settings.gop, "frames": self.error.frames, "mean_abs_error": self.error.mean_abs,
                "max_abs_error": self.error.max_abs, "decoded_crc32": self.error.crc32}


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

    task_column = src.column("task")
    tasks: dict[str, int] = {}
    for i in chosen:
        tasks.setdefault(str(task_column[i]), len(tasks))

    accumulators = {name: lerobot_stats.StatsAccumulator(f["dtype"] in ("image", "video"))
                    for name, f in features.items()}
    episode_rows: list[dict[str, Any]] = []
    fps = float(meta.fps)
    with staged_output(out, overwrite=overwrite, looks_like=_is_lerobot_dir, kind="LeRobot dataset", is_dir=True) as tmp:
        writer = _DataWriter(tmp, _hf_features(features), data_file_mb)
        videos = {c.feature: _VideoWriter(tmp, c, fps, video, video_file_mb,
                                          lambda i, key=c.key: src.read_episode(i, keys=[key])[key])
                  for c in columns if c.kind == "video"}
        index = 0
        try:
            for new_index, src_index in enumerate(track(chosen, len(chosen), "export lerobot", progress)):
                data = src.read_episode(int(src_index))
                length = len(data["action"])
                task_index = tasks[str(task_column[src_index])]
                values = _frame_values(columns, data, new_index, index, task_index, fps)
                table = pa.table({name: _arrow(features[name], v) for name, v in values.items() if name not in videos})
                chunk, file = writer.add(table)
                row: dict[str, Any] = {
                    "episode_index": new_index,
                    "tasks": [str(task_column[src_index])],
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
            "fps": _number(fps),
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
    columns: list[Column], data: dict[str, np.ndarray], episode: int, start: int, task_index: int, fps: float
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
    return values


def _arrow(feature: dict[str, Any], values: np.ndarray) -> pa.Array:
    return _images(values) if feature["dtype"] == "image" else _vector(values)


# ================================================================================================ import
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


def _read_parquet(root: Path, path: Path) -> pa.Table:
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


def _episodes_table(root: Path, info: dict[str, Any]) -> pa.Table:
    folder = inside(root, root / "meta" / "episodes")
    files = sorted(folder.glob("chunk-*/file-*.parquet"))
    if not files:
        raise DemoError(folder, "has no episodes parquet files")
    tables = [_read_parquet(root, f) for f in files]
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


def _tasks(root: Path) -> dict[int, str]:
    path = inside(root, root / TASKS_PATH)
    if not path.exists():
        return {}
    table = _read_parquet(root, path)
    names = [n for n in ("task", "__index_level_0__") if n in table.column_names]
    if "task_index" not in table.column_names or not names:
        raise DemoError(path, "has no task / task_index columns")
    _integers(table.column("task_index"), f"{path}: task_index")
    return {int(i): str(t) for i, t in zip(table.column("task_index").to_pylist(), table.column(names[0]).to_pylist())}


def _to_numpy(array: pa.Array | pa.ChunkedArray, where: str) -> np.ndarray:
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


def _decode_images(array: pa.Array | pa.ChunkedArray, shape: tuple[int, ...], where: str) -> np.ndarray:
    """PNG/JPEG bytes -> uint8 ``[T, H, W, C]``; each image's size is checked against the declared
    ``shape`` from its header, before it is decoded."""
    from PIL import Image

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


def _foreign_plan(info: dict[str, Any], info_path: Path, report: InteropReport) -> tuple[list[Column], StoreMeta]:
    """Store keys and metadata for a LeRobot dataset not written by demo (names made store keys,
    shapes and dtypes bounded: :mod:`demo.interop.untrusted`)."""
    features: dict[str, dict[str, Any]] = info["features"]
    structural = {*FRAME_COLUMNS, DONE}
    columns: list[Column] = []
    specs: dict[str, FeatureSpec] = {}
    action_spec: ActionSpec | None = None
    taken = {"action"}
    for name, f in features.items():
        if name in structural:
            continue
        dtype, shape = str(f.get("dtype")), f.get("shape", [])
        if not isinstance(shape, list) or len(shape) > 8:
            raise DemoError(info_path, f"feature {name!r}: shape {shape!r} is not a list of sizes")
        names = _flat_names(f.get("names"))
        if dtype == "string":
            report.dropped.append(f"{name}: per-frame strings (a store holds numeric arrays only)")
            continue
        if dtype in ("image", "video"):
            hwc = _image_shape(tuple(shape), names, info_path)
            if dtype == "video" and hwc[2] != 3:
                report.dropped.append(f"{name}: a video of {hwc[2]} channels (videos are decoded as RGB)")
                continue
            camera = name[len("observation.images."):] if name.startswith("observation.images.") else name
            key = store_key("obs", "image_" + camera.replace(".", "_"), taken, info_path)
            hwc, _ = check_feature(key, hwc, "uint8", info_path)
            columns.append(Column(key, name, dtype, hwc, "uint8"))
            specs[key] = FeatureSpec(hwc, "uint8", f"camera {name}", "rgb")
            continue
        try:
            np.dtype(dtype)
        except TypeError:
            report.dropped.append(f"{name}: dtype {dtype!r} unknown")
            continue
        if name == "action":
            width = math.prod(check_feature("action", shape, dtype, info_path)[0])
            labels = tuple(names) if names and len(names) == width else tuple(f"a{i}" for i in range(width))
            action_spec = ActionSpec("unknown", labels, ("",) * width, frame="unknown",
                                     description="imported from LeRobot; representation not recorded",
                                     params={"source": "lerobot"})
            if dtype != "float32":
                report.dropped.append(f"action: {dtype} values stored as float32 (a store's actions are float32)")
            columns.append(Column("action", name, "array", (width,), "float32"))
            continue
        prefix, rest = "info", name
        if name.startswith("observation."):
            prefix, rest = "obs", name[len("observation."):]
        elif name.startswith(("obs.", "sim.", "info.")):
            prefix, rest = name.split(".", 1)
        elif name.startswith("next."):
            rest = name[len("next."):]
        key = store_key(prefix, rest.replace(".", "_"), taken, info_path)
        store_shape, store_dtype = check_feature(key, shape, dtype, info_path)
        columns.append(Column(key, name, "array", store_shape, store_dtype))
        specs[key] = FeatureSpec(store_shape, store_dtype, f"LeRobot feature {name}",
                                 names=tuple(names) if names and len(names) == math.prod(store_shape) else None)
    if action_spec is None:
        raise DemoError(info_path, "has no 'action' feature")
    meta = StoreMeta(
        fps=info["fps"], features=specs, action=action_spec, robot={"name": str(info.get("robot_type") or "unknown")[:200]}
    )
    return columns, meta


def _image_shape(shape: tuple[Any, ...], names: list[str] | None, info_path: Path) -> tuple[int, int, int]:
    """``[H, W, C]`` from a declared image shape, which older datasets give as ``[C, H, W]``."""
    if len(shape) != 3 or not all(isinstance(s, int) and not isinstance(s, bool) for s in shape):
        raise DemoError(info_path, f"image feature shape {list(shape)} is not 3 sizes")
    if names == ["channels", "height", "width"] or (shape[2] not in (1, 3, 4) and shape[0] in (1, 3, 4)):
        return (shape[1], shape[2], shape[0])
    return (shape[0], shape[1], shape[2])


def _flat_names(names: Any) -> list[str] | None:
    if isinstance(names, list) and all(isinstance(n, str) for n in names):
        return names
    if isinstance(names, dict):  # LeRobot v2.0 style {"motors": [...]}
        flat = [n for v in names.values() if isinstance(v, list) for n in v]
        return flat or None
    return None


def import_lerobot(
    src_dir: str | Path,
    out: str | Path,
    *,
    overwrite: bool = False,
    progress: Progress | None = None,
) -> InteropReport:
    """Read a LeRobotDataset v3.0 folder into a new store at ``out``.

    ``progress``: a tick per episode read (stage ``import lerobot``)."""
    root, out = Path(src_dir), Path(out)
    check_not_same(root, out)
    info = read_info(root)
    info_path = root / INFO_PATH
    report = InteropReport("lerobot", "import", root, out)
    episodes = _episodes_table(root, info)
    tasks = _tasks(root)
    extras = info.get(EXTRA_KEY) if isinstance(info.get(EXTRA_KEY), dict) else None
    if extras is not None:
        columns, meta = _own_plan(extras, info_path)
        used = {c.feature for c in columns} | set(FRAME_COLUMNS) | {DONE}
        for name in info["features"]:
            if name not in used:
                report.dropped.append(f"{name}: feature added after the export by demo (not in its key map)")
    else:
        columns, meta = _foreign_plan(info, info_path, report)
        task_list = [tasks[i] for i in sorted(tasks)]
        meta.task = {"name": task_list[0] if len(task_list) == 1 else "lerobot", "lerobot_tasks": task_list}
    for c in columns:
        if c.feature not in info["features"]:
            raise DemoError(info_path, f"feature {c.feature!r} (for {c.key}) is not declared")
    meta.provenance = [*meta.provenance, {"op": "import", "format": "lerobot", "from": str(root), "time": now()}]
    episode_columns = [n for n in episodes.column_names if n.startswith(EPISODE_COLUMN_PREFIX)]
    if extras is None:
        report.notes.append("success is not recorded in a LeRobot dataset: every episode is marked success=True"
                            if "next.success" not in info["features"] else "success = next.success of each episode's last frame")
    data_path = info.get("data_path") or DATA_PATH
    has_location = {"data/chunk_index", "data/file_index"} <= set(episodes.column_names)

    rows_in_files: dict[Path, int] = {}

    def frames() -> Any:
        cache: tuple[Path | None, pa.Table | None] = (None, None)
        for i in range(episodes.num_rows):
            row = {k: episodes.column(k)[i].as_py() for k in episodes.column_names if not k.startswith("stats/")}
            if has_location:
                rel = data_path.format(chunk_index=row["data/chunk_index"], file_index=row["data/file_index"])
                path = contained(root, rel, info_path, "data_path")
            else:  # no file index per episode: read every data file once
                path = inside(root, root / "data")
            if cache[0] != path:
                if has_location:
                    cache = (path, _read_parquet(root, path))
                else:
                    files = sorted(path.glob("chunk-*/file-*.parquet"))
                    if not files:
                        raise DemoError(path, "has no chunk-*/file-*.parquet data files")
                    cache = (path, _concat(path, [_read_parquet(root, f) for f in files]))
                rows_in_files[path] = cache[1].num_rows
            table = cache[1]
            yield i, row, path, table

    def episodes_data() -> Any:
        for i, row, path, table in track(frames(), episodes.num_rows, "import lerobot", progress):
            data, info_row = _episode_from_table(i, row, path, table, columns, tasks, extras is not None, videos)
            yield data, info_row

    frames_total = 0
    videos = _VideoReader(root, info, root / "meta" / "episodes")
    with staged_output(out, overwrite=overwrite, looks_like=lambda p: (p / "zarr.json").is_file(),
                       kind="demo store", is_dir=True) as tmp:
        store = EpisodeStore.create(tmp, meta, overwrite=True)
        try:
            for batch in batches(episodes_data()):
                store.append_episodes(batch)
                frames_total += sum(len(d["action"]) for d, _ in batch)
            if sum(rows_in_files.values()) != int(info["total_frames"]):
                raise DemoError(root / "data", f"the data files hold {sum(rows_in_files.values())} frames but "
                                f"info.json total_frames is {info['total_frames']} (mismatched lengths)")
            try:
                restore_columns(store, [(n[len(EPISODE_COLUMN_PREFIX):], episodes.column(n).combine_chunks())
                                        for n in episode_columns])
            except (pa.ArrowException, TypeError, ValueError) as exc:
                raise DemoError(root / "meta" / "episodes", f"per-episode columns {EPISODE_COLUMN_PREFIX}* cannot be "
                                f"restored ({first_line(exc)})") from None
        finally:
            store.close()
            videos.close()
    report.videos = [videos.report(c, extras) for c in columns if c.kind == "video"]
    report.episodes = int(episodes.num_rows)
    report.frames = frames_total
    report.files = [str(out)]
    return report


def _episode_from_table(
    i: int,
    row: dict[str, Any],
    path: Path,
    table: pa.Table,
    columns: list[Column],
    tasks: dict[int, str],
    ours: bool,
    videos: "_VideoReader",
) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """One episode's store arrays and fixed per-episode info from its data-file rows (and videos)."""
    for col in ("episode_index", "frame_index"):
        if col not in table.column_names:
            raise DemoError(path, f"has no column {col!r}")
    episode_index = table.column("episode_index").to_numpy()
    rows = np.flatnonzero(episode_index == i)
    length = int(row["length"])
    if len(rows) != length:
        raise DemoError(path, f"episode {i} has {len(rows)} frames but meta/episodes says length {length} (mismatched lengths)")
    ep = table.take(pa.array(rows))
    order = np.argsort(ep.column("frame_index").to_numpy(), kind="stable")
    ep = ep.take(pa.array(order))
    if not np.array_equal(ep.column("frame_index").to_numpy(), np.arange(length)):
        raise DemoError(path, f"episode {i}: frame_index is not 0..{length - 1}")
    if "index" in ep.column_names and row.get("dataset_from_index") is not None:
        start, stop = row["dataset_from_index"], row.get("dataset_to_index")
        # The span is checked against the length before a range is built from it.
        if stop is None or stop - start != length or not np.array_equal(ep.column("index").to_numpy(), np.arange(start, stop)):
            raise DemoError(path, f"episode {i}: index does not span dataset_from_index..dataset_to_index")
    data: dict[str, np.ndarray] = {}
    state: np.ndarray | None = None
    for c in columns:
        if c.kind == "video":
            data[c.key] = videos.frames(c, i, row, length)
            continue
        if c.feature not in ep.column_names:
            raise DemoError(path, f"has no column {c.feature!r}")
        where = f"{path}: {c.feature}"
        if c.kind == "image":
            data[c.key] = _decode_images(ep.column(c.feature), c.shape, where)
            if data[c.key].shape[1:] != c.shape:
                raise DemoError(where, f"images are {list(data[c.key].shape[1:])}, the feature declares {list(c.shape)}")
            continue
        if c.kind == "state":
            if state is None:
                state = _to_numpy(ep.column(c.feature), where).reshape(length, -1)
            values = state[:, c.start:c.stop]
        else:
            values = _to_numpy(ep.column(c.feature), where)
        expected = int(np.prod(c.shape, dtype=np.int64)) if c.shape else 1
        if values.size != length * expected:
            raise DemoError(where, f"has {values.size // max(length, 1)} values a frame, expected {expected}")
        values = values.reshape(length, *c.shape)
        if ours and values.dtype != np.dtype(c.dtype):
            raise DemoError(where, f"dtype {values.dtype} does not match {c.dtype}")
        data[c.key] = values.astype(c.dtype, copy=False)
    task_list = row.get("tasks") if isinstance(row.get("tasks"), list) else []
    listed = str(task_list[0]) if task_list else ""
    task_index = ep.column("task_index")[0].as_py() if "task_index" in ep.column_names and length else None
    task = tasks.get(task_index, listed) if isinstance(task_index, int) else listed
    episode_info: dict[str, Any] = {}
    if ours:
        for key in ("success", "seed", "source", "operator", "task"):
            value = row.get(EPISODE_COLUMN_PREFIX + key)
            if value is not None:
                episode_info[key] = value
    else:
        success = True
        if "next.success" in ep.column_names:
            success = bool(np.asarray(_to_numpy(ep.column("next.success"), str(path))).reshape(length, -1)[-1].any())
        episode_info = {"success": success, "seed": -1, "source": "imported", "operator": "", "task": task}
    return data, append_info(check_info(episode_info, f"{path}: episode {i}"))


class _VideoReader:
    """Video features' frames, episode by episode, from the files ``meta/episodes`` points at
    (``video_path`` filled with its ``videos/<feature>/chunk_index`` and ``file_index``), starting
    at its ``from_timestamp``; one file open per feature at a time."""

    def __init__(self, root: Path, info: dict[str, Any], episodes_where: Path):
        self.root, self.info_path, self.where = root, root / INFO_PATH, episodes_where
        self.template: str | None = info.get("video_path")
        self.fps = float(info["fps"])
        self.open: dict[str, tuple[Path, VideoDecoder]] = {}
        self.decoded: dict[str, PixelError] = {}
        self.files: dict[str, set[Path]] = {}
        self.streams: dict[str, StreamInfo] = {}

    def frames(self, c: Column, episode: int, row: dict[str, Any], length: int) -> np.ndarray:
        """Episode ``episode``'s ``length`` frames of video feature ``c``, uint8 ``[length, H, W, 3]``."""
        if self.template is None:
            raise DemoError(self.info_path, f"feature {c.feature!r} is a video but video_path is null")
        prefix = f"videos/{c.feature}/"
        chunk, file, start = (row.get(prefix + k) for k in ("chunk_index", "file_index", "from_timestamp"))
        if chunk is None or file is None or start is None:
            raise DemoError(self.where, f"episode {episode} has no {prefix}chunk_index, file_index and from_timestamp")
        if isinstance(start, bool) or not isinstance(start, (int, float)) or not 0 <= start <= MAX_EPISODE_FRAMES / self.fps:
            raise DemoError(self.where, f"episode {episode}: {prefix}from_timestamp {start!r} is not a time in the video")
        rel = self.template.format(video_key=c.feature, chunk_index=chunk, file_index=file, episode_chunk=chunk,
                                   episode_index=episode)
        path = contained(self.root, rel, self.info_path, "video_path")
        current = self.open.get(c.feature)
        if current is None or current[0] != path:
            if current is not None:
                current[1].close()
                del self.open[c.feature]
            if not path.is_file():
                raise DemoError(path, "is missing")
            decoder = VideoDecoder(path, c.shape)
            self.open[c.feature] = (path, decoder)
            self.files.setdefault(c.feature, set()).add(path)
            self.streams[c.feature] = decoder.info
        frames = self.open[c.feature][1].read(float(start), length, self.fps)
        self.decoded.setdefault(c.feature, PixelError()).fingerprint(frames)
        return frames

    def close(self) -> None:
        for _, decoder in self.open.values():
            decoder.close()
        self.open.clear()

    def report(self, c: Column, extras: dict[str, Any] | None) -> VideoReport:
        """What was decoded for ``c``, with the round-trip error demo measured at export when the
        frames decoded here are the very ones it measured (same fingerprint)."""
        decoded = self.decoded.get(c.feature, PixelError())
        stream = self.streams.get(c.feature)
        recorded = _recorded_error(((extras or {}).get("videos") or {}).get(c.feature))
        mean: float | None = None
        peak: int | None = None
        measured = "no source frames to compare with (not exported by demo)"
        if recorded is not None:
            mean, peak, frames, crc = recorded
            if (frames, crc) == (decoded.frames, decoded.crc32):
                measured = "decoded frames identical to those demo measured against the source store at export"
            else:
                measured = "measured at export; the frames decoded here differ from those (another FFmpeg build?)"
        return VideoReport(c.key, c.feature, stream.codec if stream else "?", stream.pix_fmt if stream else None,
                           decoded.frames, len(self.files.get(c.feature, ())), mean, peak, measured)


def _recorded_error(value: Any) -> tuple[float, int, int, int] | None:
    """(mean, max, frames, crc32) from info.json's record of an export's video, if well formed."""
    if not isinstance(value, dict):
        return None
    fields = (value.get("mean_abs_error"), value.get("max_abs_error"), value.get("frames"), value.get("decoded_crc32"))
    if not isinstance(fields[0], (int, float)) or not all(isinstance(f, int) for f in fields[1:]):
        return None
    return float(fields[0]), int(fields[1]), int(fields[2]), int(fields[3])


def _concat(where: Path, tables: list[pa.Table]) -> pa.Table:
    try:
        return pa.concat_tables(tables, promote_options="permissive")
    except pa.ArrowException as exc:
        raise DemoError(where, f"data files do not agree ({first_line(exc)})") from None


COLUMN_KINDS = ("state", "image", "video", "array")


def _own_plan(extras: dict[str, Any], info_path: Path) -> tuple[list[Column], StoreMeta]:
    """The key map and store metadata demo recorded under ``"demo"`` in info.json, checked like
    foreign metadata: valid keys, bounded shapes, numeric dtypes, slices inside the state."""
    try:
        columns = [Column.from_json(c) for c in extras["columns"]]
        meta = StoreMeta.from_json(extras["store_meta"])
    except (KeyError, TypeError, ValueError, AttributeError, OverflowError) as exc:
        raise DemoError(info_path, f"malformed '{EXTRA_KEY}' metadata ({first_line(exc)})") from None
    check_meta(meta, info_path)
    for c in columns:
        check_feature(c.key, c.shape, c.dtype, info_path)
        if c.kind not in COLUMN_KINDS or c.key not in meta.features or not 0 <= c.start <= c.stop <= MAX_EPISODE_FRAMES:
            raise DemoError(info_path, f"malformed '{EXTRA_KEY}' column {c.key!r}")
        if c.kind == "video" and unencodable(c.shape) is not None:
            raise DemoError(info_path, f"'{EXTRA_KEY}' column {c.key!r}: {unencodable(c.shape)}")
    if {c.key for c in columns} != set(meta.features):
        raise DemoError(info_path, f"'{EXTRA_KEY}' columns do not match its features")
    return columns, meta
