"""Stores on object storage: collect / info / curate / convert against a local S3 server (moto), a
collect SIGKILLed mid-way, the writer lock, and one-line errors for bad URLs.

The server is moto's, started here on 127.0.0.1 (no network, no credentials); the module skips,
saying why, when moto or s3fs is not installed (``pip install -e '.[dev]'``).
"""

from __future__ import annotations

import gc
import importlib.util
import json
import logging
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from demo.cli.main import main
from demo.errors import DemoError
from demo.store import ActionSpec, EpisodeStore, FeatureSpec, StoreMeta

BUCKET = "demo-test"
COLLECT = ["collect", "--task", "reach", "--episodes", "3", "--seed", "4", "--workers", "0"]


@pytest.fixture(scope="module")
def s3() -> Iterator[Any]:
    """A moto S3 server on 127.0.0.1 with one bucket; the AWS_* environment points at it (subprocesses too)."""
    try:
        import s3fs
        from moto.server import ThreadedMotoServer
    except ImportError as exc:
        pytest.skip(f"no local S3 server: {exc.name} is not installed (pip install -e '.[dev]' adds moto[server], s3fs)")
    logging.getLogger("werkzeug").setLevel(logging.WARNING)  # one line per request otherwise
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    try:
        server.start()
    except OSError as exc:
        pytest.skip(f"cannot start the local S3 server on 127.0.0.1 ({exc})")
    host, port = server.get_host_and_port()
    with pytest.MonkeyPatch.context() as env:
        for name in ("AWS_PROFILE", "AWS_SESSION_TOKEN", "AWS_ENDPOINT_URL_S3", "AWS_MAX_ATTEMPTS"):
            env.delenv(name, raising=False)
        env.setenv("AWS_ENDPOINT_URL", f"http://{host}:{port}")
        env.setenv("AWS_ACCESS_KEY_ID", "test")
        env.setenv("AWS_SECRET_ACCESS_KEY", "test")
        env.setenv("AWS_DEFAULT_REGION", "us-east-1")
        s3fs.S3FileSystem.clear_instance_cache()
        fs = s3fs.S3FileSystem(use_listings_cache=False)
        fs.mkdir(BUCKET)
        yield fs
        s3fs.S3FileSystem.clear_instance_cache()
    server.stop()


def url(name: str) -> str:
    return f"s3://{BUCKET}/{name}"


def objects(fs: Any, name: str) -> dict[str, bytes]:
    prefix = f"{BUCKET}/{name}/"
    return {k[len(prefix):]: fs.cat_file(k) for k in fs.find(prefix)}


def files(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def assert_same_episodes(a: EpisodeStore, b: EpisodeStore) -> None:
    assert a.table.schema == b.table.schema
    for name in a.table.column_names:  # NaN == NaN here, unlike Table.equals
        np.testing.assert_array_equal(a.column(name), b.column(name))
    for key in a.meta.features:
        np.testing.assert_array_equal(a.load([key])[0][key], b.load([key])[0][key])


def info(capsys: pytest.CaptureFixture, store: str) -> dict:
    capsys.readouterr()
    assert main(["info", "--check", store, "--json", "-"]) == 0
    return json.loads(capsys.readouterr().out)


@pytest.mark.slow
def test_collect_to_s3_is_the_local_store_byte_for_byte(s3: Any, tmp_path: Path,
                                                        capsys: pytest.CaptureFixture) -> None:
    assert main([*COLLECT, "--out", url("reach.zarr")]) == 0
    assert main([*COLLECT, "--out", str(tmp_path / "reach.zarr")]) == 0
    summary = info(capsys, url("reach.zarr"))
    assert summary["episodes"] == 3 and summary["check"]["ok"] and summary["path"] == url("reach.zarr")
    # Every object is the file the local collect wrote, and nothing else is there.
    assert objects(s3, "reach.zarr") == files(tmp_path / "reach.zarr")
    assert not s3.exists(f"{BUCKET}/.reach.zarr.lock")  # released
    assert_same_episodes(EpisodeStore.open(url("reach.zarr")), EpisodeStore.open(tmp_path / "reach.zarr"))
    # file:// is the local path.
    assert info(capsys, f"file://{tmp_path / 'reach.zarr'}")["episodes"] == 3

    # curate s3 -> s3 and convert s3 -> local write what the same commands write from the local store
    local, remote = str(tmp_path / "reach.zarr"), url("reach.zarr")
    for src, out in ((remote, url("curated.zarr")), (local, str(tmp_path / "curated.zarr"))):
        assert main(["curate", src, "--out", out, "--max-jerk", "off", "--min-consistency", "off"]) == 0
    assert info(capsys, url("curated.zarr"))["check"]["ok"]
    assert_same_episodes(EpisodeStore.open(url("curated.zarr")), EpisodeStore.open(tmp_path / "curated.zarr"))
    for src, out in ((remote, tmp_path / "ee7_from_s3.zarr"), (local, tmp_path / "ee7.zarr")):
        assert main(["convert", src, "--to", "ee7", "--out", str(out)]) == 0
    converted = EpisodeStore.open(tmp_path / "ee7_from_s3.zarr")
    assert converted.meta.action.name == "ee7" and converted.verify() == []
    assert_same_episodes(converted, EpisodeStore.open(tmp_path / "ee7.zarr"))


def committed(fs: Any, name: str) -> int:
    try:
        return pq.read_table(pa.BufferReader(fs.cat_file(f"{BUCKET}/{name}/episodes.parquet"))).num_rows
    except FileNotFoundError:
        return 0


@pytest.mark.slow
def test_collect_killed_midway_keeps_every_finished_episode(s3: Any, tmp_path: Path,
                                                             capsys: pytest.CaptureFixture) -> None:
    # `demo collect`'s library call in a second process (without the CLI's imports: torch)
    argv = [sys.executable, "-c", "from demo.collect.scripted import CollectConfig, collect_scripted; "
            f"collect_scripted(CollectConfig(task='reach', episodes=200, seed=4), {url('killed.zarr')!r}, workers=0)"]
    with open(tmp_path / "stderr", "wb") as stderr:
        proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=stderr)
    try:
        deadline = time.time() + 90
        while committed(s3, "killed.zarr") < 2:  # polled through s3fs, as any other reader would
            assert proc.poll() is None and time.time() < deadline, (tmp_path / "stderr").read_text()
            time.sleep(0.05)
    finally:
        proc.kill()  # SIGKILL: no handler, no cleanup
        proc.wait()

    summary = info(capsys, url("killed.zarr"))
    n = summary["episodes"]
    assert 2 <= n < 200 and summary["check"]["ok"]  # every committed frame read back against its checksum
    # The killed writer's lock is left behind; the next writer on this machine takes it over.
    assert s3.exists(f"{BUCKET}/.killed.zarr.lock")
    assert main([*COLLECT, "--episodes", "1", "--append", "--out", url("killed.zarr")]) == 0
    assert info(capsys, url("killed.zarr"))["episodes"] == n + 1


def small_meta(robot: dict | None = None) -> StoreMeta:
    features = {"obs.x": FeatureSpec((2,), "float32"), "obs.image_c": FeatureSpec((4, 4, 3), "uint8")}
    return StoreMeta(fps=20.0, features=features, action=ActionSpec("joint_pos", ("a",), ("rad",)),
                     robot=robot or {"name": "t", "config": "builtin"})


def episode(i: int) -> dict[str, np.ndarray]:
    image = np.random.default_rng(i).integers(0, 4, (5, 4, 4, 3), dtype=np.uint8)
    return {"obs.x": np.full((5, 2), i, np.float32), "obs.image_c": image, "action": np.full((5, 1), i, np.float32)}


@pytest.mark.slow
def test_one_writer_and_all_or_nothing_copies(s3: Any, tmp_path: Path) -> None:
    with EpisodeStore.create(url("lock.zarr"), small_meta()) as store:
        assert not s3.exists(f"{BUCKET}/lock.zarr/episodes.parquet")  # not yet a store
        with pytest.raises(DemoError, match="no such store"):
            EpisodeStore.open(url("lock.zarr"))
        with pytest.raises(DemoError, match=r"is being written by another process \(pid \d+ on "):
            EpisodeStore.create(url("lock.zarr"), small_meta(), overwrite=True)
        store.append_episode(episode(0))
        assert EpisodeStore.open(url("lock.zarr")).num_episodes == 1  # visible with its first commit
        # A copy appears only when it is closed, however many commits it made.
        copy = store.copy_to(url("copy.zarr"))
        copy.set_column("score.x", [1.0])
        assert not s3.exists(f"{BUCKET}/copy.zarr/episodes.parquet")
        copy.close()
        assert EpisodeStore.open(url("copy.zarr")).column("score.x").tolist() == [1.0]
    # Edited in place (curate --mask), and measured as the same local store is
    with EpisodeStore.create(tmp_path / "lock.zarr", small_meta()) as local:
        local.append_episode(episode(0))
    remote = EpisodeStore.open(url("lock.zarr"), "a")
    remote.set_mask("kept", [True])
    del remote  # dropped without close: its lock goes with it
    assert EpisodeStore.open(url("lock.zarr")).mask("kept").tolist() == [True]
    assert EpisodeStore.open(url("lock.zarr")).summary()["camera_bytes"] == local.summary()["camera_bytes"]
    # Replacing needs overwrite, and deletes the old store first (not atomic, unlike a local swap).
    with pytest.raises(DemoError, match="already exists"):
        EpisodeStore.create(url("lock.zarr"), small_meta())
    with EpisodeStore.create(url("lock.zarr"), small_meta(), overwrite=True) as store:
        with pytest.raises(DemoError, match="no such store"):
            EpisodeStore.open(url("lock.zarr"))
        store.append_episodes([(episode(5), {}), (episode(6), {})])
    assert EpisodeStore.open(url("lock.zarr")).read_episode(1)["obs.x"][0, 0] == 6
    # A lock held on another machine is never taken over.
    s3.pipe_file(f"{BUCKET}/.lock.zarr.lock", f"elsewhere-{socket.gethostname()} 1\n".encode())
    with pytest.raises(DemoError, match=r"delete s3://demo-test/\.lock\.zarr\.lock and retry"):
        EpisodeStore.open(url("lock.zarr"), "a")
    s3.rm(f"{BUCKET}/.lock.zarr.lock")
    # A failed creation leaves nothing: a robot with files cannot be stored there.
    robot = {"name": "arm", "config": "/x/arm.toml", "files": {"arm.xml": "0" * 64}}
    with pytest.raises(DemoError, match="cannot hold a robot's files"):
        EpisodeStore.create(url("robot.zarr"), small_meta(robot))
    assert not s3.exists(f"{BUCKET}/robot.zarr") and not s3.exists(f"{BUCKET}/.robot.zarr.lock")


def test_bad_urls_are_one_line_errors(s3: Any, tmp_path: Path, one_line_error,
                                     monkeypatch: pytest.MonkeyPatch) -> None:
    assert "bucket s3://no-such-bucket does not exist" in one_line_error(["info", "s3://no-such-bucket/x.zarr"])
    err = one_line_error([*COLLECT, "--out", "s3://no-such-bucket/x.zarr"])
    assert "bucket s3://no-such-bucket does not exist" in err
    assert one_line_error(["info", url("absent.zarr")]).endswith(": no such store")
    assert "names a bucket, not a store in it" in one_line_error(["info", f"s3://{BUCKET}"])
    assert "unknown scheme nosuch://" in one_line_error(["info", "nosuch://b/x.zarr"])
    if importlib.util.find_spec("gcsfs") is None:
        assert "gs:// needs gcsfs: pip install -e '.[gcs]'" in one_line_error(["info", "gs://b/x.zarr"])
    monkeypatch.chdir(tmp_path)
    assert "demo import writes a local store" in one_line_error(["import", str(tmp_path), "--out", url("i.zarr")])
    assert not list(tmp_path.iterdir())  # no local "s3:" folder made of the URL


def test_unreachable_endpoint_is_one_line(s3: Any, one_line_error,
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    import s3fs

    with socket.socket() as sock:  # a port nothing listens on
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    monkeypatch.setenv("AWS_ENDPOINT_URL", f"http://127.0.0.1:{port}")
    monkeypatch.setenv("AWS_MAX_ATTEMPTS", "1")  # botocore's retries: seconds otherwise
    s3fs.S3FileSystem.clear_instance_cache()
    gc.collect()  # the dropped filesystems' sessions complain on stderr when collected: not during the command
    try:
        err = one_line_error(["info", url("reach.zarr")])
    finally:
        s3fs.S3FileSystem.clear_instance_cache()
    assert "cannot reach the object store" in err and "AWS_ENDPOINT_URL" in err
