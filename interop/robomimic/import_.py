"""robomimic HDF5 file -> store: :func:`import_robomimic`.

A file demo exported is read back by the key map and metadata in its ``demo_meta`` attribute
(bit-exact); any other robomimic file gets store keys from its first demo's datasets. The file is
untrusted (:mod:`demo.interop.untrusted`): before anything is read, every link is checked to stay
inside the file (:func:`_check_contained`), and every dataset's declared size against what it holds.
"""

from __future__ import annotations

import contextlib
import json
from collections.abc import Iterator
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
    type_from_name,
)
from demo.interop.robomimic.layout import COLUMN_ATTR, DEFAULT_FPS, DEMO_NAME, META_ATTR, h5py_module
from demo.interop.untrusted import (
    INFO_TYPES,
    MAX_FRAME_VALUES,
    NUMERIC_KINDS,
    check_count,
    check_feature,
    check_fps,
    check_info,
    check_meta,
    store_key,
)
from demo.progress import Progress
from demo.store import ActionSpec, EpisodeStore, FeatureSpec, StoreMeta
from demo.store.episode_table import MASK_PREFIX

# A dataset may declare more bytes than it stores (compressed chunks, unwritten fill values), but not
# more than this many times more: deflate cannot exceed ~1032:1, so beyond it the sizes are not data.
MAX_EXPANSION = 1100
SLACK_BYTES = 2**20  # small datasets (attributes' worth) are not held to the ratio
MAX_LINK_DEPTH = 16  # soft links through soft links


def _open(path: Path) -> Any:
    h5py = h5py_module()
    if not path.exists():
        raise DemoError(path, "no such file")
    if path.is_dir():
        raise DemoError(path, "is a directory, not a robomimic HDF5 file")
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise DemoError(path, f"is not a readable HDF5 file ({first_line(exc)})") from None
    try:
        _check_contained(path, f)
        if "data" not in f or not isinstance(f["data"], h5py.Group):
            raise DemoError(path, "is not a robomimic dataset (no 'data' group)")
    except BaseException:
        f.close()
        raise
    return f


@contextlib.contextmanager
def _reading(path: Path) -> Iterator[None]:
    """What h5py raises reading a damaged file (a bit flipped in its structures), as one line naming it."""
    try:
        yield
    except DemoError:
        raise
    except (OSError, RuntimeError, KeyError, ValueError, TypeError, UnicodeDecodeError) as exc:
        raise DemoError(path, f"corrupted HDF5 file ({first_line(exc)})") from None


def _check_contained(path: Path, f: Any) -> None:
    """Refuse a file that would make h5py read outside it or allocate what it does not hold.

    Every link is checked before any data is read: external links, soft links that do not resolve
    to an object of this file, datasets whose bytes live in other files (HDF5 external storage,
    virtual datasets), and datasets declaring more bytes than their stored bytes can expand to.
    """
    h5py = h5py_module()
    problem: list[DemoError] = []

    def visit(name: str, link: Any) -> bool | None:
        where = f"{path}: /{name}"
        try:
            if isinstance(link, h5py.ExternalLink):
                raise DemoError(where, f"is an HDF5 external link (to {link.filename!r}); refusing to read outside the file")
            if isinstance(link, h5py.SoftLink):
                _resolve_soft(f, name, link.path, where)
            else:
                obj = f[name]
                if isinstance(obj, h5py.Dataset):
                    _check_dataset(where, obj)
        except DemoError as exc:
            problem.append(exc)
            return True  # stops the visit (an exception cannot cross h5py's C callback)
        except Exception as exc:  # noqa: BLE001 - whatever h5py raises on a damaged object, named
            problem.append(DemoError(where, f"cannot be read ({first_line(exc)})"))
            return True
        return None

    try:
        f.visititems_links(visit)
    except (OSError, RuntimeError, ValueError, SystemError) as exc:
        cause = exc.__cause__ or exc.__context__ if isinstance(exc, SystemError) else exc  # h5py wraps it
        raise DemoError(path, f"corrupted HDF5 structure ({first_line(cause or exc)})") from None
    if problem:
        raise problem[0]


def _resolve_soft(f: Any, name: str, target: str, where: str, depth: int = 0) -> None:
    """A soft link must lead, by hard links and soft links within the file, to an object of it."""
    h5py = h5py_module()
    if depth > MAX_LINK_DEPTH:
        raise DemoError(where, "soft links nest too deeply (a loop?)")
    base = "/" if target.startswith("/") else "/" + name.rsplit("/", 1)[0] if "/" in name else "/"
    group = f[base]
    parts = [p for p in target.split("/") if p and p != "."]
    for i, part in enumerate(parts):
        if not isinstance(group, h5py.Group):
            raise DemoError(where, f"soft link to {target!r} that is not in this file")
        link = group.get(part, getlink=True)
        if link is None:
            raise DemoError(where, f"soft link to {target!r} that is not in this file")
        if isinstance(link, h5py.ExternalLink):
            raise DemoError(where, f"soft link through an HDF5 external link (to {link.filename!r}); refusing to read outside the file")
        if isinstance(link, h5py.SoftLink):
            _resolve_soft(f, group.name.strip("/") + "/" + part, link.path, where, depth + 1)
        if i < len(parts) - 1:
            group = group[part]


def _check_dataset(where: str, ds: Any) -> None:
    h5py = h5py_module()
    plist = ds.id.get_create_plist()
    if plist.get_external_count():
        target = plist.get_external(0)[0]
        target = target.decode(errors="replace") if isinstance(target, bytes) else str(target)
        raise DemoError(where, f"keeps its data in another file ({target!r}, HDF5 external storage); "
                               "refusing to read outside the file")
    if plist.get_layout() == h5py.h5d.VIRTUAL:
        raise DemoError(where, "is a virtual dataset (its data is mapped from other files); refusing to read it")
    declared = int(ds.size or 0) * int(ds.dtype.itemsize)
    stored = int(ds.id.get_storage_size())
    if declared > MAX_EXPANSION * stored + SLACK_BYTES:
        raise DemoError(where, f"declares {list(ds.shape)} {ds.dtype} ({declared:,} bytes) but the file holds "
                               f"{stored:,} bytes of it")


def _demo_names(path: Path, data: Any) -> list[str]:
    names = [k for k in data.keys() if DEMO_NAME.fullmatch(k)]
    if not names:
        raise DemoError(path, "has no data/demo_N groups")
    return sorted(names, key=lambda k: int(k[5:]))


def _dataset(path: Path, group: Any, rel: str) -> Any:
    """The numeric dataset ``group/rel`` (not yet read)."""
    h5py = h5py_module()
    where = f"{path}: {group.name}/{rel}"
    try:
        ds = group[rel]
    except KeyError:
        raise DemoError(where, "is missing") from None
    except (OSError, ValueError, TypeError) as exc:
        raise DemoError(where, f"cannot be read ({first_line(exc)})") from None
    if not isinstance(ds, h5py.Dataset):
        raise DemoError(where, "is not a dataset")
    if ds.dtype.kind not in NUMERIC_KINDS or ds.dtype.names or ds.dtype.subdtype:
        raise DemoError(where, f"holds {ds.dtype} values, not numbers")
    if ds.ndim == 0:
        raise DemoError(where, "is a scalar, not one value per frame")
    return ds


def _read(path: Path, ds: Any) -> np.ndarray:
    try:
        return np.asarray(ds[()])
    except (OSError, ValueError, TypeError, RuntimeError) as exc:
        raise DemoError(f"{path}: {ds.name}", f"cannot be read ({first_line(exc)})") from None


def _mask(path: Path, f: Any, name: str) -> set[str]:
    """The demo names of robomimic filter key ``mask/<name>`` (bytes or strings)."""
    h5py = h5py_module()
    ds = f["mask"][name]
    where = f"{path}: /mask/{name}"
    if not isinstance(ds, h5py.Dataset) or ds.dtype.kind not in "SOU" or ds.ndim > 1:
        raise DemoError(where, "is not a list of demo names")
    try:
        values = ds[()]
    except (OSError, ValueError, TypeError, RuntimeError) as exc:
        raise DemoError(where, f"cannot be read ({first_line(exc)})") from None
    names = np.asarray(values).reshape(-1)
    try:
        return {v.decode() if isinstance(v, bytes) else str(v) for v in names}
    except UnicodeDecodeError:
        raise DemoError(where, "holds names that are not UTF-8") from None


def _json_attr(path: Path, attrs: Any, name: str) -> Any:
    value = _attr(attrs[name])
    if not isinstance(value, str):
        raise DemoError(f"{path}: data", f"attribute {name} is not a JSON string")
    return json.loads(value)


def _foreign_meta(path: Path, f: Any, names: list[str], report: InteropReport) -> tuple[dict[str, str], StoreMeta]:
    """Key map and metadata for a robomimic file not written by demo, from its first demo."""
    h5py = h5py_module()
    data = f["data"]
    first = data[names[0]]
    if not isinstance(first, h5py.Group):
        raise DemoError(f"{path}: {first.name}", "is not a group")
    env_args: dict[str, Any] = {}
    if "env_args" in data.attrs:
        try:
            env_args = _json_attr(path, data.attrs, "env_args")
        except (DemoError, UnicodeDecodeError, ValueError, RecursionError):
            report.notes.append("data attrs env_args is not JSON; ignored")
        if not isinstance(env_args, dict):
            env_args = {}
            report.notes.append("data attrs env_args is not a JSON object; ignored")
    actions = _dataset(path, first, "actions")
    width = int(np.prod(actions.shape[1:], dtype=np.int64)) if actions.ndim > 1 else 1
    if width > MAX_FRAME_VALUES:
        raise DemoError(f"{path}: {actions.name}", f"has {width} values a frame")
    action = ActionSpec("unknown", tuple(f"a{i}" for i in range(width)), ("",) * width, frame="unknown",
                        description="imported from robomimic; representation not recorded", params={"source": "robomimic"})
    if actions.dtype != np.float32:
        report.dropped.append(f"actions: {actions.dtype} values stored as float32 (a store's actions are float32)")
    paths = {"action": "actions"}
    features: dict[str, FeatureSpec] = {}
    taken = {"action"}
    where = f"{path}: {first.name}"
    sources: list[tuple[str, str, str, str]] = []  # (prefix, name, rel, description)
    if "obs" in first:
        if not isinstance(first["obs"], h5py.Group):
            raise DemoError(f"{where}/obs", "is not a group")
        sources += [("obs", name, "obs/" + name, f"robomimic obs/{name}") for name in first["obs"]]
    sources += [(prefix, name, rel, text) for rel, prefix, name, text in (
        ("states", "sim", "robomimic_state", "robomimic 'states' (the simulator's flattened state)"),
        ("rewards", "info", "reward", "robomimic rewards"), ("dones", "info", "done", "robomimic dones")) if rel in first]
    for prefix, name, rel, text in sources:
        ds = _dataset(path, first, rel)
        key = store_key(prefix, name, taken, where)
        shape, dtype = check_feature(key, ds.shape[1:], ds.dtype, f"{path}: {ds.name}")
        paths[key] = rel
        features[key] = FeatureSpec(shape, dtype, text)
    known = {"actions", "obs", "next_obs", "states", "rewards", "dones"}
    for name in first.keys():
        if name not in known:
            report.dropped.append(f"data/demo_N/{name}: not a robomimic field demo reads")
    if "next_obs" in first:
        report.notes.append("next_obs not imported: it is obs shifted by one frame")
    if "model_file" in first.attrs:
        report.dropped.append("demo attr model_file (the robosuite model XML)")
    kwargs = env_args.get("env_kwargs") if isinstance(env_args.get("env_kwargs"), dict) else {}
    if kwargs.get("control_freq"):
        fps = check_fps(kwargs["control_freq"], f"{path}: data attrs env_args")
    else:
        fps = DEFAULT_FPS
        report.notes.append(f"no control_freq in env_args: fps set to {DEFAULT_FPS:g}")
    meta = StoreMeta(fps=fps, features=features, action=action, robot={"name": "unknown"},
                     task={"name": str(env_args.get("env_name") or "robomimic")[:200], "env_args": env_args})
    return paths, meta


def _own_meta(path: Path, data: Any) -> tuple[dict[str, str], StoreMeta, list[tuple[str, pa.DataType | None]]]:
    """Key map, metadata and per-episode column types a file written by demo records."""
    where = f"{path}: data"
    try:
        demo_meta = _json_attr(path, data.attrs, META_ATTR)
        meta = StoreMeta.from_json(demo_meta["store_meta"])
        paths = dict(demo_meta["keys"])
        column_types = [(str(n), type_from_name(str(t))) for n, t in demo_meta["episode_columns"]]
    except (KeyError, TypeError, ValueError, AttributeError, RecursionError, UnicodeDecodeError) as exc:
        raise DemoError(where, f"malformed {META_ATTR} attribute ({first_line(exc)})") from None
    if set(paths) != set(meta.features) or not all(isinstance(rel, str) and rel for rel in paths.values()):
        raise DemoError(where, f"{META_ATTR} key map does not match its features")
    check_meta(meta, where)
    return paths, meta, column_types


def import_robomimic(
    src_path: str | Path,
    out: str | Path,
    *,
    overwrite: bool = False,
    progress: Progress | None = None,
) -> InteropReport:
    """Read a robomimic HDF5 file into a new store at ``out``.

    The file is untrusted (:mod:`demo.interop.untrusted`): links and storage outside it are refused
    and every size is checked against what it holds before anything is read.
    ``progress``: a tick per episode read (stage ``import robomimic``)."""
    src_path, out = Path(src_path), Path(out)
    check_not_same(src_path, out)
    report = InteropReport("robomimic", "import", src_path, out)
    with _open(src_path) as f:
        with _reading(src_path):
            data = f["data"]
            names = _demo_names(src_path, data)
            ours = META_ATTR in data.attrs
            if ours:
                paths, meta, column_types = _own_meta(src_path, data)
            else:
                paths, meta = _foreign_meta(src_path, f, names, report)
                column_types = [(name, None) for name in sorted({a[len(COLUMN_ATTR):] for n in names
                                                                 for a in data[n].attrs if a.startswith(COLUMN_ATTR)})]
                report.notes.append("success: true when any reward > 0, or when the file has no rewards (demonstrations)")
            meta.provenance = [*meta.provenance, {"op": "import", "format": "robomimic", "from": str(src_path),
                                                  "time": now()}]
            mask_group = f["mask"] if "mask" in f and isinstance(f["mask"], h5py_module().Group) else None
            masks = {m: _mask(src_path, f, m) for m in (mask_group.keys() if mask_group is not None else ())}
            column_values = {name: [_attr(data[n].attrs.get(COLUMN_ATTR + name)) for n in names]
                             for name, _ in column_types}

        def episodes() -> Any:
            for name in track(names, len(names), "import robomimic", progress):
                with _reading(src_path):  # only the reading: errors of the store being written are its own
                    episode = _episode(src_path, data[name], paths, meta, ours)
                yield episode

        frames = 0
        with staged_output(out, overwrite=overwrite, looks_like=lambda p: (p / "zarr.json").is_file(),
                           kind="demo store", is_dir=True) as tmp:
            store = EpisodeStore.create(tmp, meta, overwrite=True)
            try:
                for batch in batches(episodes()):
                    store.append_episodes(batch)
                    frames += sum(len(d["action"]) for d, _ in batch)
                columns: list[tuple[str, pa.Array]] = []
                for name, dtype in column_types:
                    if name.startswith(MASK_PREFIX) and name[len(MASK_PREFIX):] in masks:
                        member = masks.pop(name[len(MASK_PREFIX):])
                        columns.append((name, pa.array([n in member for n in names], pa.bool_())))
                        continue
                    columns.append((name, _column(src_path, name, column_values[name], dtype)))
                for mask, member in masks.items():  # robomimic filter keys -> store masks
                    columns.append((MASK_PREFIX + mask, pa.array([n in member for n in names], pa.bool_())))
                restore_columns(store, columns)
            finally:
                store.close()
    report.episodes = len(names)
    report.frames = frames
    report.files = [str(out)]
    return report


def _column(path: Path, name: str, values: list[Any], dtype: pa.DataType | None) -> pa.Array:
    """Per-episode attribute ``episode.<name>`` of every demo as one column (arrow type kept)."""
    try:
        return pa.array(values, type=dtype) if dtype is not None else pa.array(values)
    except (pa.ArrowException, TypeError, ValueError, OverflowError) as exc:
        raise DemoError(f"{path}: data", f"demo attribute {COLUMN_ATTR}{name} has values of mixed or wrong "
                                         f"types ({first_line(exc)})") from None


def _attr(value: Any) -> Any:
    if isinstance(value, bytes):
        return value.decode(errors="replace")
    if isinstance(value, np.generic):
        return value.item()
    return value


def _episode(path: Path, group: Any, paths: dict[str, str], meta: StoreMeta, ours: bool) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """One demo's store arrays and its fixed per-episode info; every dataset's frame shape, dtype and
    length is checked against the metadata before it is read."""
    h5py = h5py_module()
    where = f"{path}: {group.name}"
    if not isinstance(group, h5py.Group):
        raise DemoError(where, "is not a group")
    datasets = {key: _dataset(path, group, rel) for key, rel in paths.items()}
    num_samples = group.attrs.get("num_samples", len(datasets["action"]))
    expected = check_count(_attr(num_samples), where, "num_samples")
    for key, ds in datasets.items():
        spec = meta.features[key]
        frame_shape = tuple(ds.shape[1:])
        if key == "action" and not ours:
            frame_shape = (int(np.prod(frame_shape, dtype=np.int64)),)
        if frame_shape != tuple(spec.shape) or (ours and ds.dtype != spec.np_dtype):
            raise DemoError(f"{path}: {ds.name}", f"is {ds.dtype} {list(ds.shape[1:])} a frame, expected "
                                                  f"{spec.dtype} {list(spec.shape)}")
        if ds.shape[0] != expected:
            raise DemoError(f"{path}: {ds.name}", f"has {ds.shape[0]} frames but num_samples is {expected} "
                                                  "(mismatched lengths)")
    data: dict[str, np.ndarray] = {}
    for key, ds in datasets.items():
        values = _read(path, ds)
        data[key] = values.reshape(len(values), *meta.features[key].shape).astype(meta.features[key].np_dtype, copy=False)
    attrs = {k[len(COLUMN_ATTR):]: _attr(v) for k, v in group.attrs.items() if k.startswith(COLUMN_ATTR)}
    if ours:
        info = {k: attrs[k] for k in INFO_TYPES if k in attrs}
    else:
        success = bool((data["info.reward"] > 0).any()) if "info.reward" in data else True
        info = {"success": success, "seed": -1, "source": "imported", "operator": "", "task": meta.task["name"], **attrs}
    return data, append_info(check_info(info, f"{where} attributes {COLUMN_ATTR}*"))
