"""Executors (demo.executor): Ray actors give the same bytes as worker processes for collection, the
same results for evaluation and the same DAgger rollouts as this process; a Ray worker killed
mid-episode is replaced and its episode run again; without Ray, --executor ray is one line.

One local Ray (2 CPUs) serves the module: starting one costs seconds.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from demo.collect import scripted
from demo.collect.scripted import CollectConfig, collect_scripted, store_meta
from demo.errors import DemoError
from demo.executor import ExecutorConfig, ordered_map
from demo.store import EpisodeStore

pytestmark = pytest.mark.slow  # Ray and process pools start per test: ~145 s in all

REACH = {"pos_tol": 0.04, "rot_tol": 0.4}  # as the other reach tests: a seconds-long BC run shows
RAY2 = ExecutorConfig("ray", 2)


@pytest.fixture(scope="module")
def ray_cluster():
    """A local Ray with 2 CPUs for the module (the executor joins it and leaves it running)."""
    try:
        import ray
    except ImportError:
        pytest.skip("Ray is not installed (pip install -e '.[ray]')")
    import logging

    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, logging_level=logging.ERROR)
    yield ray
    ray.shutdown()


@pytest.fixture(scope="module")
def reference(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """6 reach episodes collected by 2 worker processes."""
    path = tmp_path_factory.mktemp("executor") / "process.zarr"
    collect_scripted(CollectConfig(task="reach", episodes=6, seed=7, task_options=REACH), path, workers=2)
    return path


def files(store: Path) -> dict[str, bytes]:
    return {str(p.relative_to(store)): p.read_bytes() for p in sorted(store.rglob("*")) if p.is_file()}


def test_ray_collection_is_byte_identical_to_worker_processes(ray_cluster, reference: Path, tmp_path: Path) -> None:
    out = tmp_path / "ray.zarr"
    result = collect_scripted(CollectConfig(task="reach", episodes=6, seed=7, task_options=REACH), out, executor=RAY2)
    assert result.episodes == 6 and result.frames > 0
    assert ray_cluster.is_initialized()  # a Ray it did not start is left running
    ours, theirs = files(out), files(reference)
    assert sorted(ours) == sorted(theirs) and "episodes.parquet" in ours
    assert [k for k in ours if ours[k] != theirs[k]] == []  # every array chunk, the episode table, the metadata
    assert EpisodeStore.open(out).verify() == []


def test_a_ray_worker_killed_mid_episode_is_replaced_and_the_episode_rerun(ray_cluster, reference: Path,
                                                                           tmp_path: Path) -> None:
    config = CollectConfig(task="reach", episodes=6, seed=7, task_options=REACH)
    marker = tmp_path / "killed"

    def dies_once_in_episode_2(index: int):  # a closure: Ray sends it by value, a test-only job function
        env = scripted._worker_env
        if index == 2 and not marker.exists():
            marker.touch()
            step = env.step

            def step_then_die(*args, **kwargs):
                if env.steps >= 5:  # mid-episode: 5 control steps in
                    os._exit(1)
                return step(*args, **kwargs)

            env.step = step_then_die
        return scripted._worker_run(index)

    results = [r for ready in ordered_map(scripted._worker_init, (config,), dies_once_in_episode_2, range(6), RAY2)
               for r in ready]
    assert marker.exists()  # the worker did die
    assert [i for i, _, _ in results] == list(range(6))
    env = scripted.make_env_for(config)
    meta = store_meta(config, env)
    env.close()
    with EpisodeStore.create(tmp_path / "retried.zarr", meta) as store:
        store.append_episodes([(data, info) for _, data, info in results])
    retried, ref = EpisodeStore.open(tmp_path / "retried.zarr"), EpisodeStore.open(reference)
    assert retried.column("crc32").tolist() == ref.column("crc32").tolist()
    for i in range(6):
        a, b = retried.read_episode(i), ref.read_episode(i)
        assert all(np.array_equal(a[k], b[k]) and a[k].dtype == b[k].dtype for k in b), i


def test_a_job_whose_worker_always_dies_fails_in_one_line_naming_it(ray_cluster) -> None:
    def nothing() -> None:
        pass

    def always_dies(job: int) -> int:
        if job == 1:
            os._exit(1)
        return job

    with pytest.raises(DemoError, match=r"^job 1: its Ray worker died 2 times") as caught:
        for _ in ordered_map(nothing, (), always_dies, range(3), ExecutorConfig("ray", 2, retries=1),
                             label=lambda j: f"job {j}"):
            pass
    assert "\n" not in str(caught.value)


def test_an_error_in_a_worker_is_raised_here_as_itself(ray_cluster, tmp_path: Path) -> None:
    """Not retried, and not lost: a pool whose initializer raised used to restart it forever."""
    config = CollectConfig(task="reach", robot=str(tmp_path / "none.toml"))
    for executor in (ExecutorConfig("ray", 1), ExecutorConfig("process", 1)):
        with pytest.raises(DemoError, match="none.toml"):
            list(ordered_map(scripted._worker_init, (config,), scripted._worker_run, range(2), executor))


def test_ray_evaluation_gives_the_process_workers_results(ray_cluster, reference: Path, tmp_path: Path,
                                                          tiny_bc_config) -> None:
    from demo.imitation.bc import train
    from demo.evaluation.evaluate import EvalConfig, evaluate

    train(tiny_bc_config(reference, tmp_path / "bc", steps=50, include_failures=True))
    results = [evaluate(EvalConfig(run=str(tmp_path / "bc"), episodes=4, seed=3, workers=2, executor=executor))
               for executor in ("process", "ray")]
    assert [r["executor"] for r in results] == ["process", "ray"]
    for key in ("successes", "mean_length", "failures", "episodes_detail"):
        assert results[0][key] == results[1][key], key
    assert results[1]["episodes"] == 4


def test_dagger_rollouts_on_ray_are_the_in_process_ones(ray_cluster, reference: Path, tmp_path: Path) -> None:
    from demo.training.config import TrainConfig
    from demo.imitation.dagger import DaggerConfig, train_dagger

    def dagger(out: Path, executor: ExecutorConfig | None) -> EpisodeStore:
        tc = TrainConfig(data=str(reference), out=str(out), steps=100, batch_size=64, chunk=2, policy={"hidden": (32, 32)},
                         val_fraction=0.25, log_every=50, val_every=50, include_failures=True)
        train_dagger(DaggerConfig(train=tc, rounds=1, episodes_per_round=3, round_steps=40), executor=executor)
        return EpisodeStore.open(out / "data.zarr")

    inline, remote = dagger(tmp_path / "inline", None), dagger(tmp_path / "ray", RAY2)
    from demo.imitation.dagger import SEGMENT_SOURCE

    segments = inline.column("source") == SEGMENT_SOURCE  # the chunked learner's labels, each an episode
    rollouts = np.flatnonzero((inline.column("dagger_round") == 1) & ~segments)
    assert len(rollouts) == 3 and segments.any() and remote.num_episodes == inline.num_episodes
    assert remote.column("crc32").tolist() == inline.column("crc32").tolist()
    assert remote.table.equals(inline.table)


def test_bench_collect_executor_ray_compares_with_processes_in_one_run(ray_cluster) -> None:
    from demo.bench.collect import run_executors

    r = run_executors(task="reach", episodes=3, rounds=1)
    assert r["same_bytes"] and r["workers"] == 2 and len(r["samples"]["ray"]) == len(r["samples"]["process"]) == 1
    assert r["ray_to_process"] == pytest.approx(r["ray"]["frames_per_s"] / r["process"]["frames_per_s"])
    assert r["ray"]["executor"] == "ray" and r["process"]["executor"] == "process" and r["ray"]["frames"] > 0


def test_a_local_ray_started_here_listens_on_the_loopback_only() -> None:
    """Without --address the local Ray is this machine's alone: before, its servers listened on every
    interface (Ray takes the address of the default route, and turns a loopback one asked for into it)."""
    pytest.importorskip("ray", reason="Ray is not installed (pip install -e '.[ray]')")
    script = ("import json, ray\n"  # a process of its own: this module's Ray must not be running
              "from demo.executor import ExecutorConfig, session\n"
              "with session(ExecutorConfig('ray', 1)):\n"
              "    print(json.dumps([[n['NodeManagerAddress'] for n in ray.nodes()], ray.util.get_node_ip_address(),\n"
              "                      ray.get_runtime_context().gcs_address]))\n")
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    nodes, ip, gcs = json.loads(proc.stdout.strip().splitlines()[-1])
    assert nodes == ["127.0.0.1"] and ip == "127.0.0.1" and gcs.startswith("127.0.0.1:")


def test_without_ray_executor_ray_fails_in_one_line(tmp_path: Path) -> None:
    out = tmp_path / "r.zarr"
    script = ("import sys; sys.modules['ray'] = None\n"  # `import ray` raises ImportError, as when not installed
              "from demo.cli.main import main\n"
              f"sys.exit(main(['collect', '--task', 'reach', '--episodes', '1', '--executor', 'ray', '--out', {str(out)!r}]))")
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "MUJOCO_GL": "egl"})
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode != 0 and len(lines) == 1, proc.stderr
    assert lines[0] == "error: --executor ray: Ray is not installed: pip install -e '.[ray]' (or pip install 'ray>=2.40')"
    assert not out.exists()


def test_bad_executor_settings_are_refused() -> None:
    for config, needle in [(ExecutorConfig("dask", 2), "--executor: unknown executor 'dask'"),
                           (ExecutorConfig("process", 2, address="auto"), "--address: names a Ray cluster"),
                           (ExecutorConfig("ray", 0), "--workers: --executor ray needs at least 1 worker")]:
        with pytest.raises(DemoError) as caught:
            config.check()
        assert str(caught.value).startswith(needle)


def test_cli_refuses_executor_flags_where_they_do_not_apply(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from demo.cli.main import main

    for argv, needle in [
        (["eval", str(tmp_path / "run"), "--executor", "dask"], "error: --executor: unknown executor 'dask'"),
        (["collect", "--task", "reach", "--workers", "2", "--address", "auto", "--out", str(tmp_path / "a.zarr")],
         "error: --address: names a Ray cluster"),
        (["collect", "--source", "vr", "--input", "poses.jsonl", "--executor", "ray", "--out", str(tmp_path / "b.zarr")],
         "error: --source: vr replays recorded input"),
        (["train", str(tmp_path / "s.zarr"), "--out", str(tmp_path / "r"), "--workers", "2"],
         "error: --workers: --workers, --executor and --address run DAgger's rollouts"),
    ]:
        assert main(argv) != 0
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and err.startswith(needle), (argv, err)
    assert not any(tmp_path.iterdir())


def _dies_at_job_1(job: int) -> int:
    if job == 1:
        os._exit(3)
    return job


def _nothing() -> None:
    pass


def test_a_worker_process_that_dies_fails_in_one_line_naming_its_job() -> None:
    """Not a hang: a worker killed for memory, or crashing in native code, used to leave its job
    waiting forever in a multiprocessing pool."""
    with pytest.raises(DemoError, match=r"^job 1: its worker process died \(exit code 3\)$"):
        for _ in ordered_map(_nothing, (), _dies_at_job_1, range(4), ExecutorConfig("process", 2),
                             label=lambda j: f"job {j}"):
            pass
    results = [r for ready in ordered_map(_nothing, (), _dies_at_job_1, [0, 2, 3, 4, 5], ExecutorConfig("process", 2))
               for r in ready]
    assert results == [0, 2, 3, 4, 5]  # in job order
