"""Issue 21, the store half: the writer lock comes first, replacing is crash-safe, the schema is checked,
failed commands leave no half-made output and refused ones write nothing, training needs a minimum."""

from __future__ import annotations

import hashlib
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
from demo.interop.common import staged_output
from demo.interop.sample import make_sample_store, sample_meta
from demo.store import EpisodeStore


# ------------------------------------------------------------------------------------------ helpers
def tree_bytes(path: Path) -> dict[str, bytes]:
    """Every file under ``path`` with its bytes (a store unchanged is this, unchanged)."""
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*")) if p.is_file()}


def digest(path: Path) -> str:
    return hashlib.sha256(json.dumps({k: v.hex() for k, v in tree_bytes(path).items()}).encode()).hexdigest()


def leftovers(folder: Path, name: str) -> list[str]:
    """Staging folders, swapped-out stores and lock files of ``name`` left in ``folder``."""
    return sorted(p.name for p in folder.iterdir() if p.name.startswith(f".{name}."))


def spawn(tmp_path: Path, code: str, *args: str) -> subprocess.Popen:
    script = tmp_path / f"child{time.monotonic_ns()}.py"
    script.write_text(textwrap.dedent(code))
    return subprocess.Popen([sys.executable, str(script), *args], stderr=subprocess.PIPE, text=True)


def wait_for(marker: Path, proc: subprocess.Popen, seconds: float = 60) -> None:
    deadline = time.time() + seconds
    while not marker.exists():
        assert proc.poll() is None, proc.stderr.read() if proc.stderr else proc.returncode
        assert time.time() < deadline, f"child never reached {marker.name}"
        time.sleep(0.02)


def kill(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        os.kill(proc.pid, signal.SIGKILL)
    proc.wait()


HOLDER = """
    import sys, time
    from demo.store import EpisodeStore
    store = EpisodeStore.open(sys.argv[1], "a")  # holds the writer lock, as an append in progress does
    open(sys.argv[2], "w").close()
    time.sleep(120)
"""


# ------------------------------------------------------------------------------------------ point 1
def test_overwrite_of_a_store_being_written_is_refused(tmp_path: Path, one_line_error) -> None:
    store = make_sample_store(tmp_path / "s.zarr")
    before = tree_bytes(store)
    holder = spawn(tmp_path, HOLDER, str(store), str(tmp_path / "ready"))
    try:
        wait_for(tmp_path / "ready", holder)
        busy = f"is being written by another process (pid {holder.pid})"
        with pytest.raises(DemoError, match=busy.replace("(", r"\(").replace(")", r"\)")):
            EpisodeStore.create(store, sample_meta(), overwrite=True)
        with EpisodeStore.open(make_sample_store(tmp_path / "src.zarr")) as src, pytest.raises(DemoError, match=busy[:30]):
            src.copy_to(store, overwrite=True)  # curate's and DAgger's path
        with pytest.raises(DemoError, match=busy[:30]):
            with staged_output(store, overwrite=True, looks_like=lambda p: True, kind="demo store", is_dir=True):
                pass  # import's path
        one_line_error(["collect", "--task", "reach", "--episodes", "1", "--workers", "0", "--overwrite",
                        "--out", str(store)], busy)
        assert tree_bytes(store) == before  # nothing was removed, replaced or written
    finally:
        kill(holder)


REPLACER = """
    import os, sys, time
    from demo.interop.sample import sample_episode, sample_meta
    from demo.store import EpisodeStore, swap
    import numpy as np
    path, step, marker = sys.argv[1:4]

    def pause():
        open(marker, "w").close()
        time.sleep(120)

    if step == "staged":  # the new store is complete beside the old one, not yet swapped in
        publish = swap.publish
        swap.publish = lambda a, b: (pause(), publish(a, b))
    elif step == "swapped":  # swapped, the old store not yet deleted
        remove = swap.remove
        swap.remove = lambda p: (pause() if ".tmp-" in p.name else None, remove(p))
    elif step == "halfway":  # a filesystem without an atomic exchange, killed between its two renames
        swap._exchange = lambda a, b: False
        rename, calls = os.rename, []
        def halfway(a, b):
            calls.append(a)
            if len(calls) == 2:
                pause()
            rename(a, b)
        swap.os.rename = halfway
    store = EpisodeStore.create(path, sample_meta(), overwrite=True)
    store.append_episode(sample_episode(np.random.default_rng(7), sample_meta(), 5), seed=7)
    store.close()
"""


@pytest.mark.parametrize("step", ["staged", "swapped", "halfway"])
def test_replacing_a_store_is_crash_safe(tmp_path: Path, step: str, one_line_error) -> None:
    store = make_sample_store(tmp_path / "s.zarr")
    old = digest(store)
    proc = spawn(tmp_path, REPLACER, str(store), step, str(tmp_path / "paused"))
    try:
        wait_for(tmp_path / "paused", proc)
    finally:
        kill(proc)
    if step == "halfway":  # the old store is aside: a reader is told so, the next writer puts it back
        one_line_error(["info", str(store)], "no such store", "killed halfway")
        EpisodeStore.open(store, "a").close()
    with EpisodeStore.open(store) as s:
        assert s.verify() == []
        seeds = s.column("seed").tolist()
    assert seeds == ([7] if step == "swapped" else list(range(100, 106)))  # the new store, or the old one whole
    if step != "swapped":
        assert digest(store) == old
    EpisodeStore.open(store, "a").close()  # the next writer removes what the killed one left
    assert leftovers(tmp_path, "s.zarr") == []


# ------------------------------------------------------------------------------------------ point 2
CREATOR = """
    import sys, time
    from pathlib import Path
    import numpy as np
    from demo.errors import DemoError
    from demo.interop.sample import sample_episode, sample_meta
    from demo.store import EpisodeStore
    path, ready, go, hold = sys.argv[1:5]
    Path(ready).touch()
    while not Path(go).exists():
        time.sleep(0.001)
    try:
        store = EpisodeStore.create(path, sample_meta())
        if hold != "-":
            Path(hold).touch()
            while not Path(hold + ".go").exists():
                time.sleep(0.01)
        store.append_episodes([(sample_episode(np.random.default_rng(i), sample_meta(), 4), {"seed": i}) for i in range(2)])
        store.close()
    except DemoError as exc:
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(1)
"""


def test_the_loser_of_two_creates_fails_in_one_line(tmp_path: Path, one_line_error) -> None:
    store, go = tmp_path / "new.zarr", tmp_path / "go"
    go.touch()
    winner = spawn(tmp_path, CREATOR, str(store), str(tmp_path / "ready"), str(go), str(tmp_path / "held"))
    try:
        wait_for(tmp_path / "held", winner)  # created (lock held), nothing committed yet
        one_line_error(["collect", "--task", "reach", "--episodes", "1", "--workers", "0", "--out", str(store)],
                       f"is being written by another process (pid {winner.pid})")
        (tmp_path / "held.go").touch()
        assert winner.wait(timeout=60) == 0, winner.stderr.read()
    finally:
        kill(winner)
    with EpisodeStore.open(store) as s:
        assert s.num_episodes == 2 and s.verify() == []


def test_concurrent_creates_one_wins_the_others_fail_cleanly(tmp_path: Path) -> None:
    store, go = tmp_path / "new.zarr", tmp_path / "go"
    procs = [spawn(tmp_path, CREATOR, str(store), str(tmp_path / f"ready{k}"), str(go), "-") for k in range(3)]
    try:
        for k, p in enumerate(procs):
            wait_for(tmp_path / f"ready{k}", p)
        go.touch()
        results = [(p.wait(timeout=60), p.stderr.read()) for p in procs]
    finally:
        for p in procs:
            kill(p)
    assert sorted(rc for rc, _ in results) == [0, 1, 1], results
    for rc, err in results:
        if rc:
            assert err.startswith("error: ") and len(err.strip().splitlines()) == 1, err
            assert "is being written by another process" in err or "already exists" in err, err
    with EpisodeStore.open(store) as s:
        assert s.num_episodes == 2 and s.verify() == []
    assert leftovers(tmp_path, "new.zarr") == []


# ------------------------------------------------------------------------------------------ point 5
@pytest.mark.parametrize("key, field, value, shown", [
    ("action", "data_type", "int32", "array holds int32 frames"),
    ("obs.joint_pos", "trailing", 6, "of shape (6,)"),
])
def test_array_dtype_and_shape_are_checked_against_the_schema(tmp_path: Path, one_line_error,
                                                               key: str, field: str, value: object, shown: str) -> None:
    store = make_sample_store(tmp_path / "s.zarr")
    meta_file = store / "data" / key / "zarr.json"
    doc = json.loads(meta_file.read_text())
    if field == "trailing":
        doc["shape"][1] = doc["chunk_grid"]["configuration"]["chunk_shape"][1] = value
    else:
        doc[field] = value
    meta_file.write_text(json.dumps(doc))
    one_line_error(["info", str(store), "--check"], f"data/{key}/zarr.json", shown, "schema declares")
    with pytest.raises(DemoError, match="schema declares"):
        EpisodeStore.open(store)


# ------------------------------------------------------------------------------------------ point 6
def poison(store: Path, key: str) -> None:
    """A NaN in the first chunk of ``key`` (uncompressed float32 rows)."""
    chunk = sorted(p for p in (store / "data" / key / "c").rglob("*") if p.is_file())[0]
    values = np.frombuffer(chunk.read_bytes(), np.float32).copy()
    values[1] = np.nan
    chunk.write_bytes(values.tobytes())


def test_failed_curate_names_its_input_and_leaves_no_output(tmp_path: Path, one_line_error) -> None:
    from demo.curate import synthetic

    good = synthetic.write_store(tmp_path / "good.zarr", synthetic.mixed_episodes(8, seed=3))
    bad = tmp_path / "bad.zarr"
    bad.mkdir()
    for name, data in tree_bytes(good).items():
        (bad / name).parent.mkdir(parents=True, exist_ok=True)
        (bad / name).write_bytes(data)
    poison(bad, "obs.goal")
    out = tmp_path / "curated.zarr"
    one_line_error(["curate", str(bad), "--out", str(out)], f"{bad} episode 0", "obs.goal: non-finite")
    assert not out.exists() and leftovers(tmp_path, "curated.zarr") == []
    assert main(["curate", str(good), "--out", str(out)]) == 0  # a rerun needs no --overwrite
    before = digest(out)
    one_line_error(["curate", str(bad), "--out", str(out), "--overwrite"], f"{bad} episode 0")
    assert digest(out) == before  # a failed --overwrite leaves the old output whole


def test_failed_convert_names_its_input_and_leaves_no_output(tmp_path: Path) -> None:
    from demo.collect.scripted import CollectConfig, collect_scripted
    from demo.convert.convert import ConvertOptions, convert_store

    src = tmp_path / "src.zarr"
    collect_scripted(CollectConfig(task="reach", episodes=2, seed=0), src, workers=0)
    poison(src, "obs.joint_vel")
    # The poisoned chunk no longer matches the checksum written with it: refused where it is read.
    with pytest.raises(DemoError, match=f"{src}: episode 0: its data does not match its checksum"):
        convert_store(src, tmp_path / "ee7.zarr", ConvertOptions(to="ee7"))
    assert not (tmp_path / "ee7.zarr").exists() and leftovers(tmp_path, "ee7.zarr") == []


def test_collect_failing_before_its_first_episode_leaves_nothing(tmp_path: Path) -> None:
    from demo.collect.scripted import CollectConfig, collect_scripted

    def interrupted(tick: object) -> None:
        raise KeyboardInterrupt  # Ctrl-C once the store is open, before any episode is committed

    out = tmp_path / "c.zarr"
    with pytest.raises(KeyboardInterrupt):
        collect_scripted(CollectConfig(task="reach", episodes=2), out, workers=0, progress=interrupted)
    assert not out.exists() and leftovers(tmp_path, "c.zarr") == []
    old = make_sample_store(tmp_path / "old.zarr")
    before = digest(old)
    with pytest.raises(KeyboardInterrupt):
        collect_scripted(CollectConfig(task="reach", episodes=2), old, workers=0, overwrite=True, progress=interrupted)
    assert digest(old) == before  # an interrupted --overwrite replaced nothing
    result = collect_scripted(CollectConfig(task="reach", episodes=1), out, workers=0)  # no --overwrite needed
    assert result.episodes == 1 and EpisodeStore.open(out).num_episodes == 1


def test_a_failed_import_leaves_no_output_and_releases_the_lock(tmp_path: Path) -> None:
    out = tmp_path / "imported.zarr"
    with pytest.raises(DemoError, match="bad row"):
        with staged_output(out, overwrite=False, looks_like=lambda p: True, kind="demo store", is_dir=True) as tmp:
            make_sample_store(tmp)
            raise DemoError("lerobot/data/chunk-000/file-000.parquet", "bad row")
    assert not out.exists() and leftovers(tmp_path, "imported.zarr") == []


# ------------------------------------------------------------------------------------------ point 8
CRASHED_COLLECT = """
    import os, signal, sys
    from demo.collect.scripted import CollectConfig, collect_scripted

    def die(tick):
        if tick.done == 2:
            os.kill(os.getpid(), signal.SIGKILL)  # a crash: arrays keep their spare capacity

    collect_scripted(CollectConfig(task="reach", episodes=5), sys.argv[1], workers=0, progress=die)
"""


def test_a_refused_append_writes_nothing(tmp_path: Path, one_line_error) -> None:
    store = tmp_path / "crashed.zarr"
    proc = spawn(tmp_path, CRASHED_COLLECT, str(store))
    assert proc.wait(timeout=120) == -signal.SIGKILL, proc.stderr.read()
    with EpisodeStore.open(store) as s:
        committed = s.num_frames
        assert s.num_episodes == 2 and s.array("action").shape[0] > committed  # spare rows left by the crash
    before = tree_bytes(store)
    one_line_error(["collect", "--task", "pick", "--episodes", "1", "--workers", "0", "--append",
                    "--out", str(store)], "cannot append", "different task")
    assert tree_bytes(store) == before
    assert leftovers(tmp_path, "crashed.zarr") == []  # nor a lock file left behind


# ------------------------------------------------------------------------------------------ point 10
@pytest.mark.parametrize("episodes, length, needle", [
    (1, 30, "1 training episode(s) with 30 labelled frame(s)"),
    (2, 3, "2 training episode(s) with 6 labelled frame(s)"),
])
def test_training_below_the_minimum_is_refused(tmp_path: Path, one_line_error, synthetic_store,
                                               episodes: int, length: int, needle: str) -> None:
    store = synthetic_store(tmp_path / "tiny.zarr", episodes=episodes, length=length)
    one_line_error(["train", str(store), "--out", str(tmp_path / "run"), "--steps", "2"],
                   "too little to train on", needle, "the minimum is 2 episodes and one window of 16 frames")
