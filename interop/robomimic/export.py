"""Store -> robomimic HDF5 file: :func:`export_robomimic` (the file layout:
:mod:`demo.interop.robomimic.layout`). Each store key becomes a dataset of ``data/demo_<i>``;
``rewards``, ``dones`` and ``next_obs`` are synthesised for robomimic; the store's metadata and the
per-episode columns' arrow types go to attributes, so that the import restores the store bit-exact.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from demo import __version__
from demo.errors import DemoError
from demo.interop.common import (
    InteropReport,
    carried_columns,
    check_not_same,
    now,
    short_name,
    staged_output,
    track,
    type_name,
)
from demo.interop.robomimic.layout import COLUMN_ATTR, META_ATTR, h5py_module
from demo.progress import Progress
from demo.store import EpisodeStore, FeatureSpec, StoreMeta
from demo.store.episode_store import EpisodeSelection
from demo.store.episode_table import MASK_PREFIX
from demo.store.location import store_path as locate_store
from demo.store.spec import is_image


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
        return path.is_file() and h5py_module().is_hdf5(str(path))
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
    h5py = h5py_module()
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
        # read-write: once the file grows, libhdf5 reads back what it wrote (a write-only file fails then)
        with open(tmp, "w+b", buffering=0) as raw, _WriteErrorKept(raw) as sink, h5py.File(sink, "w") as f:
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
