"""Episode store: round trips, atomic appends under SIGKILL, masks, copies, bad input."""

from __future__ import annotations

import gc
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from demo.cli.main import main
from demo.errors import DemoError
from demo.store import ActionSpec, EpisodeStore, FeatureSpec, StoreMeta


def make_meta() -> StoreMeta:
    return StoreMeta(
        fps=20.0,
        features={
            "obs.joint_pos": FeatureSpec((7,), "float32", "arm joint angles", "rad"),
            "obs.image_front": FeatureSpec((6, 5, 3), "uint8", "camera", "rgb"),
            "obs.contacts": FeatureSpec((2,), "int16", "contact counts"),
            "sim.state": FeatureSpec((13,), "float64", "mujoco integration state"),
        },
        action=ActionSpec("joint_pos", tuple(f"a{i}" for i in range(8)), ("rad",) * 7 + ("1",)),
        robot={"name": "test"},
        task={"name": "reach"},
    )


def random_episode(seed: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    n = int(rng.integers(5, 40))
    return {
        "action": rng.normal(size=(n, 8)).astype(np.float32),
        "obs.joint_pos": rng.normal(size=(n, 7)).astype(np.float32),
        "obs.image_front": rng.integers(0, 256, size=(n, 6, 5, 3)).astype(np.uint8),
        "obs.contacts": rng.integers(-5, 5, size=(n, 2)).astype(np.int16),
        "sim.state": rng.normal(size=(n, 13)),
    }


def test_round_trip_is_bit_exact(tmp_path: Path) -> None:
    episodes = [random_episode(i) for i in range(12)]
    with EpisodeStore.create(tmp_path / "s.zarr", make_meta()) as store:
        for i, ep in enumerate(episodes):
            store.append_episode(ep, success=i % 3 != 0, seed=i, source="scripted", operator="expert")
    store = EpisodeStore.open(tmp_path / "s.zarr")
    assert store.num_episodes == 12
    assert store.num_frames == sum(len(e["action"]) for e in episodes)
    assert store.episode_ends[-1] == store.num_frames
    for i, ep in enumerate(episodes):
        back = store.read_episode(i)
        for key, value in ep.items():
            assert back[key].dtype == value.dtype
            np.testing.assert_array_equal(back[key], value)
    assert store.column("success").tolist() == [i % 3 != 0 for i in range(12)]
    assert store.verify() == []
    data, ends = store.load(["action"], episodes=[2, 5])
    np.testing.assert_array_equal(data["action"], np.concatenate([episodes[2]["action"], episodes[5]["action"]]))
    assert ends.tolist() == np.cumsum([len(episodes[2]["action"]), len(episodes[5]["action"])]).tolist()


def test_masks_columns_and_copy(tmp_path: Path) -> None:
    with EpisodeStore.create(tmp_path / "s.zarr", make_meta()) as store:
        for i in range(6):
            store.append_episode(random_episode(i), seed=i, source="scripted", dagger_round=i // 2)
        store.set_mask("train", [True, True, False, True, False, True])
        store.set_column("score.jerk", np.arange(6, dtype=float))
        with pytest.raises(DemoError, match="6 episodes"):
            store.set_mask("bad", [True])
        copy = store.copy_to(tmp_path / "c.zarr", "train", frame_ranges={3: (1, 4)}, provenance={"op": "test"})
        assert not (tmp_path / "c.zarr").exists()  # a copy appears whole, when it is closed
        copy.close()
    copy = EpisodeStore.open(tmp_path / "c.zarr")
    assert copy.num_episodes == 4
    assert copy.column("source_episode").tolist() == [0, 1, 3, 5]
    assert copy.column("score.jerk").tolist() == [0.0, 1.0, 3.0, 5.0]
    assert copy.column("dagger_round").tolist() == [0, 0, 1, 2]
    np.testing.assert_array_equal(copy.read_episode(2)["action"], random_episode(3)["action"][1:4])
    assert copy.meta.provenance[-1]["op"] == "test"
    assert EpisodeStore.open(tmp_path / "s.zarr").num_episodes == 6  # source untouched


def test_one_writer_at_a_time(tmp_path: Path) -> None:
    with EpisodeStore.create(tmp_path / "s.zarr", make_meta()) as store:
        with pytest.raises(DemoError, match="another process"):
            EpisodeStore.open(tmp_path / "s.zarr", "a")
        store.append_episode(random_episode(0))
        assert EpisodeStore.open(tmp_path / "s.zarr", "r").num_episodes == 1  # readers are never blocked


def test_create_refuses_to_clobber(tmp_path: Path) -> None:
    EpisodeStore.create(tmp_path / "s.zarr", make_meta()).close()
    with pytest.raises(DemoError, match="already exists"):
        EpisodeStore.create(tmp_path / "s.zarr", make_meta())
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "a.txt").write_text("precious")
    with pytest.raises(DemoError, match="not a demo store"):
        EpisodeStore.create(tmp_path / "notes", make_meta(), overwrite=True)
    assert (tmp_path / "notes" / "a.txt").read_text() == "precious"


WRITER = textwrap.dedent(
    """
    import sys, time, numpy as np
    sys.path.insert(0, {tests!r})
    from test_episode_store import make_meta, random_episode
    from demo.store import EpisodeStore
    from demo.store import episode_table
    path, pause_at = sys.argv[1], int(sys.argv[2])
    store = EpisodeStore.create(path, make_meta())
    real_write = episode_table.write_atomic
    count = [0]
    def slow_commit(table, p):
        # Frames and episode_ends of this episode are on disk; the commit has not happened.
        if count[0] == pause_at:
            open(path + ".paused", "w").close()
            time.sleep(60)
        count[0] += 1
        real_write(table, p)
    episode_table.write_atomic = slow_commit  # every commit (demo.store.writing) calls it through the module
    count[0] = 1  # the empty table was already written by create()
    for i in range(1000):
        store.append_episode(random_episode(i), seed=i, source="scripted")
    """
)


def run_writer(tmp_path: Path, pause_at: int) -> subprocess.Popen:
    script = tmp_path / "writer.py"
    script.write_text(WRITER.format(tests=str(Path(__file__).parent)))
    return subprocess.Popen([sys.executable, str(script), str(tmp_path / "s.zarr"), str(pause_at)])


def test_sigkill_mid_episode_keeps_finished_episodes(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    proc = run_writer(tmp_path, pause_at=8)  # killed while appending episode index 7
    deadline = time.time() + 60
    while not (tmp_path / "s.zarr.paused").exists():
        assert proc.poll() is None and time.time() < deadline, "writer never reached the pause"
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()

    assert main(["info", str(tmp_path / "s.zarr"), "--check", "--json", "-"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["episodes"] == 7 and summary["check"]["ok"]
    store = EpisodeStore.open(tmp_path / "s.zarr", "a")
    for i in range(7):
        np.testing.assert_array_equal(store.read_episode(i)["sim.state"], random_episode(i)["sim.state"])
    # The next writer trims the uncommitted frames and carries on.
    store.append_episode(random_episode(100), seed=100)
    store.close()
    store = EpisodeStore.open(tmp_path / "s.zarr")
    assert store.num_episodes == 8 and store.verify() == []
    np.testing.assert_array_equal(store.read_episode(7)["action"], random_episode(100)["action"])


@pytest.mark.slow
def test_sigkill_at_random_times(tmp_path: Path) -> None:
    for delay in (0.9, 1.3, 1.7):
        target = tmp_path / f"run{delay}"
        target.mkdir()
        proc = run_writer(target, pause_at=10**9)
        time.sleep(delay)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        if not (target / "s.zarr" / "episodes.parquet").exists():
            continue  # killed before the store existed
        store = EpisodeStore.open(target / "s.zarr")
        assert store.verify() == []
        for i in range(store.num_episodes):
            np.testing.assert_array_equal(store.read_episode(i)["action"], random_episode(i)["action"])


def chunk_files(store: Path, key: str) -> list[Path]:
    return sorted(p for p in (store / "data" / key / "c").rglob("*") if p.is_file())


def filled_store(path: Path, n: int = 3) -> None:
    with EpisodeStore.create(path, make_meta()) as store:
        for i in range(n):
            store.append_episode(random_episode(i), seed=i)


def test_bad_input_not_a_store(tmp_path: Path, one_line_error) -> None:
    one_line_error(["info", str(tmp_path / "missing.zarr")], "no such store")
    (tmp_path / "dir").mkdir()
    one_line_error(["info", str(tmp_path / "dir")], "not a demo episode store")
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "zarr.json").write_text(json.dumps({"zarr_format": 3, "node_type": "group", "attributes": {}}))
    one_line_error(["info", str(tmp_path / "other")], "not a demo episode store")


def test_bad_input_wrong_schema_version(tmp_path: Path, one_line_error) -> None:
    filled_store(tmp_path / "s.zarr")
    meta_file = tmp_path / "s.zarr" / "zarr.json"
    doc = json.loads(meta_file.read_text())
    doc["attributes"]["demo"]["schema_version"] = 99
    meta_file.write_text(json.dumps(doc))
    one_line_error(["info", str(tmp_path / "s.zarr")], "schema version 99 is not supported")


def test_bad_input_corrupted_table(tmp_path: Path, one_line_error) -> None:
    filled_store(tmp_path / "s.zarr")
    table = tmp_path / "s.zarr" / "episodes.parquet"
    table.write_bytes(table.read_bytes()[: len(table.read_bytes()) // 2])
    one_line_error(["info", str(tmp_path / "s.zarr")], "episodes.parquet: episode table is corrupted")


def test_bad_input_truncated_array(tmp_path: Path, one_line_error) -> None:
    filled_store(tmp_path / "s.zarr")
    meta_file = tmp_path / "s.zarr" / "data" / "action" / "zarr.json"
    doc = json.loads(meta_file.read_text())
    doc["shape"][0] = 3
    meta_file.write_text(json.dumps(doc))
    one_line_error(["info", str(tmp_path / "s.zarr")], "data/action: is truncated")


def test_bad_input_corrupted_chunk(tmp_path: Path, one_line_error) -> None:
    filled_store(tmp_path / "s.zarr")
    chunk = chunk_files(tmp_path / "s.zarr", "obs.joint_pos")[0]
    chunk.write_bytes(b"garbage" * 10)
    one_line_error(["info", str(tmp_path / "s.zarr"), "--check"], "damaged episode")
    with pytest.raises(DemoError, match="obs.joint_pos: cannot be read"):
        EpisodeStore.open(tmp_path / "s.zarr").read_episode(0)


def test_bad_input_missing_chunk_is_caught_by_info_check(tmp_path: Path, one_line_error) -> None:
    filled_store(tmp_path / "s.zarr")
    for chunk in chunk_files(tmp_path / "s.zarr", "sim.state"):
        chunk.unlink()
    one_line_error(["info", str(tmp_path / "s.zarr"), "--check"], "damaged episode", "cannot be read")


def test_bad_input_on_append(tmp_path: Path) -> None:
    with EpisodeStore.create(tmp_path / "s.zarr", make_meta()) as store:
        store.append_episode(random_episode(0))
        bad = random_episode(1)
        bad["action"][3, 2] = np.nan
        with pytest.raises(DemoError, match="action: non-finite value .* at frame 3"):
            store.append_episode(bad)
        short = random_episode(2)
        short["obs.joint_pos"] = short["obs.joint_pos"][:-1]
        with pytest.raises(DemoError, match="mismatched lengths"):
            store.append_episode(short)
        missing = random_episode(3)
        del missing["sim.state"]
        with pytest.raises(DemoError, match="missing sim.state"):
            store.append_episode(missing)
        wrong = random_episode(4)
        wrong["obs.joint_pos"] = wrong["obs.joint_pos"][:, :6]
        with pytest.raises(DemoError, match="frame shape"):
            store.append_episode(wrong)
        assert store.num_episodes == 1
    store = EpisodeStore.open(tmp_path / "s.zarr")
    assert store.num_episodes == 1 and store.verify() == []


def test_a_store_that_failed_to_construct_is_collected_quietly() -> None:
    """__del__ of an object whose __init__ raised before it held a lock says nothing."""
    seen: list[object] = []
    previous, sys.unraisablehook = sys.unraisablehook, seen.append
    try:
        with pytest.raises(TypeError):
            EpisodeStore()  # type: ignore[call-arg]
        gc.collect()
    finally:
        sys.unraisablehook = previous
    assert seen == []
