"""Scripted collection: determinism, DART labels, appends, interruption, CLI errors."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from demo.cli.main import main
from demo.collect.scripted import CollectConfig, collect_scripted
from demo.errors import DemoError
from demo.progress import Tick
from demo.seeds import episode_seed
from demo.store import EpisodeStore


def crcs(path: Path) -> list[int]:
    return EpisodeStore.open(path).column("crc32").tolist()


def test_same_seed_same_bytes_for_any_worker_count(tmp_path: Path) -> None:
    config = CollectConfig(task="reach", episodes=3, seed=5)
    inline = collect_scripted(config, tmp_path / "a.zarr", workers=0)
    collect_scripted(CollectConfig(task="reach", episodes=3, seed=5), tmp_path / "b.zarr", workers=2)
    assert inline.episodes == 3 and inline.frames > 0
    assert crcs(tmp_path / "a.zarr") == crcs(tmp_path / "b.zarr")
    store = EpisodeStore.open(tmp_path / "a.zarr")
    assert store.column("seed").tolist() == [episode_seed(5, i) for i in range(3)]
    assert set(store.meta.features) >= {"action", "sim.state", "info.executed_action", "info.ee_target", "obs.joint_pos"}
    assert store.meta.task["name"] == "reach" and store.meta.robot["config"] == "builtin"
    assert store.verify() == []


def test_different_seeds_different_initial_states(tmp_path: Path) -> None:
    collect_scripted(CollectConfig(task="reach", episodes=2, seed=0), tmp_path / "a.zarr", workers=0)
    collect_scripted(CollectConfig(task="reach", episodes=2, seed=1), tmp_path / "b.zarr", workers=0)
    a, b = EpisodeStore.open(tmp_path / "a.zarr"), EpisodeStore.open(tmp_path / "b.zarr")
    first = [s.read_episode(i, ["sim.state"])["sim.state"][0] for s in (a, b) for i in range(2)]
    for i in range(4):
        for j in range(i + 1, 4):
            assert not np.allclose(first[i], first[j])


def test_dart_noise_keeps_clean_labels(tmp_path: Path) -> None:
    collect_scripted(CollectConfig(task="reach", episodes=2, seed=0, noise=0.05), tmp_path / "n.zarr", workers=0)
    ep = EpisodeStore.open(tmp_path / "n.zarr").read_episode(0)
    diff = ep["info.executed_action"][:, :7] - ep["action"][:, :7]
    assert 0.03 < diff.std() < 0.07  # the executed command carries the noise ...
    np.testing.assert_array_equal(ep["info.executed_action"][:, 7], ep["action"][:, 7])  # ... not the gripper


def test_append_continues_the_seed_sequence(tmp_path: Path) -> None:
    collect_scripted(CollectConfig(task="reach", episodes=2, seed=0), tmp_path / "s.zarr", workers=0)
    collect_scripted(CollectConfig(task="reach", episodes=2, seed=0), tmp_path / "s.zarr", workers=0, append=True)
    store = EpisodeStore.open(tmp_path / "s.zarr")
    assert store.column("seed").tolist() == [episode_seed(0, i) for i in range(4)]
    with pytest.raises(DemoError, match="different task"):
        collect_scripted(CollectConfig(task="pick", episodes=1), tmp_path / "s.zarr", workers=0, append=True)


@pytest.mark.parametrize("workers", [0, 1])
def test_interrupt_keeps_finished_episodes(tmp_path: Path, workers: int) -> None:
    ticks: list[Tick] = []

    def stop_after_two(tick: Tick) -> None:
        ticks.append(tick)
        if tick.done == 2:
            raise KeyboardInterrupt

    # Far more episodes than are needed to interrupt: a worker running ahead of a busy main process
    # must not be able to finish them all (with 6, a loaded machine once stored all 6).
    with pytest.raises(KeyboardInterrupt):
        collect_scripted(CollectConfig(task="reach", episodes=40), tmp_path / "s.zarr", workers=workers, progress=stop_after_two)
    assert [t.done for t in ticks] == [0, 1, 2] and {t.total for t in ticks} == {40}
    assert ticks[0].stage == "collect reach" and ticks[-1].fields["frames"] > ticks[1].fields["frames"] > 0
    store = EpisodeStore.open(tmp_path / "s.zarr")
    assert 2 <= store.num_episodes < 40
    assert store.verify() == []


def ctrl_c_reaches() -> None:
    """A child's SIGINT at its default (Python's KeyboardInterrupt), whatever this process inherited: a test run
    started in the background by a shell without job control ignores SIGINT, and its children would too (a
    process that starts with SIGINT ignored rightly keeps ignoring it), so Ctrl-C would never reach them."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_killed_collect_run_with_workers_ends_quietly(tmp_path: Path, signum: int) -> None:
    """Ctrl-C (SIGINT to the process group; SIGTERM alike) of `demo collect --workers 1`: before, the
    worker printed a KeyboardInterrupt or BrokenPipeError traceback (the parent at times hung in its
    pool's shutdown), and on SIGTERM the resource tracker warned of leaked semaphores."""
    out = tmp_path / "x.zarr"
    # Far more episodes than run before the signal: 200 pick episodes take under 8 s on a quiet machine.
    argv = ["collect", "--task", "pick", "--episodes", "100000", "--workers", "1", "--out", str(out)]
    with open(tmp_path / "stderr", "w") as stderr:  # a file: a pipe nobody reads yet could fill and stall the run
        child = subprocess.Popen([sys.executable, "-m", "demo", *argv], stdout=subprocess.DEVNULL, stderr=stderr,
                                 start_new_session=True, env={**os.environ, "MUJOCO_GL": "egl"},
                                     preexec_fn=ctrl_c_reaches)
    try:
        deadline = time.monotonic() + 60  # the worker is running jobs once an episode is stored
        while time.monotonic() < deadline and child.poll() is None:
            try:
                if EpisodeStore.open(out).num_episodes >= 1:
                    break
            except DemoError:  # not created yet
                pass
            time.sleep(0.2)
        assert child.poll() is None, "the run ended before it was interrupted"
        os.killpg(child.pid, signum)
        child.wait(timeout=60)
    finally:
        if child.poll() is None:  # hung: not this test's to leave running
            os.killpg(child.pid, signal.SIGKILL)
            child.wait()
    err = (tmp_path / "stderr").read_text()
    assert "Traceback" not in err and "leaked semaphore" not in err, err
    assert child.returncode == 130, err
    store = EpisodeStore.open(out)
    assert 1 <= store.num_episodes < 100000 and store.verify() == []
    assert main(["info", str(out)]) == 0


def test_cli_collect_and_bad_input(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "r.zarr"
    assert main(["collect", "--task", "reach", "--episodes", "2", "--workers", "0", "--out", str(out), "--json", "-"]) == 0
    assert '"successes"' in capsys.readouterr().out
    before = crcs(out)
    for argv, needle in [
        (["--out", str(out)], "already exists (pass --append to add episodes to it, --overwrite to replace it"),
        (["--out", str(tmp_path / "x.zarr"), "--operator", "bad"], "unknown operator profile"),
        (["--out", str(tmp_path / "x.zarr"), "--task", "juggle"], "juggle"),
        (["--out", str(tmp_path / "x.zarr"), "--episodes", "0"], "at least 1"),
        (["--out", str(tmp_path / "x.zarr"), "--camera", "front"], "NAME@WIDTHxHEIGHT"),
        (["--out", str(tmp_path / "x.zarr"), "--robot", str(tmp_path / "none.toml")], "none.toml"),
    ]:
        rc = main(["collect", "--task", "reach", "--episodes", "1", "--workers", "0", *argv])
        err = capsys.readouterr().err.strip()
        assert rc != 0 and len(err.splitlines()) == 1 and needle in err, (argv, err)
    assert crcs(out) == before  # nothing stored was lost
