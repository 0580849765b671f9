"""LeRobot v3.0 export/import: the folder validates against the v3.0 layout, round trips are bit-exact
(camera videos: within a stated pixel error), foreign datasets import, bad input fails with one line
naming the file.

One file of ~580 lines on purpose: the tests of one format both ways share its fixtures (stores with and
without cameras, exported folders, a foreign dataset)."""

from __future__ import annotations

import io
import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from PIL import Image

from demo.cli.main import main
from demo.errors import DemoError
from demo.interop.lerobot import export_lerobot, import_lerobot
from demo.interop.sample import make_sample_store, sample_episode, sample_meta
from demo.interop.video import VideoDecoder, write_video
from demo.store import EpisodeStore, FeatureSpec

STATS = ("min", "max", "mean", "std", "count", "q01", "q10", "q50", "q90", "q99")
FRAME_FEATURES = {"timestamp": "float32", "frame_index": "int64", "episode_index": "int64", "index": "int64",
                  "task_index": "int64", "next.done": "bool"}
EPISODE_COLUMNS = ("episode_index", "tasks", "length", "data/chunk_index", "data/file_index", "dataset_from_index",
                   "dataset_to_index")


@pytest.fixture(scope="module")
def sample(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_sample_store(tmp_path_factory.mktemp("lr") / "s.zarr", episodes=7, seed=1)


def assert_same_store(a: EpisodeStore, b: EpisodeStore, episodes: list[int] | None = None) -> None:
    """Every frame of every key bit-exact (dtype too), the episode table equal, metadata equal."""
    chosen = episodes if episodes is not None else list(range(a.num_episodes))
    assert b.num_episodes == len(chosen)
    assert list(b.meta.features) == list(a.meta.features)
    for new, old in enumerate(chosen):
        x, y = a.read_episode(old), b.read_episode(new)
        for key in a.meta.features:
            assert y[key].dtype == x[key].dtype, key
            assert y[key].shape == x[key].shape, key
            np.testing.assert_array_equal(y[key], x[key], err_msg=key)
    if episodes is None:
        assert b.table.equals(a.table), (a.table.schema, b.table.schema)
    ma, mb = a.meta.to_json(), b.meta.to_json()
    pa_, pb = ma.pop("provenance"), mb.pop("provenance")
    assert ma == mb
    assert pb[: len(pa_)] == pa_
    assert [p["op"] for p in pb[len(pa_):]] == ["export", "import"]
    assert b.verify() == []


def validate_v30(root: Path) -> dict:
    """Check a folder against the LeRobotDataset v3.0 layout; return info.json."""
    info = json.loads((root / "meta/info.json").read_text())
    for key in ("codebase_version", "fps", "robot_type", "features", "total_episodes", "total_frames", "total_tasks",
                "chunks_size", "data_files_size_in_mb", "video_files_size_in_mb", "data_path", "video_path", "splits"):
        assert key in info, key
    assert info["codebase_version"] == "v3.0"
    assert info["data_path"] == "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
    n_ep, n_fr = info["total_episodes"], info["total_frames"]
    assert info["splits"] == {"train": f"0:{n_ep}"}
    features = info["features"]
    videos = [name for name, f in features.items() if f["dtype"] == "video"]
    assert info["video_path"] == ("videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4" if videos else None)
    for name, dtype in FRAME_FEATURES.items():
        assert features[name] == {"dtype": dtype, "shape": [1], "names": None}
    for name, f in features.items():
        assert set(f) == ({"dtype", "shape", "names", "info"} if name in videos else {"dtype", "shape", "names"}), name
        if f["names"] is not None:
            assert len(f["names"]) == (3 if f["dtype"] in ("image", "video") else f["shape"][0]), name
    in_parquet = {name for name in features if name not in videos}

    # data files: columns and arrow types exactly as declared
    data_files = sorted((root / "data").glob("chunk-*/file-*.parquet"))
    assert data_files
    tables = []
    for path in data_files:
        t = pq.read_table(path)
        assert set(t.column_names) == in_parquet, path  # videos live in their own files
        for name in in_parquet:
            f = features[name]
            typ = t.schema.field(name).type
            if f["dtype"] == "image":
                assert typ == pa.struct([("bytes", pa.binary()), ("path", pa.string())]), name
            elif f["shape"] == [1]:
                assert typ == pa.from_numpy_dtype(np.dtype(f["dtype"])), name
            else:
                assert typ == pa.list_(pa.from_numpy_dtype(np.dtype(f["dtype"])), f["shape"][0]), name
        tables.append(t)
    data = pa.concat_tables(tables)
    assert data.num_rows == n_fr
    np.testing.assert_array_equal(data.column("index").to_numpy(), np.arange(n_fr))

    # tasks
    tasks = pq.read_table(root / "meta/tasks.parquet")
    assert tasks.column_names == ["task_index", "task"]
    assert json.loads(tasks.schema.metadata[b"pandas"])["index_columns"] == ["task"]
    assert tasks.num_rows == info["total_tasks"]
    task_of = dict(zip(tasks.column("task_index").to_pylist(), tasks.column("task").to_pylist()))

    # episodes
    episodes = pq.read_table(root / "meta/episodes/chunk-000/file-000.parquet")
    for column in EPISODE_COLUMNS:
        assert column in episodes.column_names, column
    for name in features:
        for stat in STATS:
            assert f"stats/{name}/{stat}" in episodes.column_names, (name, stat)
    assert episodes.num_rows == n_ep
    np.testing.assert_array_equal(episodes.column("episode_index").to_numpy(), np.arange(n_ep))
    lengths = episodes.column("length").to_numpy()
    assert lengths.sum() == n_fr
    ends = np.cumsum(lengths)
    np.testing.assert_array_equal(episodes.column("dataset_to_index").to_numpy(), ends)
    np.testing.assert_array_equal(episodes.column("dataset_from_index").to_numpy(), ends - lengths)
    fps = float(info["fps"])
    for i in range(n_ep):
        chunk = episodes.column("data/chunk_index")[i].as_py()
        file = episodes.column("data/file_index")[i].as_py()
        t = pq.read_table(root / info["data_path"].format(chunk_index=chunk, file_index=file))
        rows = t.filter(pa.compute.equal(t.column("episode_index"), i))
        assert rows.num_rows == lengths[i]
        frame = rows.column("frame_index").to_numpy()
        np.testing.assert_array_equal(frame, np.arange(lengths[i]))
        np.testing.assert_array_equal(rows.column("timestamp").to_numpy(), (frame / fps).astype(np.float32))
        np.testing.assert_array_equal(rows.column("next.done").to_numpy(zero_copy_only=False), frame == lengths[i] - 1)
        np.testing.assert_array_equal(rows.column("index").to_numpy(), np.arange(ends[i] - lengths[i], ends[i]))
        task_index = set(rows.column("task_index").to_pylist())
        assert len(task_index) == 1
        assert episodes.column("tasks")[i].as_py() == [task_of[task_index.pop()]]
        assert episodes.column("stats/action/count")[i].as_py() == [lengths[i]]
    validate_videos(root, info, episodes)

    # stats.json: every feature, every stat, the dataset's count, ordered quantiles, exact moments
    stats = json.loads((root / "meta/stats.json").read_text())
    assert set(stats) == set(features)
    for name, f in features.items():
        s = {k: np.asarray(v, dtype=np.float64) for k, v in stats[name].items()}
        assert set(s) == set(STATS), name
        assert s["count"].tolist() == [n_fr]
        shape = (f["shape"][2], 1, 1) if f["dtype"] in ("image", "video") else (f["shape"][0],)
        for stat in STATS[:4] + STATS[5:]:
            assert s[stat].shape == shape, (name, stat)
        chain = [s["min"], s["q01"], s["q10"], s["q50"], s["q90"], s["q99"], s["max"]]
        for lo, hi in zip(chain, chain[1:]):
            assert np.all(lo <= hi + 1e-12), name
        if f["dtype"] not in ("image", "video"):
            col = data.column(name).combine_chunks()
            values = (col.flatten() if pa.types.is_fixed_size_list(col.type) else col).to_numpy(zero_copy_only=False)
            values = values.astype(np.float64).reshape(n_fr, -1)
            np.testing.assert_array_equal(s["min"], values.min(0))
            np.testing.assert_array_equal(s["max"], values.max(0))
            np.testing.assert_allclose(s["mean"], values.mean(0), rtol=1e-9, atol=1e-12)
            np.testing.assert_allclose(s["std"], values.std(0), rtol=1e-7, atol=1e-12)
    return info


def validate_videos(root: Path, info: dict, episodes: pa.Table) -> None:
    """Every video feature: its episodes follow each other in their files with exact timestamps, the
    files exist where video_path says, and each file holds exactly its episodes' frames."""
    fps = float(info["fps"])
    for name, f in info["features"].items():
        if f["dtype"] != "video":
            continue
        v = f["info"]
        assert (v["video.height"], v["video.width"], v["video.channels"]) == tuple(f["shape"])
        assert v["video.codec"] == "av1" and v["video.pix_fmt"] == "yuv420p" and v["video.fps"] == info["fps"]
        assert v["has_audio"] is False and v["video.is_depth_map"] is False
        columns = {k: episodes.column(f"videos/{name}/{k}").to_pylist()
                   for k in ("chunk_index", "file_index", "from_timestamp", "to_timestamp")}
        assert episodes.schema.field(f"videos/{name}/from_timestamp").type == pa.float64()
        frames_in: dict[tuple[int, int], int] = {}
        for i, length in enumerate(episodes.column("length").to_pylist()):
            where = (columns["chunk_index"][i], columns["file_index"][i])
            start = frames_in.get(where, 0)
            assert columns["from_timestamp"][i] == start / fps  # episodes one after another in the file
            assert columns["to_timestamp"][i] == (start + length) / fps
            frames_in[where] = start + length
        for (chunk, file), count in frames_in.items():
            path = root / info["video_path"].format(video_key=name, chunk_index=chunk, file_index=file)
            with VideoDecoder(path, tuple(f["shape"])) as decoder:
                assert decoder.info.codec == "av1" and decoder.info.pix_fmt == "yuv420p"
                decoder.read(0.0, count, fps)  # every frame there, at exactly k / fps
                with pytest.raises(DemoError, match="ends after 0"):
                    decoder.read(count / fps, 1, fps)  # and no more


def test_export_validates_against_v30_layout(sample: Path, tmp_path: Path) -> None:
    report = export_lerobot(sample, tmp_path / "lr", images="embed")
    info = validate_v30(tmp_path / "lr")
    store = EpisodeStore.open(sample)
    assert info["total_episodes"] == store.num_episodes == report.episodes
    assert info["total_frames"] == store.num_frames == report.frames
    assert info["total_tasks"] == 2 and info["fps"] == 20 and info["robot_type"] == "panda_prim"
    features = info["features"]
    # float32 obs.* concatenated into observation.state, in feature order, split recorded in names
    assert features["observation.state"]["shape"] == [7 + 3 + 1 + 6]
    assert features["observation.state"]["names"][:8] == [f"joint_pos.j{i}" for i in range(7)] + ["ee_pos.0"]
    # other obs keep their dtype under their store name (LeRobot policies read every observation* key)
    assert features["obs.goal64"]["dtype"] == "float64" and features["obs.contacts"]["dtype"] == "int16"
    assert features["obs.grasped"] == {"dtype": "bool", "shape": [1], "names": None}
    assert [k for k in features if k.startswith("observation")] == ["observation.state", "observation.images.front"]
    assert features["observation.images.front"] == {"dtype": "image", "shape": [12, 10, 3],
                                                   "names": ["height", "width", "channels"]}
    assert features["sim.state"]["dtype"] == "float64" and features["info.ee_target"]["shape"] == [7]
    assert features["action"]["names"] == list(store.meta.action.names)
    # the data really is there: state slice, PNG image, sim.state of episode 2
    episodes = pq.read_table(tmp_path / "lr/meta/episodes/chunk-000/file-000.parquet")
    start = episodes.column("dataset_from_index")[2].as_py()
    data = pq.read_table(tmp_path / "lr/data/chunk-000/file-000.parquet")
    ep = store.read_episode(2)
    row = data.slice(start, 1)
    state = np.asarray(row.column("observation.state")[0].as_py(), dtype=np.float32)
    np.testing.assert_array_equal(state[7:10], ep["obs.ee_pos"][0])
    png = row.column("observation.images.front")[0].as_py()["bytes"]
    np.testing.assert_array_equal(np.asarray(Image.open(io.BytesIO(png))), ep["obs.image_front"][0])
    np.testing.assert_array_equal(np.asarray(row.column("sim.state")[0].as_py()), ep["sim.state"][0])
    # what LeRobot has no place for is kept under "demo", and per-episode columns as demo/<column>
    assert info["demo"]["store_meta"]["action"]["name"] == "ee7"
    assert "demo/mask.train" in episodes.column_names and "demo/score.jerk" in episodes.column_names
    assert any("ee7" in item for item in report.extras)
    assert report.dropped == []


def test_round_trip_is_bit_exact(sample: Path, tmp_path: Path) -> None:
    export_lerobot(sample, tmp_path / "lr", images="embed")
    report = import_lerobot(tmp_path / "lr", tmp_path / "back.zarr")
    assert report.dropped == []
    assert_same_store(EpisodeStore.open(sample), EpisodeStore.open(tmp_path / "back.zarr"))


def test_many_data_files_and_subset(sample: Path, tmp_path: Path) -> None:
    store = EpisodeStore.open(sample)
    export_lerobot(sample, tmp_path / "lr", episodes="train", images="embed", data_file_mb=0.001)
    info = validate_v30(tmp_path / "lr")
    chosen = [int(i) for i in store.select("train")]
    assert info["total_episodes"] == len(chosen) < store.num_episodes
    assert len(list((tmp_path / "lr/data").glob("chunk-*/file-*.parquet"))) == len(chosen)  # one per episode here
    assert info["demo"]["source_episodes"] == chosen
    import_lerobot(tmp_path / "lr", tmp_path / "back.zarr")
    back = EpisodeStore.open(tmp_path / "back.zarr")
    assert_same_store(store, back, chosen)
    assert back.mask("train").all() and back.column("seed").tolist() == store.column("seed")[chosen].tolist()


def test_cli_export_import(sample: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["export", str(sample), "--format", "lerobot", "--out", str(tmp_path / "lr")]) == 0
    out = capsys.readouterr().out
    assert "exported 7 episodes" in out and "meta/info.json" in out
    assert main(["import", str(tmp_path / "lr"), "--out", str(tmp_path / "b.zarr"), "--json", "-"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["format"] == "lerobot" and report["episodes"] == 7
    assert EpisodeStore.open(tmp_path / "b.zarr").num_frames == EpisodeStore.open(sample).num_frames


def write_foreign_dataset(root: Path, locate: bool = True) -> None:
    """A small v3.0 dataset as LeRobot writes it (no demo metadata, variable-size list columns)."""
    (root / "meta/episodes/chunk-000").mkdir(parents=True)
    (root / "data/chunk-000").mkdir(parents=True)
    rng = np.random.default_rng(0)
    lengths = [4, 6]
    n = sum(lengths)
    images = rng.integers(0, 256, size=(n, 4, 5, 3), dtype=np.uint8)

    def png(a: np.ndarray) -> bytes:
        buf = io.BytesIO()
        Image.fromarray(a).save(buf, format="PNG")
        return buf.getvalue()

    episode = np.repeat([0, 1], lengths)
    frame = np.concatenate([np.arange(k) for k in lengths])
    data = pa.table({
        "observation.state": pa.array(rng.normal(size=(n, 3)).astype(np.float32).tolist(), pa.list_(pa.float32())),
        "action": pa.array(rng.normal(size=(n, 2)).tolist(), pa.list_(pa.float64())),
        "observation.images.cam": pa.StructArray.from_arrays(
            [pa.array([png(im) for im in images], pa.binary()), pa.array([None] * n, pa.string())], names=["bytes", "path"]),
        "next.reward": pa.array(rng.random(n).astype(np.float32)),
        "language": pa.array(["pick it"] * n),
        "timestamp": pa.array((frame / 10).astype(np.float32)),
        "frame_index": pa.array(frame), "episode_index": pa.array(episode), "index": pa.array(np.arange(n)),
        "task_index": pa.array(episode), "next.done": pa.array(frame == np.repeat(lengths, lengths) - 1),
    })
    pq.write_table(data, root / "data/chunk-000/file-000.parquet")
    episodes = {"episode_index": [0, 1], "tasks": [["pick"], ["place"]], "length": lengths}
    if locate:
        episodes.update({"data/chunk_index": [0, 0], "data/file_index": [0, 0], "dataset_from_index": [0, 4],
                         "dataset_to_index": [4, 10]})
    pq.write_table(pa.table(episodes), root / "meta/episodes/chunk-000/file-000.parquet")
    pq.write_table(pa.table({"task_index": [0, 1], "__index_level_0__": ["pick", "place"]}), root / "meta/tasks.parquet")
    features = {
        "observation.state": {"dtype": "float32", "shape": [3], "names": ["x", "y", "z"]},
        "action": {"dtype": "float64", "shape": [2], "names": {"motors": ["m0", "m1"]}},
        "observation.images.cam": {"dtype": "image", "shape": [4, 5, 3], "names": ["height", "width", "channels"]},
        "next.reward": {"dtype": "float32", "shape": [1], "names": None},
        "language": {"dtype": "string", "shape": [1], "names": None},
        **{k: {"dtype": v, "shape": [1], "names": None} for k, v in FRAME_FEATURES.items()},
    }
    info = {"codebase_version": "v3.0", "robot_type": "so100", "fps": 10, "features": features, "total_episodes": 2,
            "total_frames": n, "total_tasks": 2, "chunks_size": 1000, "data_path": "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"}
    (root / "meta/info.json").write_text(json.dumps(info))
    np.save(root / "images.npy", images)


@pytest.mark.parametrize("locate", [True, False])
def test_import_foreign_dataset(tmp_path: Path, locate: bool) -> None:
    write_foreign_dataset(tmp_path / "ds", locate)
    report = import_lerobot(tmp_path / "ds", tmp_path / "s.zarr")
    store = EpisodeStore.open(tmp_path / "s.zarr")
    assert store.num_episodes == 2 and store.episode_lengths.tolist() == [4, 6] and store.meta.fps == 10.0
    assert set(store.meta.features) == {"action", "obs.state", "obs.image_cam", "info.reward"}
    assert store.meta.action.name == "unknown" and store.meta.action.names == ("m0", "m1")
    assert store.meta.robot == {"name": "so100"}
    assert store.column("task").tolist() == ["pick", "place"]
    images = np.load(tmp_path / "ds/images.npy")
    np.testing.assert_array_equal(store.read_episode(1)["obs.image_cam"], images[4:])
    table = pq.read_table(tmp_path / "ds/data/chunk-000/file-000.parquet")
    np.testing.assert_array_equal(store.read_episode(0)["obs.state"],
                                  np.asarray(table.column("observation.state").to_pylist()[:4], dtype=np.float32))
    assert any("language" in d for d in report.dropped) and any("float64" in d for d in report.dropped)


@pytest.mark.parametrize("case", ["not_dataset", "v21", "mismatched", "corrupted", "total_frames", "stray_rows",
                                  "declared_shape"])
def test_bad_input_one_line_error(case: str, sample: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    root = tmp_path / "lr"
    if case == "not_dataset":
        root.mkdir()
        (root / "readme.txt").write_text("hello")
        expected = (root, "not a LeRobot dataset")
    else:
        export_lerobot(sample, root, data_file_mb=0.001)
        info_path = root / "meta/info.json"
        if case == "v21":
            info = json.loads(info_path.read_text())
            info["codebase_version"] = "v2.1"
            info_path.write_text(json.dumps(info))
            (root / "meta/episodes.jsonl").write_text("{}\n")
            expected = (info_path, "unsupported LeRobot dataset version 'v2.1'")
        elif case == "mismatched":
            path = root / "meta/episodes/chunk-000/file-000.parquet"
            t = pq.read_table(path)
            lengths = t.column("length").to_numpy().copy()
            lengths[0] += 1
            lengths[1] -= 1  # totals still agree: only the data file can tell
            pq.write_table(t.set_column(t.column_names.index("length"), "length", pa.array(lengths)), path)
            expected = (root / "data/chunk-000/file-000.parquet", "mismatched lengths")
        elif case == "corrupted":
            path = root / "data/chunk-000/file-002.parquet"
            path.write_bytes(path.read_bytes()[: len(path.read_bytes()) // 2])  # a crash mid-write
            expected = (path, "corrupted parquet")
        elif case == "declared_shape":  # info.json says one value fewer a frame than the data holds
            info = json.loads(info_path.read_text())
            info["features"]["observation.state"]["shape"][0] -= 1
            info_path.write_text(json.dumps(info))
            expected = (info_path, "declares shape")
        elif case == "total_frames":
            info = json.loads(info_path.read_text())
            info["total_frames"] += 1
            info_path.write_text(json.dumps(info))
            expected = (info_path, "total_frames")
        else:  # frames of an episode that meta/episodes does not list
            path = root / "data/chunk-000/file-001.parquet"
            t = pq.read_table(path)
            stray = t.slice(0, 2)
            stray = stray.set_column(stray.column_names.index("episode_index"), "episode_index", pa.array([99, 99]))
            pq.write_table(pa.concat_tables([t, stray]), path)
            expected = (root / "data", "mismatched lengths")
    out = tmp_path / "out.zarr"
    with pytest.raises(DemoError) as err:
        import_lerobot(root, out)
    assert err.value.where == str(expected[0]) and expected[1] in err.value.problem
    assert not out.exists() and [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []
    capsys.readouterr()
    assert main(["import", str(root), "--format", "lerobot", "--out", str(out)]) == 1
    captured = capsys.readouterr()
    assert captured.err.strip().count("\n") == 0 and captured.err.startswith("error: ")
    assert "Traceback" not in captured.err


def test_existing_out_is_never_clobbered(sample: Path, tmp_path: Path) -> None:
    export_lerobot(sample, tmp_path / "lr")
    before = (tmp_path / "lr/meta/info.json").read_text()
    with pytest.raises(DemoError, match="already exists"):
        export_lerobot(sample, tmp_path / "lr", episodes="valid")
    assert (tmp_path / "lr/meta/info.json").read_text() == before
    report = export_lerobot(sample, tmp_path / "lr", episodes="valid", overwrite=True)
    assert json.loads((tmp_path / "lr/meta/info.json").read_text())["total_episodes"] == report.episodes < 7
    # --overwrite never deletes something that is not a LeRobot dataset
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine/notes.txt").write_text("keep me")
    with pytest.raises(DemoError, match="not a LeRobot dataset"):
        export_lerobot(sample, tmp_path / "mine", overwrite=True)
    assert (tmp_path / "mine/notes.txt").read_text() == "keep me"
    # import: an existing store is kept unless --overwrite
    shutil.copytree(sample, tmp_path / "copy.zarr")
    with pytest.raises(DemoError, match="already exists"):
        import_lerobot(tmp_path / "lr", tmp_path / "copy.zarr")
    assert EpisodeStore.open(tmp_path / "copy.zarr").num_episodes == 7
    import_lerobot(tmp_path / "lr", tmp_path / "copy.zarr", overwrite=True)
    assert EpisodeStore.open(tmp_path / "copy.zarr").num_episodes == report.episodes


# ---------------------------------------------------------------------------------------------- camera videos
# |decoded - source| (0-255) bounds for the clips below at CRF 30; measured: mean 3.6-3.8, max 57-138, most
# of it on the red square's edges, whose colour yuv420p keeps at half resolution.
MEAN_BOUND, MAX_BOUND = 5.0, 160


def camera_clip(length: int, phase: float, h: int = 48, w: int = 64) -> np.ndarray:
    """A camera-like uint8 clip [T, H, W, 3]: smooth shading and a sharp-edged square moving over it."""
    t = np.arange(length)[:, None, None]
    y, x = np.mgrid[0:h, 0:w]
    frames = np.empty((length, h, w, 3), np.uint8)
    frames[..., 0] = 120 + 80 * np.sin((x + 2 * t + phase) / 9)
    frames[..., 1] = 120 + 80 * np.cos((y - t + phase) / 7)
    frames[..., 2] = 100 + 50 * np.sin((x + y) / 11 + t / 5)
    for k in range(length):
        left = (5 + 2 * k + int(phase)) % (w - 12)
        frames[k, 12:24, left:left + 12] = (230, 40, 40)
    return frames


@pytest.fixture(scope="module")
def cameras(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Four episodes with two RGB cameras (videos) and a 1-channel one (too few channels: stays PNG)."""
    meta = sample_meta(image=(48, 64))
    meta.features["obs.image_wrist"] = FeatureSpec((32, 40, 3), "uint8", "wrist camera", "rgb")
    meta.features["obs.image_depth"] = FeatureSpec((16, 20, 1), "uint8", "depth as grey levels")
    rng = np.random.default_rng(3)
    path = tmp_path_factory.mktemp("cams") / "c.zarr"
    with EpisodeStore.create(path, meta) as store:
        for i, length in enumerate((25, 8, 31, 12)):
            data = sample_episode(rng, meta, length)
            data["obs.image_front"] = camera_clip(length, 3.0 * i)
            data["obs.image_wrist"] = camera_clip(length, 7.0 * i + 1, 32, 40)
            store.append_episode(data, success=True, seed=i, source="scripted", operator="expert", task="pick")
    return path


def image_error(a: EpisodeStore, b: EpisodeStore, key: str) -> tuple[float, int]:
    """Mean and max |b - a| over every frame of ``key``, 0-255."""
    diffs = [np.abs(b.read_episode(i)[key].astype(np.int16) - a.read_episode(i)[key]) for i in range(a.num_episodes)]
    return float(np.concatenate([d.ravel() for d in diffs]).mean()), int(max(d.max() for d in diffs))


def test_export_videos_in_v30_layout(cameras: Path, tmp_path: Path) -> None:
    report = export_lerobot(cameras, tmp_path / "lr")
    info = validate_v30(tmp_path / "lr")
    features = info["features"]
    assert features["observation.images.front"]["dtype"] == "video" and features["observation.images.front"]["shape"] == [48, 64, 3]
    assert features["observation.images.wrist"]["info"]["video.height"] == 32
    assert features["observation.images.depth"]["dtype"] == "image"  # one channel: embedded PNG, and said so
    assert any("obs.image_depth" in n and "not RGB" in n for n in report.notes)
    assert sorted(str(p.relative_to(tmp_path / "lr")) for p in (tmp_path / "lr/videos").rglob("*.mp4")) == [
        "videos/observation.images.front/chunk-000/file-000.mp4", "videos/observation.images.wrist/chunk-000/file-000.mp4"]
    assert {f for f in report.files if f.startswith("videos/")} == {
        "videos/observation.images.front/chunk-000/file-000.mp4", "videos/observation.images.wrist/chunk-000/file-000.mp4"}
    assert [v.key for v in report.videos] == ["obs.image_front", "obs.image_wrist"]
    for v in report.videos:
        assert (v.codec, v.pix_fmt, v.frames, v.files) == ("av1", "yuv420p", 76, 1)
        assert 0 < v.mean_abs_error < MEAN_BOUND and 0 < v.max_abs_error <= MAX_BOUND, v  # lossy, but close
    assert info["demo"]["videos"]["observation.images.front"]["crf"] == 30


def test_video_round_trip_within_the_measured_error(cameras: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["export", str(cameras), "--format", "lerobot", "--out", str(tmp_path / "lr"), "--json", "-"]) == 0
    exported = json.loads(capsys.readouterr().out)["videos"]
    assert main(["import", str(tmp_path / "lr"), "--out", str(tmp_path / "b.zarr"), "--json", "-"]) == 0
    captured = capsys.readouterr()
    imported = json.loads(captured.out)["videos"]
    assert "camera videos: round-trip pixel error" in captured.err and "mean abs" in captured.err
    a, b = EpisodeStore.open(cameras), EpisodeStore.open(tmp_path / "b.zarr")
    assert b.num_episodes == 4 and b.episode_lengths.tolist() == a.episode_lengths.tolist()
    for i in range(4):  # everything but the videos is bit-exact; the videos have the store's shapes and dtype
        x, y = a.read_episode(i), b.read_episode(i)
        for key in a.meta.features:
            assert y[key].dtype == x[key].dtype and y[key].shape == x[key].shape, key
            if key not in ("obs.image_front", "obs.image_wrist"):
                np.testing.assert_array_equal(y[key], x[key], err_msg=key)
    for e, m in zip(exported, imported):
        mean, peak = image_error(a, b, e["key"])
        # the error both reports state is the one between the source store and what the import wrote
        assert e["mean_abs_error"] == pytest.approx(mean, abs=1e-9) and e["max_abs_error"] == peak
        assert (m["mean_abs_error"], m["max_abs_error"]) == (e["mean_abs_error"], e["max_abs_error"])
        assert m["measured"].startswith("decoded frames identical") and m["frames"] == 76
        assert mean < MEAN_BOUND and peak <= MAX_BOUND


@pytest.mark.slow
def test_video_files_roll_over_and_subsets_import(cameras: Path, tmp_path: Path) -> None:
    report = export_lerobot(cameras, tmp_path / "lr", video_file_mb=1e-6, episodes=[0, 2, 3])
    info = validate_v30(tmp_path / "lr")
    assert info["video_files_size_in_mb"] == 1e-6
    # a file per episode at this limit; validate_v30 checked each file holds exactly its episodes' frames
    assert [v.files for v in report.videos] == [3, 3]
    assert (tmp_path / "lr/videos/observation.images.wrist/chunk-000/file-002.mp4").is_file()
    import_lerobot(tmp_path / "lr", tmp_path / "b.zarr")
    a, b = EpisodeStore.open(cameras), EpisodeStore.open(tmp_path / "b.zarr")
    for new, old in enumerate((0, 2, 3)):
        x, y = a.read_episode(old)["obs.image_front"], b.read_episode(new)["obs.image_front"]
        assert y.shape == x.shape and np.abs(y.astype(np.int16) - x).mean() < MEAN_BOUND


def test_foreign_video_dataset_imports_without_a_reference(cameras: Path, tmp_path: Path) -> None:
    export_lerobot(cameras, tmp_path / "lr")
    info_path = tmp_path / "lr/meta/info.json"
    info = json.loads(info_path.read_text())
    info.pop("demo")  # as LeRobot's own tools leave it
    info_path.write_text(json.dumps(info))
    report = import_lerobot(tmp_path / "lr", tmp_path / "b.zarr")
    store = EpisodeStore.open(tmp_path / "b.zarr")
    assert store.meta.features["obs.image_front"].shape == (48, 64, 3)
    assert store.read_episode(2)["obs.image_wrist"].shape == (31, 32, 40, 3)
    front = [v for v in report.videos if v.key == "obs.image_front"][0]
    assert front.frames == 76 and front.mean_abs_error is None and front.measured.startswith("no source frames")
    assert image_error(EpisodeStore.open(cameras), store, "obs.image_front")[0] < MEAN_BOUND


@pytest.mark.slow
@pytest.mark.parametrize("case", ["truncated", "garbage", "fewer_frames", "wrong_size", "missing", "timestamp"])
def test_bad_video_one_line_error(case: str, cameras: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    root = tmp_path / "lr"
    export_lerobot(cameras, root)
    video = root / "videos/observation.images.front/chunk-000/file-000.mp4"
    where, problem = video, {
        "truncated": "not a readable video", "garbage": "not a readable video", "fewer_frames": "fewer frames than",
        "wrong_size": "frames are 32x48 pixels, the feature declares 64x48", "missing": "is missing",
        "timestamp": "has no frame at 0.0250 s"}[case]
    if case == "truncated":  # a crash mid-write: the index at the end of the file is lost
        video.write_bytes(video.read_bytes()[: video.stat().st_size * 2 // 3])
    elif case == "garbage":
        video.write_bytes(b"\x00\x00\x00\x18ftypmp42" + bytes(range(256)) * 8)
    elif case == "fewer_frames":
        write_video(video, camera_clip(70, 0.0), fps=20)  # 76 frames expected
    elif case == "wrong_size":
        write_video(video, camera_clip(76, 0.0, 48, 32), fps=20)
    elif case == "missing":
        video.unlink()
    else:  # an episode said to start between two frames
        path = root / "meta/episodes/chunk-000/file-000.parquet"
        t = pq.read_table(path)
        name = "videos/observation.images.front/from_timestamp"
        starts = t.column(name).to_pylist()
        starts[0] = 0.025
        pq.write_table(t.set_column(t.column_names.index(name), name, pa.array(starts, pa.float64())), path)
    out = tmp_path / "out.zarr"
    with pytest.raises(DemoError) as err:
        import_lerobot(root, out)
    assert err.value.where == str(where) and problem in err.value.problem, err.value
    assert not out.exists() and [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []
    capsys.readouterr()
    assert main(["import", str(root), "--out", str(out)]) == 1
    captured = capsys.readouterr()
    assert captured.err.strip().count("\n") == 0 and captured.err.startswith(f"error: {video}: ")
    assert "Traceback" not in captured.err and not out.exists()


# A Python with lerobot installed, for the cross-check below. Never this project's environment: lerobot
# pins torch < 2.11 (a multi-GB CUDA build); e.g. python3 -m venv /tmp/lrvenv && /tmp/lrvenv/bin/pip
# install lerobot==0.4.4, then DEMO_LEROBOT_PYTHON=/tmp/lrvenv/bin/python.
LEROBOT_PYTHON = os.environ.get("DEMO_LEROBOT_PYTHON")
LEROBOT_READ = """
import sys, numpy as np
from lerobot.datasets.lerobot_dataset import LeRobotDataset
ds = LeRobotDataset(repo_id="local/x", root=sys.argv[1], video_backend="pyav")
items = [ds[i] for i in range(len(ds))]
np.savez(sys.argv[2], **{k: np.stack([np.round(it[k].permute(1, 2, 0).numpy() * 255) for it in items]).astype(np.uint8)
                         for k in ds.meta.video_keys})
"""


@pytest.mark.skipif(not LEROBOT_PYTHON, reason="LeRobot is not installed: set DEMO_LEROBOT_PYTHON to a Python that "
                    "has lerobot to read the export with LeRobotDataset")
def test_lerobot_reads_the_video_export(cameras: Path, tmp_path: Path) -> None:
    export_lerobot(cameras, tmp_path / "lr", video_file_mb=1e-6)  # several files per camera
    import_lerobot(tmp_path / "lr", tmp_path / "b.zarr")
    subprocess.run([LEROBOT_PYTHON, "-c", LEROBOT_READ, str(tmp_path / "lr"), str(tmp_path / "frames.npz")], check=True,
                   env={**os.environ, "HF_HUB_OFFLINE": "1"}, timeout=600)
    read = np.load(tmp_path / "frames.npz")
    source, imported = EpisodeStore.open(cameras), EpisodeStore.open(tmp_path / "b.zarr")
    for key in ("obs.image_front", "obs.image_wrist"):
        got = read[f"observation.images.{key[len('obs.image_'):]}"]
        # LeRobot's own decoder (pyav backend) returns exactly the frames demo imports
        np.testing.assert_array_equal(got, np.concatenate([imported.read_episode(i)[key] for i in range(4)]))
        assert np.abs(got.astype(np.int16) - np.concatenate([source.read_episode(i)[key] for i in range(4)])).mean() < MEAN_BOUND


def test_an_export_stripped_of_its_demo_metadata_still_trains_and_converts(tmp_path: Path) -> None:
    """LeRobot's edit tools (delete_episodes, split_dataset, merge_datasets) drop info.json's "demo" block and
    the episodes' demo/* columns. What they keep carries what matters: the action's and observation.state's
    element names, next.success and the task string."""
    store, root = tmp_path / "reach.zarr", tmp_path / "lr"
    assert main(["collect", "--task", "reach", "--episodes", "6", "--seed", "0", "--out", str(store)]) == 0
    export_lerobot(store, root)
    info_path = root / "meta/info.json"
    info = json.loads(info_path.read_text())
    assert info["features"]["next.success"]["dtype"] == "bool" and "next.reward" in info["features"]
    del info["demo"]  # what the edit tools leave
    info_path.write_text(json.dumps(info))
    for path in (root / "meta/episodes").rglob("*.parquet"):
        table = pq.read_table(path)
        pq.write_table(table.drop([c for c in table.column_names if c.startswith("demo/")]), path)
    imported = tmp_path / "back.zarr"
    import_lerobot(root, imported)
    with EpisodeStore.open(store) as source, EpisodeStore.open(imported) as back:
        assert back.meta.action.name == "joint_pos" and back.meta.action == source.meta.action
        low_dim = [k for k in source.meta.features if k.startswith("obs.") and source.meta.features[k].dtype == "float32"]
        assert [k for k in back.meta.features if k.startswith("obs.")] == low_dim  # the split, not one obs.state
        np.testing.assert_array_equal(back.read_episode(2)["obs.joint_pos"], source.read_episode(2)["obs.joint_pos"])
        assert back.column("success").tolist() == source.column("success").tolist()
        assert back.column("task").tolist() == source.column("task").tolist()
        assert back.meta.robot == {"name": "panda_prim", "config": "builtin"}
    assert main(["convert", str(imported), "--to", "ee7", "--out", str(tmp_path / "ee7.zarr")]) == 0
    assert main(["train", str(imported), "--steps", "20", "--out", str(tmp_path / "run")]) == 0
