"""robomimic HDF5 export/import: robomimic's layout, bit-exact round trips, masks <-> filter keys,
foreign files, bad input."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest

from demo.cli.main import main
from demo.errors import DemoError
from demo.interop.robomimic import export_robomimic, import_robomimic
from demo.interop.sample import make_sample_store
from demo.store import EpisodeStore


@pytest.fixture(scope="module")
def sample(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_sample_store(tmp_path_factory.mktemp("rm") / "s.zarr", episodes=7, seed=2)


def test_export_layout(sample: Path, tmp_path: Path) -> None:
    report = export_robomimic(sample, tmp_path / "d.hdf5")
    store = EpisodeStore.open(sample)
    with h5py.File(tmp_path / "d.hdf5", "r") as f:
        data = f["data"]
        assert sorted(data.keys(), key=lambda k: int(k[5:])) == [f"demo_{i}" for i in range(7)]
        assert data.attrs["total"] == store.num_frames
        env_args = json.loads(data.attrs["env_args"])
        assert env_args["env_name"] == "pick" and env_args["env_kwargs"]["control_freq"] == 20.0
        for i in range(store.num_episodes):
            ep = store.read_episode(i)
            g = data[f"demo_{i}"]
            n = len(ep["action"])
            assert g.attrs["num_samples"] == n
            np.testing.assert_array_equal(g["actions"][()], ep["action"])
            assert g["actions"].dtype == np.float32
            np.testing.assert_array_equal(g["states"][()], ep["sim.state"])
            np.testing.assert_array_equal(g["obs/image_front"][()], ep["obs.image_front"])
            np.testing.assert_array_equal(g["obs/joint_pos"][()], ep["obs.joint_pos"])
            np.testing.assert_array_equal(g["next_obs/joint_pos"][()][:-1], ep["obs.joint_pos"][1:])
            np.testing.assert_array_equal(g["extra/info.ee_target"][()], ep["info.ee_target"])
            assert g["dones"][()].tolist() == [0] * (n - 1) + [1]
            assert g["rewards"][()][-1] == float(store.column("success")[i]) and g["rewards"][()][:-1].sum() == 0
            assert g.attrs["episode.seed"] == store.column("seed")[i]
            assert g.attrs["episode.operator"] == store.column("operator")[i]
        for name in ("train", "valid", "empty"):
            members = sorted(int(v.decode()[5:]) for v in f[f"mask/{name}"][()])
            assert members == np.flatnonzero(store.mask(name)).tolist()
    assert any("ee7" in e for e in report.extras) and report.dropped == []


def test_round_trip_is_bit_exact(sample: Path, tmp_path: Path) -> None:
    export_robomimic(sample, tmp_path / "d.hdf5")
    report = import_robomimic(tmp_path / "d.hdf5", tmp_path / "back.zarr")
    assert report.dropped == []
    a, b = EpisodeStore.open(sample), EpisodeStore.open(tmp_path / "back.zarr")
    assert b.num_episodes == a.num_episodes and list(b.meta.features) == list(a.meta.features)
    for i in range(a.num_episodes):
        x, y = a.read_episode(i), b.read_episode(i)
        for key in x:
            assert y[key].dtype == x[key].dtype and y[key].shape == x[key].shape, key
            np.testing.assert_array_equal(y[key], x[key], err_msg=key)
    assert b.table.equals(a.table), (a.table.schema, b.table.schema)
    ma, mb = a.meta.to_json(), b.meta.to_json()
    pa_, pb = ma.pop("provenance"), mb.pop("provenance")
    assert ma == mb and pb[: len(pa_)] == pa_ and [p["op"] for p in pb[len(pa_):]] == ["export", "import"]
    assert b.verify() == []


def test_subset_and_cli(sample: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "train.hdf5"
    assert main(["export", str(sample), "--format", "robomimic", "--out", str(out), "--mask", "train"]) == 0
    assert "exported" in capsys.readouterr().out
    assert main(["import", str(out), "--out", str(tmp_path / "b.zarr")]) == 0  # format detected
    a, b = EpisodeStore.open(sample), EpisodeStore.open(tmp_path / "b.zarr")
    chosen = a.select("train")
    assert b.num_episodes == len(chosen) and b.mask("train").all() and not b.mask("valid").any()
    for new, old in enumerate(chosen):
        np.testing.assert_array_equal(b.read_episode(new)["obs.rot"], a.read_episode(int(old))["obs.rot"])


def write_foreign_file(path: Path) -> dict[str, np.ndarray]:
    """A robomimic-style file: float64 actions, robosuite-like obs, rewards, dones, filter keys."""
    rng = np.random.default_rng(0)
    arrays = {}
    with h5py.File(path, "w") as f:
        data = f.create_group("data")
        data.attrs["env_args"] = json.dumps({"env_name": "Lift", "type": 1, "env_kwargs": {"control_freq": 20}})
        total = 0
        for i, n in enumerate([5, 8, 3]):
            g = data.create_group(f"demo_{i}")
            g.attrs["num_samples"] = n
            g.attrs["model_file"] = "<mujoco/>"
            arrays[f"actions{i}"] = rng.uniform(-1, 1, size=(n, 7))
            g.create_dataset("actions", data=arrays[f"actions{i}"])
            arrays[f"eef{i}"] = rng.normal(size=(n, 3))
            g.create_dataset("obs/robot0_eef_pos", data=arrays[f"eef{i}"])
            g.create_dataset("next_obs/robot0_eef_pos", data=rng.normal(size=(n, 3)))
            g.create_dataset("states", data=rng.normal(size=(n, 32)))
            rewards = np.zeros(n)
            rewards[-1] = 1.0 if i != 1 else 0.0
            g.create_dataset("rewards", data=rewards)
            g.create_dataset("dones", data=(np.arange(n) == n - 1).astype(np.int64))
            total += n
        data.attrs["total"] = total
        f.create_dataset("mask/train", data=np.array([b"demo_0", b"demo_2"]))
        f.create_dataset("mask/valid", data=np.array([b"demo_1"]))
    return arrays


def test_import_foreign_file(tmp_path: Path) -> None:
    arrays = write_foreign_file(tmp_path / "lift.hdf5")
    report = import_robomimic(tmp_path / "lift.hdf5", tmp_path / "s.zarr")
    store = EpisodeStore.open(tmp_path / "s.zarr")
    assert store.episode_lengths.tolist() == [5, 8, 3] and store.meta.fps == 20.0
    assert set(store.meta.features) == {"action", "obs.robot0_eef_pos", "sim.robomimic_state", "info.reward", "info.done"}
    np.testing.assert_array_equal(store.read_episode(1)["obs.robot0_eef_pos"], arrays["eef1"])  # float64 kept
    np.testing.assert_array_equal(store.read_episode(1)["action"], arrays["actions1"].astype(np.float32))
    assert store.column("success").tolist() == [True, False, True]
    assert store.mask("train").tolist() == [True, False, True] and store.mask("valid").tolist() == [False, True, False]
    assert store.meta.task["name"] == "Lift"
    assert any("float64" in d for d in report.dropped) and any("model_file" in d for d in report.dropped)


@pytest.mark.parametrize("case", ["missing", "directory", "not_hdf5", "no_data", "mismatched"])
def test_bad_input_one_line_error(case: str, sample: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "in.hdf5"
    if case == "directory":
        path.mkdir()
        expected = (path, "is a directory")
    elif case == "not_hdf5":
        path.write_text("not hdf5")
        expected = (path, "not a readable HDF5 file")
    elif case == "no_data":
        with h5py.File(path, "w") as f:
            f.create_group("something")
        expected = (path, "no 'data' group")
    elif case == "mismatched":
        export_robomimic(sample, path)
        with h5py.File(path, "a") as f:
            obs = f["data/demo_3/obs/ee_pos"]
            values = obs[()]
            del f["data/demo_3/obs/ee_pos"]
            f["data/demo_3/obs/ee_pos"] = values[:-1]
        expected = (f"{path}: /data/demo_3/obs/ee_pos", "mismatched lengths")
    else:
        expected = (path, "no such file")
    out = tmp_path / "out.zarr"
    with pytest.raises(DemoError) as err:
        import_robomimic(path, out)
    assert err.value.where == str(expected[0]) and expected[1] in err.value.problem
    assert not out.exists()
    capsys.readouterr()
    assert main(["import", str(path), "--format", "robomimic", "--out", str(out)]) == 1
    captured = capsys.readouterr()
    assert captured.err.startswith("error: ") and captured.err.strip().count("\n") == 0


def test_existing_out_is_never_clobbered(sample: Path, tmp_path: Path) -> None:
    out = tmp_path / "d.hdf5"
    export_robomimic(sample, out)
    size = out.stat().st_size
    with pytest.raises(DemoError, match="already exists"):
        export_robomimic(sample, out, episodes="valid")
    assert out.stat().st_size == size
    export_robomimic(sample, out, episodes="valid", overwrite=True)
    with h5py.File(out, "r") as f:
        assert len(f["data"]) == int(EpisodeStore.open(sample).mask("valid").sum())
    text = tmp_path / "notes.txt"
    text.write_text("keep me")
    with pytest.raises(DemoError, match="not a robomimic HDF5 file"):
        export_robomimic(sample, text, overwrite=True)
    assert text.read_text() == "keep me"


def test_export_of_many_episodes_reads_back(tmp_path: Path) -> None:
    """From about 200 episodes libhdf5 reads the staged file back while writing it: a write-only staging
    file failed the export then (UnsupportedOperation)."""
    store, out = tmp_path / "ref.zarr", tmp_path / "ref_rm.hdf5"
    assert main(["collect", "--task", "reach", "--episodes", "240", "--seed", "0", "--out", str(store)]) == 0
    assert main(["export", str(store), "--format", "robomimic", "--out", str(out)]) == 0
    source = EpisodeStore.open(store)
    with h5py.File(out, "r") as f:
        data = f["data"]
        assert len(data) == 240 and "mask" in f
        assert data.attrs["total"] == source.num_frames
        np.testing.assert_array_equal(data["demo_239/actions"][()], source.read_episode(239)["action"])
    try:
        import robomimic.utils.file_utils as file_utils
    except ImportError:  # robomimic is optional: h5py's reading above is the check then
        return
    assert file_utils.get_env_metadata_from_dataset(str(out))["env_name"] == "reach"
