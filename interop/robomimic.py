"""robomimic HDF5 export and import (h5py).

File layout written by :func:`export_robomimic` (and read by :func:`import_robomimic`)::

    data                 attrs: total (frames), env_args (JSON), demo_meta (JSON, written by demo)
    data/demo_<i>        attrs: num_samples; episode.<column> for every per-episode column
      actions            [T, d] float32 (the store's action, in its representation)
      obs/<name>         obs.<name>, dtype kept (camera images uint8 [T, H, W, C], gzip)
      next_obs/<name>    obs shifted by one frame, the last frame repeated (robomimic's convention)
      states             sim.state [T, n] float64: MuJoCo mjSTATE_INTEGRATION (not robosuite's layout)
      rewards            [T] float64, sparse: 1.0 on the last frame of a successful episode
      dones              [T] int64: 1 on the last frame
      extra/<key>        every other store key (info.*, sim.* besides sim.state), ignored by robomimic
    mask/<name>          names (bytes) of the demos in store mask ``mask.<name>`` (robomimic filter keys)

``env_args`` is ``{"env_name": <task>, "type": "demo", "env_kwargs": {robot, task, control_freq}}``:
robomimic can train from the file, but cannot create the environment for rollouts (its env types
are robosuite/gym). ``demo_meta`` holds the store's metadata (fps, action representation name,
units and params, feature descriptions, robot, task, provenance), the key map and the arrow types of
the per-episode columns, which make store -> robomimic -> store bit-exact. Synthesised datasets
(``rewards``, ``dones``, ``next_obs``) are skipped when reading a file demo wrote.
"""

from __future__ import annotations

import contextlib
import json
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from demo import __version__
from demo.errors import DemoError
from demo.interop.common import (
    InteropReport,
    append_info,
    batches,
    carried_columns,
    check_not_same,
    first_line,
    is_image,
    now,
    restore_columns,
    short_name,
    staged_output,
    track,
    type_from_name,
    type_name,
)
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
from demo.store.episode_store import EpisodeSelection
from demo.store.location import store_path as locate_store
from demo.store.episode_table import MASK_PREFIX

META_ATTR = "demo_meta"
COLUMN_ATTR = "episode."
DEMO_NAME = re.compile(r"demo_(\d+)")
DEFAULT_FPS = 20.0  # robomimic's robosuite datasets are recorded at 20 Hz control


def _h5py():
    import h5py

    return h5py


def _key_paths(meta: StoreMeta) -> dict[str, str]:
    """Store key -> dataset path inside ``data/demo_<i>``."""
    paths = {}
    for key in meta.features:
        if key == "action":
            paths[key] = "actions"
        elif key == "sim.state":
            paths[key] = "states"
        elif key.startswith("obs."):
            paths[key] = "obs/" + short_name(key)
        else:
            paths[key] = "extra/" + key
    return paths


def _is_hdf5(path: Path) -> bool:
    try:
        return path.is_file() and _h5py().is_hdf5(str(path))
    except OSError:
        return False


def export_robomimic(
    store_path: str | Path,
    out: str | Path,
    *,
    overwrite: bool = False,
    episodes: EpisodeSelection = None,
    next_obs: bool = True,
    progress: Progress | None = None,
) -> InteropReport:
    """Write the store's (selected) episodes to a robomimic HDF5 file at ``out``.

    ``progress``: a tick per episode written (stage ``export robomimic``)."""
    h5py = _h5py()
    store_path, out = locate_store(store_path), Path(out)
    check_not_same(store_path, out)
    src = EpisodeStore.open(store_path)
    meta = src.meta
    chosen = src.select(episodes)
    if len(chosen) == 0:
        raise DemoError(store_path, "has no episodes to export")
    paths = _key_paths(meta)
    carried = carried_columns(src)
    masks = [name[len(MASK_PREFIX):] for name, _ in carried if name.startswith(MASK_PREFIX)]
    bad = [m for m in masks if "/" in m or not m]
    if bad:
        raise DemoError(store_path, f"mask name(s) {bad} cannot be HDF5 names")
    attr_columns = [(n, t) for n, t in carried if not n.startswith(MASK_PREFIX)]
    table = src.table
    success = src.column("success")
    report = InteropReport("robomimic", "export", store_path, out, episodes=int(len(chosen)))
    synthesized = ["rewards", "dones"] + (["next_obs"] if next_obs else [])
    store_meta = meta.to_json()
    store_meta["provenance"] = [*meta.provenance, {
        "op": "export", "format": "robomimic", "from": str(store_path), "episodes": int(len(chosen)),
        "time": now(), "demo": __version__,
    }]
    demo_meta = {
        "format": meta.format,
        "schema_version": meta.schema_version,
        "store_meta": store_meta,
        "keys": paths,
        "episode_columns": [[n, type_name(t)] for n, t in carried],
        "synthesized": synthesized,
        "source_episodes": [int(i) for i in chosen] if len(chosen) != src.num_episodes else None,
    }
    env_args = {
        "env_name": (meta.task or {}).get("name", ""),
        "type": "demo",
        "env_kwargs": {"robot": meta.robot, "task": meta.task, "control_freq": meta.fps},
    }
    frames = 0
    with staged_output(out, overwrite=overwrite, looks_like=_is_hdf5, kind="robomimic HDF5 file", is_dir=False) as tmp:
        with open(tmp, "wb", buffering=0) as raw, _WriteErrorKept(raw) as sink, h5py.File(sink, "w") as f:
            data = f.create_group("data")
            for new_index, src_index in enumerate(track(chosen, len(chosen), "export robomimic", progress)):
                ep = src.read_episode(int(src_index))
                length = len(ep["action"])
                g = data.create_group(f"demo_{new_index}")
                g.attrs["num_samples"] = length
                for key, rel in paths.items():
                    _write(g, rel, ep[key], meta.features[key])
                    if next_obs and rel.startswith("obs/"):
                        shifted = np.concatenate([ep[key][1:], ep[key][-1:]])
                        _write(g, "next_" + rel, shifted, meta.features[key])
                rewards = np.zeros(length, dtype=np.float64)
                rewards[-1] = float(bool(success[src_index]))
                dones = np.zeros(length, dtype=np.int64)
                dones[-1] = 1
                g.create_dataset("rewards", data=rewards)
                g.create_dataset("dones", data=dones)
                for name, _ in attr_columns:
                    value = table.column(name)[int(src_index)].as_py()
                    if value is not None:
                        g.attrs[COLUMN_ATTR + name] = value
                frames += length
            data.attrs["total"] = frames
            data.attrs["env_args"] = json.dumps(env_args)
            data.attrs[META_ATTR] = json.dumps(demo_meta)
            mask_group = f.create_group("mask")
            for name in masks:
                member = np.asarray(src.mask(name))[chosen]
                names = [f"demo_{i}".encode() for i in np.flatnonzero(member)]
                mask_group.create_dataset(name, data=np.array(names, dtype="S") if names else np.zeros(0, dtype="S1"))
    report.frames = frames
    report.files = [str(out)]
    params = f", params {', '.join(meta.action.params)}" if meta.action.params else ""
    report.extras = [
        f"action representation '{meta.action.name}' (frame {meta.action.frame}, units){params}",
        f"fps {meta.fps:g}, feature units and descriptions, robot and task metadata, provenance (data attrs {META_ATTR})",
    ]
    if attr_columns:
        report.extras.append("per-episode columns " + ", ".join(n for n, _ in attr_columns) + f" (demo attrs {COLUMN_ATTR}*)")
    extra_keys = [k for k, rel in paths.items() if rel.startswith("extra/")]
    if extra_keys:
        report.extras.append("per-frame keys robomimic has no field for: " + ", ".join(extra_keys) + " (data/demo_N/extra/)")
    report.notes.append(
        "rewards (sparse, from success) and dones (last frame) are synthesised"
        + ("; next_obs repeats the last frame" if next_obs else "")
    )
    if "sim.state" in meta.features:
        report.notes.append("states hold MuJoCo's mjSTATE_INTEGRATION vector, not robosuite's: robomimic cannot replay them")
    return report


class _WriteErrorKept:
    """The (unbuffered) file h5py writes through: the first OSError of a write (disk full, file too
    large) is kept and raised when the block ends, and later writes are dropped, so that libhdf5
    closes the file normally. Left to fail itself, libhdf5 crashes the process (a segfault) when it
    cannot flush on close; the staged output is then removed as for any other error."""

    def __init__(self, raw: Any):
        self.raw = raw
        self.error: OSError | None = None

    def write(self, data: Any) -> int:
        if self.error is None:
            try:
                return self.raw.write(data)
            except OSError as exc:
                self.error = exc
        return len(memoryview(data))

    def truncate(self, size: int | None = None) -> int:
        if self.error is None:
            try:
                return self.raw.truncate(size)
            except OSError as exc:  # growing the file past a size limit fails here
                self.error = exc
        return size if size is not None else self.raw.tell()

    def flush(self) -> None:
        pass  # the file is unbuffered

    def __getattr__(self, name: str) -> Any:  # read, seek, tell: the real file's
        return getattr(self.raw, name)

    def __enter__(self) -> "_WriteErrorKept":
        return self

    def __exit__(self, *exc: object) -> None:
        if self.error is not None:
            raise self.error


def _write(group: Any, rel: str, values: np.ndarray, spec: FeatureSpec) -> None:
    if is_image(spec):
        group.create_dataset(rel, data=values, compression="gzip", compression_opts=4, chunks=(1, *values.shape[1:]))
    else:
        group.create_dataset(rel, data=values)


# ================================================================================================ import
# A dataset may declare more bytes than it stores (compressed chunks, unwritten fill values), but not
# more than this many times more: deflate cannot exceed ~1032:1, so beyond it the sizes are not data.
MAX_EXPANSION = 1100
SLACK_BYTES = 2**20  # small datasets (attributes' worth) are not held to the ratio
MAX_LINK_DEPTH = 16  # soft links through soft links


def _open(path: Path) -> Any:
    h5py = _h5py()
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
    h5py = _h5py()
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
    h5py = _h5py()
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
    h5py = _h5py()
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
    h5py = _h5py()
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
    h5py = _h5py()
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
    h5py = _h5py()
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
            mask_group = f["mask"] if "mask" in f and isinstance(f["mask"], _h5py().Group) else None
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
    h5py = _h5py()
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
