"""robomimic HDF5 export/import: robomimic's layout, bit-exact round trips, masks <-> filter keys,
foreign files, bad input."""

from __future__ import annotations

import json
import os
import subprocess
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


def test_instructions_travel_as_a_demo_attribute(tmp_path: Path) -> None:
    """An episode's instruction is its demo group's ``episode.instruction`` attribute, and imports back."""
    assert main(["collect", "--task", "reach", "--episodes", "2", "--workers", "0", "--instruction", "touch the goal",
                 "--out", str(tmp_path / "told.zarr")]) == 0
    export_robomimic(tmp_path / "told.zarr", tmp_path / "told.hdf5")
    with h5py.File(tmp_path / "told.hdf5") as f:
        assert [f[f"data/demo_{i}"].attrs["episode.instruction"] for i in range(2)] == ["touch the goal"] * 2
    import_robomimic(tmp_path / "told.hdf5", tmp_path / "back.zarr")
    with EpisodeStore.open(tmp_path / "back.zarr") as store:
        assert list(store.column("instruction")) == ["touch the goal"] * 2


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


# From about 200 episodes libhdf5 reads the staged file back while writing it: a write-only staging file failed
# the export then (UnsupportedOperation); 240 reach episodes was the smallest store seen to fail.
MANY = 240


@pytest.fixture(scope="module")
def many(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """MANY reach episodes with a mask (every 10th episode), exported by `demo export`: (store, file)."""
    root = tmp_path_factory.mktemp("many")
    store, out = root / "reach.zarr", root / "reach.hdf5"
    assert main(["collect", "--task", "reach", "--episodes", str(MANY), "--seed", "0", "--out", str(store)]) == 0
    with EpisodeStore.open(store, "a") as s:
        s.set_mask("valid", np.arange(MANY) % 10 == 0)
    assert main(["export", str(store), "--format", "robomimic", "--out", str(out)]) == 0
    return store, out


def test_export_of_many_episodes_reads_back(many: tuple[Path, Path]) -> None:
    """What robomimic's readers take from the file (data/demo_N, total, env_args, num_samples, the filter
    keys), checked with h5py alone."""
    store, out = many
    source = EpisodeStore.open(store)
    lengths = source.episode_lengths
    with h5py.File(out, "r") as f:
        data = f["data"]
        assert sorted(data, key=lambda k: int(k[5:])) == [f"demo_{i}" for i in range(MANY)]
        assert data.attrs["total"] == source.num_frames == lengths.sum()
        env_args = json.loads(data.attrs["env_args"])
        assert env_args["env_name"] == "reach" and env_args["env_kwargs"]["control_freq"] == 20.0
        assert [int(data[f"demo_{i}"].attrs["num_samples"]) for i in range(MANY)] == lengths.tolist()
        for i in range(MANY):
            g = data[f"demo_{i}"]
            assert {len(g[k]) for k in ("actions", "rewards", "dones", "states")} == {lengths[i]}
            for prefix in ("obs", "next_obs"):
                assert {len(g[prefix][k]) for k in g[prefix]} == {lengths[i]}
        for i in (0, 199, 200, MANY - 1):
            ep = source.read_episode(i)
            np.testing.assert_array_equal(data[f"demo_{i}/actions"][()], ep["action"])
            np.testing.assert_array_equal(data[f"demo_{i}/obs/joint_pos"][()], ep["obs.joint_pos"])
        assert list(f["mask"]) == ["valid"]
        assert f["mask/valid"][()].tolist() == [f"demo_{i}".encode() for i in range(0, MANY, 10)]


# A Python with robomimic installed, for the cross-check below. Never this project's environment (robomimic
# needs torch). robomimic 0.3.0's dataset reader needs only torch, h5py, tqdm and termcolor of its
# dependencies (PyPI's torchvision does not import beside the CPU torch): python3 -m venv /tmp/rmvenv &&
# /tmp/rmvenv/bin/pip install --no-deps robomimic==0.3.0 && /tmp/rmvenv/bin/pip install torch==2.13.0 h5py
# tqdm termcolor, then DEMO_ROBOMIMIC_PYTHON=/tmp/rmvenv/bin/python (docs/interop.md).
ROBOMIMIC_PYTHON = os.environ.get("DEMO_ROBOMIMIC_PYTHON")
ROBOMIMIC_READ = """
import sys, time, h5py, numpy as np, torch
import robomimic.utils.obs_utils as ObsUtils
from robomimic.utils.dataset import SequenceDataset
path, out = sys.argv[1], sys.argv[2]
with h5py.File(path, "r") as f:
    low_dim = sorted(k for k in f["data/demo_0/obs"] if f["data/demo_0/obs"][k].ndim == 2)
    masks = list(f["mask"])
ObsUtils.initialize_obs_utils_with_obs_specs({"obs": {"low_dim": low_dim}})
def dataset(filter_key):
    return SequenceDataset(hdf5_path=path, obs_keys=low_dim, dataset_keys=("actions", "rewards", "dones"),
                           seq_length=10, frame_stack=1, pad_seq_length=True, hdf5_cache_mode="low_dim",
                           filter_by_attribute=filter_key)
start = time.perf_counter()
ds = dataset(None)
load = time.perf_counter() - start
items = [ds[i] for i in range(len(ds))]
arrays = {"length": len(ds), "demos": ds.n_demos, "load_s": load}
for key in ("actions", "rewards", "dones"):
    arrays[key] = np.stack([it[key] for it in items])
for prefix in ("obs", "next_obs"):
    for key in low_dim:
        arrays[prefix + "/" + key] = np.stack([it[prefix][key] for it in items])
batch = next(iter(torch.utils.data.DataLoader(ds, batch_size=64, shuffle=True)))  # as robomimic's training loop
arrays["batch"] = np.array([*batch["actions"].shape, *batch["obs"]["joint_pos"].shape])
for name in masks:
    subset = dataset(name)
    arrays["mask/" + name] = np.array([subset.n_demos, len(subset)])
np.savez(out, **arrays)
print(f"SequenceDataset: {len(ds)} sequences of {ds.n_demos} demos, loaded in {load:.2f} s")
"""


def robomimic_sequences(store: EpisodeStore, seq_length: int) -> dict[str, np.ndarray]:
    """What robomimic's SequenceDataset(seq_length, frame_stack=1, pad_seq_length=True, hdf5_cache_mode="low_dim")
    returns for every index of an export of the whole store: one sequence per frame, the episode's last frame
    repeated past its end; next_obs is obs one frame later (the last frame repeated); actions, rewards and
    dones as float32."""
    lengths = store.episode_lengths
    episodes = [store.read_episode(i) for i in range(store.num_episodes)]
    last = np.cumsum(lengths) - 1
    ends = np.repeat(last, lengths)[:, None]
    index = np.minimum(np.arange(len(ends))[:, None] + np.arange(seq_length), ends)
    following = np.minimum(index + 1, ends)
    done = np.zeros(len(ends), np.int64)
    done[last] = 1
    rewards = done * np.repeat(np.asarray(store.column("success"), np.float64), lengths)
    sequences = {"actions": np.concatenate([ep["action"] for ep in episodes])[index], "rewards": rewards[index],
                 "dones": done[index]}
    sequences = {k: v.astype(np.float32) for k, v in sequences.items()}  # hdf5_cache_mode="low_dim" casts these
    for key, spec in store.meta.features.items():
        if key.startswith("obs.") and len(spec.shape) == 1:
            frames = np.concatenate([ep[key] for ep in episodes])
            sequences["obs/" + key[4:]], sequences["next_obs/" + key[4:]] = frames[index], frames[following]
    return sequences


@pytest.mark.skipif(not ROBOMIMIC_PYTHON, reason="robomimic is not installed: set DEMO_ROBOMIMIC_PYTHON to a Python "
                    "that has robomimic 0.3.0 to read the export with its SequenceDataset (docs/interop.md)")
def test_robomimic_sequence_dataset_reads_the_export(many: tuple[Path, Path], tmp_path: Path) -> None:
    store, out = many
    subprocess.run([ROBOMIMIC_PYTHON, "-c", ROBOMIMIC_READ, str(out), str(tmp_path / "items.npz")], check=True,
                   timeout=600)
    read = np.load(tmp_path / "items.npz")
    source = EpisodeStore.open(store)
    assert int(read["length"]) == source.num_frames and int(read["demos"]) == MANY
    assert read["batch"].tolist() == [64, 10, source.meta.features["action"].shape[0], 64, 10, 7]
    valid = source.episode_lengths[::10]
    assert read["mask/valid"].tolist() == [len(valid), int(valid.sum())]
    expected = robomimic_sequences(source, seq_length=10)
    obs_keys = sorted(k for k in read.files if k.startswith(("obs/", "next_obs/")))
    assert obs_keys == sorted(k for k in expected if "/" in k)
    for key, values in expected.items():
        assert read[key].dtype == values.dtype and read[key].shape == values.shape, key
        np.testing.assert_array_equal(read[key], values, err_msg=key)
