"""Imports treat datasets as untrusted: nothing outside the dataset is read, a path outside gives the
same error whether or not its target exists, and sizes from metadata are checked before allocating.

robomimic: HDF5 external storage, external links, soft links out of the file and virtual datasets
are refused with one line naming the file and the dataset. LeRobot: data_path with ``..``, absolute
or format-string tricks, and symlinks out of the folder are refused alike.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import h5py
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from demo.errors import DemoError
from demo.interop.lerobot import export_lerobot, import_lerobot
from demo.interop.robomimic import export_robomimic, import_robomimic
from demo.interop.sample import make_sample_store
from demo.store import EpisodeStore

SECRET = np.arange(64, dtype=np.float32)  # what an attacker would like the store to hold


@pytest.fixture(scope="module")
def sample(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_sample_store(tmp_path_factory.mktemp("untrusted") / "s.zarr", episodes=3, seed=4)


# ---------------------------------------------------------------------------------------------- robomimic
def foreign_h5(path: Path, actions: Callable[[h5py.Group], None]) -> Path:
    """A robomimic file whose data/demo_0/actions is made by ``actions(group)``."""
    with h5py.File(path, "w") as f:
        g = f.create_group("data/demo_0")
        g.create_dataset("obs/x", data=np.zeros((16, 2), np.float32))
        actions(g)
    return path


@pytest.mark.parametrize("kind", ["external_storage", "external_link", "soft_link_out", "virtual"])
def test_robomimic_reads_nothing_outside_the_file(kind: str, tmp_path: Path, one_line_error) -> None:
    secret = tmp_path / "secret.bin"
    secret.write_bytes(SECRET.tobytes())
    with h5py.File(tmp_path / "other.h5", "w") as other:
        other["x"] = SECRET.reshape(16, 4)

    def attack(g: h5py.Group) -> None:
        if kind == "external_storage":  # the case: it imported with exit 0, holding secret.bin's bytes
            g.create_dataset("actions", shape=(16, 4), dtype="float32", external=[(str(secret), 0, SECRET.nbytes)])
        elif kind == "external_link":
            g["actions"] = h5py.ExternalLink(str(tmp_path / "other.h5"), "/x")
        elif kind == "soft_link_out":
            g.file["hop"] = h5py.ExternalLink(str(tmp_path / "other.h5"), "/")
            g["actions"] = h5py.SoftLink("/hop/x")
        else:
            layout = h5py.VirtualLayout(shape=(16, 4), dtype="float32")
            layout[...] = h5py.VirtualSource(str(tmp_path / "other.h5"), "x", shape=(16, 4))
            g.create_virtual_dataset("actions", layout)

    path = foreign_h5(tmp_path / "in.hdf5", attack)
    out = tmp_path / "out.zarr"
    with pytest.raises(DemoError) as err:
        import_robomimic(path, out)
    assert err.value.where.startswith(f"{path}: /") and "refusing to read" in err.value.problem
    assert ("/data/demo_0/actions" in err.value.where) or kind == "soft_link_out"
    assert not out.exists()
    line = one_line_error(["import", str(path), "--out", str(out)], rc=1)
    assert line.startswith(f"error: {path}: /") and not out.exists()


def test_robomimic_soft_link_inside_the_file_is_read(tmp_path: Path) -> None:
    values = np.random.default_rng(0).normal(size=(16, 3)).astype(np.float32)

    def linked(g: h5py.Group) -> None:
        g.file["shared"] = values
        g["actions"] = h5py.SoftLink("/shared")

    import_robomimic(foreign_h5(tmp_path / "in.hdf5", linked), tmp_path / "s.zarr")
    np.testing.assert_array_equal(EpisodeStore.open(tmp_path / "s.zarr").read_episode(0)["action"], values)


def test_robomimic_sizes_are_bounded_before_reading(sample: Path, tmp_path: Path) -> None:
    # 2**40 frames declared in a file of a few kB: refused from the metadata, nothing allocated.
    path = foreign_h5(tmp_path / "huge.hdf5", lambda g: g.create_dataset(
        "actions", shape=(2**40, 8), dtype="float32", chunks=(1024, 8)))
    with pytest.raises(DemoError, match="declares .* but the file holds"):
        import_robomimic(path, tmp_path / "a.zarr")
    export_robomimic(sample, tmp_path / "d.hdf5")
    with h5py.File(tmp_path / "d.hdf5", "a") as f:
        f["data/demo_1"].attrs["num_samples"] = 2**40
    with pytest.raises(DemoError, match="num_samples 1099511627776 is not within"):
        import_robomimic(tmp_path / "d.hdf5", tmp_path / "b.zarr")


def test_robomimic_feature_names_become_store_keys(sample: Path, tmp_path: Path, one_line_error) -> None:
    # A foreign obs name a store key cannot hold is renamed; demo's own key map is checked, not trusted.
    path = foreign_h5(tmp_path / "in.hdf5", lambda g: g.create_dataset("actions", data=np.ones((16, 2), np.float32)))
    with h5py.File(path, "a") as f:
        f["data/demo_0/obs"].move("x", "..")
    import_robomimic(path, tmp_path / "s.zarr")
    assert set(EpisodeStore.open(tmp_path / "s.zarr").meta.features) == {"action", "obs.__"}
    export_robomimic(sample, tmp_path / "d.hdf5")
    with h5py.File(tmp_path / "d.hdf5", "a") as f:
        meta = json.loads(f["data"].attrs["demo_meta"])
        meta["store_meta"]["features"]["obs.a/../b"] = meta["store_meta"]["features"].pop("obs.ee_pos")
        meta["keys"]["obs.a/../b"] = meta["keys"].pop("obs.ee_pos")
        f["data"].attrs["demo_meta"] = json.dumps(meta)
    line = one_line_error(["import", str(tmp_path / "d.hdf5"), "--out", str(tmp_path / "b.zarr")], rc=1)
    assert line == (f"error: {tmp_path / 'd.hdf5'}: data: feature key 'obs.a/../b' is not a store key "
                    "(action, obs.NAME, sim.NAME or info.NAME)")


# ---------------------------------------------------------------------------------------------- LeRobot
@pytest.fixture
def dataset(sample: Path, tmp_path: Path) -> Path:
    export_lerobot(sample, tmp_path / "ds")
    outside = tmp_path / "elsewhere/chunk-000"
    outside.mkdir(parents=True)
    (outside / "file-000.parquet").write_bytes((tmp_path / "ds/data/chunk-000/file-000.parquet").read_bytes())
    return tmp_path / "ds"


def set_info(root: Path, **changes: object) -> Path:
    path = root / "meta/info.json"
    info = json.loads(path.read_text())
    info.update(changes)
    path.write_text(json.dumps(info))
    return path


@pytest.mark.parametrize("template", [
    "../elsewhere/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet",  # the case: it imported that file
    "{root}/elsewhere/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet",
])
def test_lerobot_data_path_outside_is_refused_alike(template: str, dataset: Path, one_line_error) -> None:
    template = template.replace("{root}", str(dataset.parent))
    info = set_info(dataset, data_path=template)
    exists = one_line_error(["import", str(dataset), "--out", str(dataset.parent / "a.zarr")], rc=1)
    set_info(dataset, data_path=template.replace("/elsewhere/", "/nowhere/"))
    missing = one_line_error(["import", str(dataset), "--out", str(dataset.parent / "b.zarr")], rc=1)
    assert exists.startswith(f"error: {info}: data_path ") and "leads outside the dataset folder" in exists
    assert exists.replace("/elsewhere/", "/nowhere/") == missing  # nothing tells whether the target exists
    assert not (dataset.parent / "a.zarr").exists()


@pytest.mark.parametrize("template", ["data/{chunk_index.__class__}/{file_index}.parquet",
                                      "data/chunk-{chunk_index:999999999d}/file-{file_index:03d}.parquet",
                                      "data/{secret}/{file_index}.parquet"])
def test_lerobot_path_templates_are_data_not_code(template: str, dataset: Path) -> None:
    set_info(dataset, data_path=template)
    with pytest.raises(DemoError, match=r"only \{chunk_index\}, \{file_index\}"):
        import_lerobot(dataset, dataset.parent / "a.zarr")


@pytest.mark.parametrize("link", ["meta/info.json", "meta", "data/chunk-000/file-000.parquet", "meta/tasks.parquet",
                                  "meta/episodes/chunk-000/file-000.parquet"])
def test_lerobot_symlinks_out_are_refused_alike(link: str, dataset: Path, one_line_error) -> None:
    path = dataset / link
    shutil.rmtree(path) if path.is_dir() else path.unlink()
    errors = []
    for target in ("elsewhere", "nowhere"):
        if path.is_symlink():
            path.unlink()
        path.symlink_to(dataset.parent / target / ("chunk-000/file-000.parquet" if link.endswith(".parquet") else ""))
        errors.append(one_line_error(["import", str(dataset), "--out", str(dataset.parent / "a.zarr")], rc=1))
    assert errors[0] == errors[1] and "leads outside the dataset folder" in errors[0]
    assert not (dataset.parent / "a.zarr").exists()


def test_lerobot_video_path_leading_out_is_refused(dataset: Path) -> None:
    set_info(dataset, video_path="../../videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4")
    with pytest.raises(DemoError, match="video_path .* leads outside the dataset folder"):
        import_lerobot(dataset, dataset.parent / "a.zarr")


@pytest.mark.parametrize("column,value", [("dataset_to_index", 2**40), ("length", 2**62), ("data/file_index", -1)])
def test_lerobot_sizes_are_bounded_before_allocating(column: str, value: int, dataset: Path) -> None:
    path = dataset / "meta/episodes/chunk-000/file-000.parquet"
    table = pq.read_table(path)
    values = table.column(column).to_pylist()
    values[0] = value
    pq.write_table(table.set_column(table.column_names.index(column), column, pa.array(values, pa.int64())), path)
    with pytest.raises(DemoError):  # before: np.arange(0, 2**40) (8 TiB), or an int64 overflow of the lengths' sum
        import_lerobot(dataset, dataset.parent / "a.zarr")


@pytest.mark.parametrize("changes", [{"fps": float("nan")}, {"total_frames": 2**70}, {"total_episodes": -1}])
def test_lerobot_info_numbers_are_checked(changes: dict, dataset: Path, one_line_error) -> None:
    info = set_info(dataset, **changes)
    assert one_line_error(["import", str(dataset), "--out", str(dataset.parent / "a.zarr")], rc=1).startswith(f"error: {info}: ")


def test_lerobot_feature_names_become_store_keys(dataset: Path, tmp_path: Path) -> None:
    # A foreign feature name zarr would refuse as an array path ('.'/'..' segments): renamed, not a ValueError.
    info = json.loads((dataset / "meta/info.json").read_text())
    features = {"action": info["features"]["action"], "observation.a/../b": {"dtype": "float32", "shape": [3], "names": None},
                **{k: info["features"][k] for k in ("timestamp", "frame_index", "episode_index", "index", "task_index")}}
    table = pq.read_table(dataset / "data/chunk-000/file-000.parquet")
    data = pa.table({"action": table.column("action"), "observation.a/../b": table.column("obs.goal64").cast(
        pa.list_(pa.float32(), 3)), **{k: table.column(k) for k in features if k in table.column_names and k != "action"}})
    pq.write_table(data, dataset / "data/chunk-000/file-000.parquet")
    info.pop("demo")  # a foreign dataset
    info["features"] = features
    (dataset / "meta/info.json").write_text(json.dumps(info))
    import_lerobot(dataset, tmp_path / "s.zarr")
    assert "obs.a____b" in EpisodeStore.open(tmp_path / "s.zarr").meta.features
