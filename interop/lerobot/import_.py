"""LeRobotDataset v3.0 folder -> store: :func:`import_lerobot`.

A folder demo exported is read back by the key map and store metadata it recorded under info.json's
``demo`` key (:func:`_own_plan`: bit-exact); any other LeRobot v3.0 dataset gets store keys made from
its feature names (:func:`_foreign_plan`). The folder is untrusted (:mod:`demo.interop.untrusted`,
:mod:`demo.interop.lerobot.files`): every size, index and path is checked before it is used.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from demo.errors import DemoError, first_line
from demo.interop.common import (
    InteropReport,
    append_info,
    batches,
    check_not_same,
    now,
    restore_columns,
    staged_output,
    track,
)
from demo.interop.lerobot.files import (
    column_to_numpy,
    concat_data,
    decode_images,
    episodes_table,
    read_info,
    read_parquet,
    read_tasks,
)
from demo.interop.lerobot.layout import (DATA_PATH, DONE, EPISODE_COLUMN_PREFIX, EXTRA_KEY, FRAME_COLUMNS, INFO_PATH, REWARD,
                                         STATE, SUCCESS, Column)
from demo.interop.lerobot.videos import VideoReader
from demo.interop.untrusted import MAX_EPISODE_FRAMES, check_feature, check_info, check_meta, contained, inside, store_key
from demo.interop.video import unencodable
from demo.progress import Progress
from demo.sim.env import joint_pos_action
from demo.sim.robot import load_robot
from demo.sim.robot_record import BUILTIN
from demo.store import ActionSpec, EpisodeStore, FeatureSpec, StoreMeta
from demo.store.instructions import INSTRUCTION_COLUMN, MAX_CHARACTERS, normalized

# The Column.kind values a recorded key map may hold (see demo.interop.lerobot.layout.Column).
COLUMN_KINDS = ("state", "image", "video", "array")


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
    episodes = episodes_table(root, info)
    tasks = read_tasks(root)
    extras = info.get(EXTRA_KEY) if isinstance(info.get(EXTRA_KEY), dict) else None
    if extras is not None:
        columns, meta = _own_plan(extras, info_path)
        used = {c.feature for c in columns} | set(FRAME_COLUMNS) | {DONE, SUCCESS, REWARD}
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
    _check_declared_shapes(columns, info["features"], info_path)
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
                    cache = (path, read_parquet(root, path))
                else:
                    files = sorted(path.glob("chunk-*/file-*.parquet"))
                    if not files:
                        raise DemoError(path, "has no chunk-*/file-*.parquet data files")
                    cache = (path, concat_data(path, [read_parquet(root, f) for f in files]))
                rows_in_files[path] = cache[1].num_rows
            table = cache[1]
            yield i, row, path, table

    def episodes_data() -> Any:
        for i, row, path, table in track(frames(), episodes.num_rows, "import lerobot", progress):
            data, info_row = _episode_from_table(i, row, path, table, columns, tasks, extras is not None, videos)
            yield data, info_row

    frames_total = 0
    videos = VideoReader(root, info, root / "meta" / "episodes")
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
    videos: "VideoReader",
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
            data[c.key] = decode_images(ep.column(c.feature), c.shape, where)
            if data[c.key].shape[1:] != c.shape:
                raise DemoError(where, f"images are {list(data[c.key].shape[1:])}, the feature declares {list(c.shape)}")
            continue
        if c.kind == "state":
            if state is None:
                state = column_to_numpy(ep.column(c.feature), where).reshape(length, -1)
                declared = max(k.stop for k in columns if k.kind == "state")
                if state.shape[1] != declared:  # a slice would silently drop (or misplace) values
                    raise DemoError(where, f"episode {i} has {state.shape[1]} values a frame, info.json declares "
                                           f"{declared}")
            values = state[:, c.start:c.stop]
        else:
            values = column_to_numpy(ep.column(c.feature), where)
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
            success = bool(np.asarray(column_to_numpy(ep.column("next.success"), str(path))).reshape(length, -1)[-1].any())
        episode_info = {"success": success, "seed": -1, "source": "imported", "operator": "", "task": task}
        told = normalized(task)[:MAX_CHARACTERS]  # LeRobot's task is the episode's language: its instruction
        return data, {**append_info(check_info(episode_info, f"{path}: episode {i}")),
                      **({INSTRUCTION_COLUMN: told} if told else {})}
    return data, append_info(check_info(episode_info, f"{path}: episode {i}"))


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
            action_spec = recognised_action(labels) or ActionSpec(
                "unknown", labels, ("",) * width, frame="unknown",
                description="imported from LeRobot; representation not recorded", params={"source": "lerobot"})
            if dtype != "float32":
                report.dropped.append(f"action: {dtype} values stored as float32 (a store's actions are float32)")
            columns.append(Column("action", name, "array", (width,), "float32"))
            continue
        split = state_split(names) if name == STATE and dtype == "float32" else None
        if split:  # a demo export whose "demo" block was dropped: its obs.* keys, from the element names
            for short, start, stop, elements in split:
                key = store_key("obs", short, taken, info_path)
                columns.append(Column(key, STATE, "state", (stop - start,), "float32", start, stop))
                specs[key] = FeatureSpec((stop - start,), "float32", f"LeRobot {STATE}[{start}:{stop}]",
                                         names=elements if len(elements) == stop - start else None)
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
    robot_type = str(info.get("robot_type") or "unknown")[:200]
    # The built-in arm is known by its name; any other robot's files travel only in the "demo" block.
    robot = {"name": robot_type, "config": BUILTIN} if robot_type == load_robot(None).name else {"name": robot_type}
    meta = StoreMeta(fps=info["fps"], features=specs, action=action_spec, robot=robot)
    return columns, meta


def state_split(names: list[str] | None) -> list[tuple[str, int, int, tuple[str, ...]]] | None:
    """``observation.state`` as demo exports name its elements (``joint_pos.joint1``, ..., ``gripper``): the
    (key, start, stop, element names) of each ``obs.<key>`` it concatenates; None for names of another form
    (no ``key.element`` name, or a key in two places)."""
    if not names or not any("." in n for n in names):
        return None
    groups: list[tuple[str, int, int, tuple[str, ...]]] = []
    for i, n in enumerate(names):
        short, _, element = n.partition(".")
        if groups and groups[-1][0] == short and element:
            key, start, _, elements = groups[-1]
            groups[-1] = (key, start, i + 1, (*elements, element))
        else:
            groups.append((short, i, i + 1, (element,) if element else ()))
    keys = [g[0] for g in groups]
    return groups if len(set(keys)) == len(keys) and all(keys) else None


def recognised_action(names: tuple[str, ...]) -> ActionSpec | None:
    """The action representation a demo export's action names give away (its "demo" block dropped by another
    tool): ``<joint>.target``... + ``gripper`` is what the simulator takes, ``joint_pos``. (The end-effector
    forms are :mod:`demo.convert`'s, which this layer does not read: they import as ``unknown``.)"""
    if len(names) >= 2 and names[-1] == "gripper" and all(n.endswith(".target") for n in names[:-1]):
        return joint_pos_action([n.removesuffix(".target") for n in names[:-1]])
    return None


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


def _check_declared_shapes(columns: list[Column], features: dict[str, Any], info_path: Path) -> None:
    """Every feature's declared ``shape`` holds the values the key map reads from it (``observation.state``: every
    slice; an array: its frame), so that a dataset whose info.json was edited apart from its data is refused."""
    state = [c for c in columns if c.kind == "state"]
    for c in columns:
        if c.kind in ("image", "video") or (c.kind == "state" and c is not state[0]):
            continue
        shape = features[c.feature].get("shape")
        declared = math.prod(shape) if isinstance(shape, list) and all(isinstance(n, int) for n in shape) else None
        wanted = max(k.stop for k in state) if c.kind == "state" else math.prod(c.shape)
        if declared != wanted:
            raise DemoError(info_path, f"feature {c.feature!r} declares shape {shape}, {declared} values a frame; the "
                                       f"data is read as {wanted}")


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
