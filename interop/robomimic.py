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

import json
import re
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
from demo.progress import Progress
from demo.store import ActionSpec, EpisodeStore, FeatureSpec, StoreMeta
from demo.store.episode_store import EpisodeSelection
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
    store_path, out = Path(store_path), Path(out)
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
        with h5py.File(tmp, "w") as f:
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


def _write(group: Any, rel: str, values: np.ndarray, spec: FeatureSpec) -> None:
    if is_image(spec):
        group.create_dataset(rel, data=values, compression="gzip", compression_opts=4, chunks=(1, *values.shape[1:]))
    else:
        group.create_dataset(rel, data=values)


# ================================================================================================ import
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
    if "data" not in f or not isinstance(f["data"], h5py.Group):
        f.close()
        raise DemoError(path, "is not a robomimic dataset (no 'data' group)")
    return f


def _demo_names(path: Path, data: Any) -> list[str]:
    names = [k for k in data.keys() if DEMO_NAME.fullmatch(k)]
    if not names:
        raise DemoError(path, "has no data/demo_N groups")
    return sorted(names, key=lambda k: int(k[5:]))


def _read(path: Path, group: Any, rel: str) -> np.ndarray:
    try:
        return np.asarray(group[rel][()])
    except KeyError:
        raise DemoError(f"{path}: {group.name}/{rel}", "is missing") from None
    except (OSError, ValueError) as exc:
        raise DemoError(f"{path}: {group.name}/{rel}", f"cannot be read ({first_line(exc)})") from None


def _foreign_meta(path: Path, f: Any, names: list[str], report: InteropReport) -> tuple[dict[str, str], StoreMeta]:
    """Key map and metadata for a robomimic file not written by demo, from its first demo."""
    data = f["data"]
    first = data[names[0]]
    env_args: dict[str, Any] = {}
    if "env_args" in data.attrs:
        try:
            env_args = json.loads(data.attrs["env_args"])
        except (TypeError, ValueError):
            report.notes.append("data attrs env_args is not JSON; ignored")
    if "actions" not in first:
        raise DemoError(f"{path}: {first.name}", "has no 'actions'")
    actions = first["actions"]
    width = int(np.prod(actions.shape[1:], dtype=np.int64)) if actions.ndim > 1 else 1
    action = ActionSpec("unknown", tuple(f"a{i}" for i in range(width)), ("",) * width, frame="unknown",
                        description="imported from robomimic; representation not recorded", params={"source": "robomimic"})
    if actions.dtype != np.float32:
        report.dropped.append(f"actions: {actions.dtype} values stored as float32 (a store's actions are float32)")
    paths = {"action": "actions"}
    features: dict[str, FeatureSpec] = {}
    if "obs" in first:
        for name, ds in first["obs"].items():
            key = "obs." + name
            paths[key] = "obs/" + name
            features[key] = FeatureSpec(tuple(ds.shape[1:]), str(ds.dtype), f"robomimic obs/{name}")
    for rel, key, text in (("states", "sim.robomimic_state", "robomimic 'states' (the simulator's flattened state)"),
                           ("rewards", "info.reward", "robomimic rewards"), ("dones", "info.done", "robomimic dones")):
        if rel in first:
            ds = first[rel]
            paths[key] = rel
            features[key] = FeatureSpec(tuple(ds.shape[1:]), str(ds.dtype), text)
    known = {"actions", "obs", "next_obs", "states", "rewards", "dones"}
    for name in first.keys():
        if name not in known:
            report.dropped.append(f"data/demo_N/{name}: not a robomimic field demo reads")
    if "next_obs" in first:
        report.notes.append("next_obs not imported: it is obs shifted by one frame")
    if "model_file" in first.attrs:
        report.dropped.append("demo attr model_file (the robosuite model XML)")
    kwargs = env_args.get("env_kwargs") or {}
    fps = float(kwargs.get("control_freq") or DEFAULT_FPS)
    if not kwargs.get("control_freq"):
        report.notes.append(f"no control_freq in env_args: fps set to {DEFAULT_FPS:g}")
    meta = StoreMeta(fps=fps, features=features, action=action, robot={"name": "unknown"},
                     task={"name": str(env_args.get("env_name") or "robomimic"), "env_args": env_args})
    return paths, meta


def import_robomimic(
    src_path: str | Path,
    out: str | Path,
    *,
    overwrite: bool = False,
    progress: Progress | None = None,
) -> InteropReport:
    """Read a robomimic HDF5 file into a new store at ``out``.

    ``progress``: a tick per episode read (stage ``import robomimic``)."""
    src_path, out = Path(src_path), Path(out)
    check_not_same(src_path, out)
    report = InteropReport("robomimic", "import", src_path, out)
    with _open(src_path) as f:
        data = f["data"]
        names = _demo_names(src_path, data)
        ours = META_ATTR in data.attrs
        if ours:
            try:
                demo_meta = json.loads(data.attrs[META_ATTR])
                meta = StoreMeta.from_json(demo_meta["store_meta"])
                paths = dict(demo_meta["keys"])
                column_types = [(str(n), type_from_name(str(t))) for n, t in demo_meta["episode_columns"]]
            except (KeyError, TypeError, ValueError) as exc:
                raise DemoError(f"{src_path}: data", f"malformed {META_ATTR} attribute ({first_line(exc)})") from None
            if set(paths) != set(meta.features):
                raise DemoError(f"{src_path}: data", f"{META_ATTR} key map does not match its features")
        else:
            paths, meta = _foreign_meta(src_path, f, names, report)
            column_types = [(name, None) for name in sorted({a[len(COLUMN_ATTR):] for n in names
                                                             for a in data[n].attrs if a.startswith(COLUMN_ATTR)})]
            report.notes.append("success: true when any reward > 0, or when the file has no rewards (demonstrations)")
        meta.provenance = [*meta.provenance, {"op": "import", "format": "robomimic", "from": str(src_path), "time": now()}]
        mask_names = list(f["mask"].keys()) if "mask" in f else []
        masks = {m: {v.decode() if isinstance(v, bytes) else str(v) for v in _read(src_path, f["mask"], m).reshape(-1)}
                 for m in mask_names}

        def episodes() -> Any:
            for name in track(names, len(names), "import robomimic", progress):
                yield _episode(src_path, data[name], paths, meta, ours)

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
                    values = [_attr(data[n].attrs.get(COLUMN_ATTR + name)) for n in names]
                    columns.append((name, pa.array(values, type=dtype) if dtype is not None else pa.array(values)))
                for mask, member in masks.items():  # robomimic filter keys -> store masks
                    columns.append((MASK_PREFIX + mask, pa.array([n in member for n in names], pa.bool_())))
                restore_columns(store, columns)
            finally:
                store.close()
    report.episodes = len(names)
    report.frames = frames
    report.files = [str(out)]
    return report


def _attr(value: Any) -> Any:
    if isinstance(value, bytes):
        return value.decode()
    if isinstance(value, np.generic):
        return value.item()
    return value


def _episode(path: Path, group: Any, paths: dict[str, str], meta: StoreMeta, ours: bool) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """One demo's store arrays (all the same length, checked) and its fixed per-episode info."""
    data: dict[str, np.ndarray] = {}
    for key, rel in paths.items():
        values = _read(path, group, rel)
        spec = meta.features[key]
        if ours and (values.dtype != spec.np_dtype or values.shape[1:] != spec.shape):
            raise DemoError(f"{path}: {group.name}/{rel}", f"is {values.dtype} {list(values.shape[1:])}, "
                            f"expected {spec.dtype} {list(spec.shape)}")
        if key == "action":
            values = values.reshape(len(values), -1).astype(np.float32, copy=False)
        data[key] = values
    lengths = {rel: len(data[key]) for key, rel in paths.items()}
    expected = int(group.attrs["num_samples"]) if "num_samples" in group.attrs else lengths["actions"]
    for rel, n in lengths.items():
        if n != expected:
            raise DemoError(f"{path}: {group.name}/{rel}", f"has {n} frames but num_samples is {expected} (mismatched lengths)")
    attrs = {k[len(COLUMN_ATTR):]: _attr(v) for k, v in group.attrs.items() if k.startswith(COLUMN_ATTR)}
    if ours:
        info = {k: attrs[k] for k in ("success", "seed", "source", "operator", "task") if k in attrs}
    else:
        success = bool((data["info.reward"] > 0).any()) if "info.reward" in data else True
        info = {"success": success, "seed": -1, "source": "imported", "operator": "", "task": meta.task["name"], **attrs}
    return data, append_info(info)
