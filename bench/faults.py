"""`demo bench faults`: kills, races and a full disk against every store writer; no finished episode may be lost.

Every scenario runs real ``demo`` processes on ``reach`` (the fastest task: its scripted episodes end
at success, ~27 frames each) and then opens each store, verifies every episode's checksum and checks
that the episodes it holds are the ones collected, in order (their reset seeds):

- **SIGKILL collect** (``kills`` trials): a ``episodes``-episode collection (default 1,000, with
  ``workers`` simulation processes) is killed, writer and workers at once (SIGKILL to its process
  group), at a time drawn uniformly from ``[0, max_kill_s]`` s, start-up included;
- **SIGKILL append** (``append_kills``): the same, appending to a copy of a 20-episode store, killed
  at a time uniform in ``[0, max_kill_s]`` s after the appender opened the store;
- **overwrite race** (``races``): while such an append runs, ``demo collect --overwrite``, ``demo
  convert --overwrite`` and ``demo import --overwrite`` (in turn) target its store; each must be
  refused with one line naming the writer's pid, then the appender is killed;
- **concurrent create** (``creates``): three ``demo collect`` processes create the same new store at
  the same moment; one must win, the others fail with one ``error:`` line;
- **full disk** (one trial): a collection into a ``disk_mib`` MiB tmpfs mounted for the run (as root),
  else into a folder where the child may write no file over 32 KiB (``RLIMIT_FSIZE``, so it fails on
  its first chunk), until the disk refuses a write.

A finished episode is one the collector reported committed (its progress callback, called after the
commit, logs the count to a file outside the store) before it died. Lost = finished episodes the
store does not hold intact; the command fails when any was lost. A store that does not exist after a
kill counts as fine only if nothing was finished.
"""

from __future__ import annotations

import json
import os
import random
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from demo.bench.common import machine
from demo.collect.scripted import CollectConfig, collect_scripted, start_seed
from demo.errors import DemoError
from demo.progress import Progress, Tick, or_silent
from demo.store import EpisodeStore

TASK = "reach"
BASE_EPISODES = 20  # episodes in the store that appends and races start from
CREATORS = 3  # processes racing to create one store
FSIZE_LIMIT = 32 * 1024  # bytes per file when no tmpfs can be mounted (not root)
CHILD = "import json, sys; from demo.bench.faults import child_collect; child_collect(json.loads(sys.argv[1]))"
CREATOR = ("import sys, time; from pathlib import Path; from demo.cli.main import main; go = Path(sys.argv[1]); "
           "Path(sys.argv[2]).touch()\nwhile not go.exists(): time.sleep(0.001)\nsys.exit(main(sys.argv[3:]))")


@dataclass
class FaultsConfig:
    """The run's sizes (``demo bench faults`` takes its defaults from here)."""

    episodes: int = 1000  # episodes each killed collection is asked for
    kills: int = 20
    append_kills: int = 5
    races: int = 5
    creates: int = 5
    max_kill_s: float = 10.0  # kill times are uniform in [0, max_kill_s] s after the start
    disk_mib: int = 2
    workers: int = 1
    seed: int = 0  # seeds the kill times (the collections use seed 0)


# ------------------------------------------------------------------------------------------ the child
def child_collect(args: dict[str, Any]) -> None:
    """Entry point of a collecting child: ``collect_scripted`` that logs each commit's episode count.

    ``args``: ``out``, ``log``, ``episodes``, ``workers``, ``append`` and ``fsize`` (a per-file size
    limit in bytes, 0 for none). Exits 1 with ``error: ...`` on one line when collection fails.
    """
    if args.get("fsize"):
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # an over-size write fails with EFBIG instead
        resource.setrlimit(resource.RLIMIT_FSIZE, (args["fsize"], args["fsize"]))
    log = open(args["log"], "a", buffering=1)  # one write per line: the parent reads it after a kill

    def logged(tick: Tick) -> None:
        if tick.done is not None:  # 0: the store is open (its lock held); then the episodes committed so far
            log.write(f"{tick.done}\n")

    config = CollectConfig(task=TASK, episodes=int(args["episodes"]), seed=0)
    try:
        collect_scripted(config, args["out"], workers=int(args["workers"]), append=bool(args["append"]), progress=logged)
    except DemoError as exc:
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(1)
    except OSError as exc:
        print(f"error: OSError: {exc}", file=sys.stderr)
        sys.exit(1)


def _finished(log: Path) -> int:
    lines = log.read_text().split() if log.exists() else []
    return int(lines[-1]) if lines else 0


# ------------------------------------------------------------------------------------------ checks
def inspect(path: Path, finished: int) -> dict[str, Any]:
    """Whether the store at ``path`` holds its ``finished`` first episodes intact: readable, lost, problem."""
    expected = [start_seed(CollectConfig(task=TASK, seed=0), i) for i in range(finished)]
    if not path.exists():
        return {"readable": None if finished == 0 else False, "stored": 0, "lost": finished,
                "problem": None if finished == 0 else "no store"}
    try:
        with EpisodeStore.open(path) as store:
            problems = store.verify()
            stored = store.num_episodes
            seeds = store.column("seed").tolist() if stored else []
    except DemoError as exc:
        return {"readable": False, "stored": 0, "lost": finished, "problem": str(exc)}
    intact = 0
    while intact < min(stored, finished) and seeds[intact] == expected[intact]:
        intact += 1
    if problems:
        intact = 0
    return {"readable": not problems, "stored": stored, "lost": finished - intact,
            "problem": problems[0] if problems else None}


def _one_line_error(stderr: str) -> bool:
    lines = [line for line in stderr.strip().splitlines() if line.strip()]
    return len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in stderr


# ------------------------------------------------------------------------------------------ processes
def _spawn(argv: list[str], err: Path) -> subprocess.Popen:
    # Its own process group, so that one SIGKILL takes the writer and its simulation workers at once.
    with open(err, "w") as f:
        return subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=f, start_new_session=True)


def _collector(out: Path, work: Path, name: str, cfg: FaultsConfig, append: bool = False,
               fsize: int = 0) -> tuple[subprocess.Popen, Path, Path]:
    log, err = work / f"{name}.log", work / f"{name}.err"
    args = {"out": str(out), "log": str(log), "episodes": cfg.episodes, "workers": cfg.workers, "append": append,
            "fsize": fsize}
    return _spawn([sys.executable, "-c", CHILD, json.dumps(args)], err), log, err


def _wait(ready: Callable[[], bool], proc: subprocess.Popen, seconds: float = 120) -> None:
    """Until ``ready()``, ``proc`` exits or ``seconds`` pass (the trial then reports what it finds)."""
    deadline = time.time() + seconds
    while not ready() and proc.poll() is None and time.time() < deadline:
        time.sleep(0.02)


def _kill(proc: subprocess.Popen) -> bool:
    """SIGKILL ``proc``'s process group; False when it had already exited."""
    if proc.poll() is not None:
        return False
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    return True


def _demo(argv: list[str], timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "demo", *argv], capture_output=True, text=True, timeout=timeout)


# ------------------------------------------------------------------------------------------ scenarios
def kill_trial(work: Path, cfg: FaultsConfig, rng: random.Random, base: Path | None, i: int) -> dict[str, Any]:
    """One collection (or, with ``base``, an append to a copy of it) killed at a random time."""
    out = work / f"kill{i}.zarr"
    before = 0
    if base is not None:
        shutil.copytree(base, out)
        before = BASE_EPISODES
    at = rng.uniform(0.0, cfg.max_kill_s)
    proc, log, err = _collector(out, work, f"kill{i}", cfg, append=base is not None)
    if base is not None:  # an append is killed while appending, not while starting up
        _wait(lambda: log.exists(), proc)
    time.sleep(at)
    killed = _kill(proc)
    finished = before + _finished(log)
    result = {"kill_at_s": round(at, 3), "killed": killed, "finished": finished, **inspect(out, finished)}
    if not killed and proc.returncode != 0:  # it failed by itself: a bug, not a survived kill
        result["problem"] = f"exited {proc.returncode} before the kill: {err.read_text().strip()[-300:]}"
    return result


def race_trial(work: Path, cfg: FaultsConfig, rng: random.Random, sources: dict[str, Path], i: int) -> dict[str, Any]:
    """An append in progress, an ``--overwrite`` of its store by another command, then a kill."""
    out = work / f"race{i}.zarr"
    shutil.copytree(sources["store"], out)
    kind = ("collect", "convert", "import")[i % 3]
    argv = {
        "collect": ["collect", "--task", TASK, "--episodes", "5", "--seed", "99", "--workers", "0"],
        "convert": ["convert", str(sources["store"]), "--to", "ee7"],
        "import": ["import", str(sources["lerobot"])],
    }[kind] + ["--out", str(out), "--overwrite"]
    proc, log, _ = _collector(out, work, f"race{i}", cfg, append=True)
    _wait(lambda: _finished(log) > 0, proc)  # the appender holds the store and has committed: now overwrite it
    other = _demo(argv)
    time.sleep(rng.uniform(0.0, 2.0))
    killed = _kill(proc)
    finished = BASE_EPISODES + _finished(log)
    refused = other.returncode != 0 and _one_line_error(other.stderr) and "being written by another process" in other.stderr
    return {"overwrite_by": kind, "overwrite_rc": other.returncode, "overwrite_stderr": other.stderr.strip()[-300:],
            "refused_in_one_line": refused, "appender_pid": proc.pid, "killed": killed, "finished": finished,
            **inspect(out, finished)}


def create_trial(work: Path, cfg: FaultsConfig, i: int) -> dict[str, Any]:
    """``CREATORS`` ``demo collect`` processes released at the same moment onto one new store."""
    out, go = work / f"create{i}.zarr", work / f"go{i}"
    argv = ["collect", "--task", TASK, "--episodes", "3", "--workers", "0", "--seed", "0", "--out", str(out)]
    procs, errs = [], []
    for k in range(CREATORS):
        ready, err = work / f"ready{i}_{k}", work / f"create{i}_{k}.err"
        procs.append((_spawn([sys.executable, "-c", CREATOR, str(go), str(ready), *argv], err), ready))
        errs.append(err)
    deadline = time.time() + 120
    while not all(r.exists() for _, r in procs) and time.time() < deadline:
        time.sleep(0.01)
    go.touch()
    codes = [p.wait(timeout=300) for p, _ in procs]
    stderr = [e.read_text() for e in errs]
    winners = sum(c == 0 for c in codes)
    clean = all(_one_line_error(s) for c, s in zip(codes, stderr) if c != 0)
    finished = 3 if winners else 0
    return {"winners": winners, "losers_one_line": clean, "exit_codes": codes,
            "loser_errors": [s.strip()[-200:] for c, s in zip(codes, stderr) if c != 0], "finished": finished,
            **inspect(out, finished), **({"problem": f"{winners} winners"} if winners != 1 else {})}


def disk_trial(work: Path, cfg: FaultsConfig) -> dict[str, Any]:
    """A collection into a small filesystem until a write fails."""
    disk = work / "disk"
    disk.mkdir()
    mounted = _mount_tmpfs(disk, cfg.disk_mib)
    try:
        out = disk / "full.zarr"
        proc, log, err = _collector(out, work, "disk", cfg, fsize=0 if mounted else FSIZE_LIMIT)
        try:
            rc = proc.wait(timeout=600)
        except subprocess.TimeoutExpired:
            rc = None
            _kill(proc)
        finished = _finished(log)
        result = {"disk": f"tmpfs {cfg.disk_mib} MiB" if mounted else f"RLIMIT_FSIZE {FSIZE_LIMIT // 1024} KiB per file",
                  "rc": rc, "error": err.read_text().strip()[-300:], "one_line": _one_line_error(err.read_text()),
                  "finished": finished, **inspect(out, finished)}
    finally:
        if mounted:
            subprocess.run(["umount", str(disk)], check=False)
    return result


def _mount_tmpfs(where: Path, mib: int) -> bool:
    if os.geteuid() != 0 or shutil.which("mount") is None:
        return False
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={mib}m", "tmpfs", str(where)], capture_output=True)
    return done.returncode == 0


# ------------------------------------------------------------------------------------------ the run
def run(cfg: FaultsConfig, progress: Progress | None = None) -> dict[str, Any]:
    """Every scenario; ``finished_lost`` must be 0 (see the module docstring)."""
    report = or_silent(progress)
    rng = random.Random(cfg.seed)
    started = time.perf_counter()
    scenarios: dict[str, list[dict[str, Any]]] = {}
    with tempfile.TemporaryDirectory(prefix="demo-faults-") as tmp:
        work = Path(tmp)
        sources = _sources(work) if cfg.append_kills or cfg.races else {}

        def repeat(name: str, n: int, trial: Callable[[int], dict[str, Any]]) -> None:
            scenarios[name] = []
            for i in range(n):
                report(Tick(f"bench faults: {name}", i, n))
                scenarios[name].append(trial(i))
            report(Tick(f"bench faults: {name}", n, n))

        repeat("sigkill collect", cfg.kills, lambda i: kill_trial(work, cfg, rng, None, i))
        repeat("sigkill append", cfg.append_kills, lambda i: kill_trial(work, cfg, rng, sources["store"], 100 + i))
        repeat("overwrite race", cfg.races, lambda i: race_trial(work, cfg, rng, sources, i))
        repeat("concurrent create", cfg.creates, lambda i: create_trial(work, cfg, i))
        repeat("full disk", 1, lambda i: disk_trial(work, cfg))
    rows = [_summary(name, trials) for name, trials in scenarios.items()]
    lost = sum(r["finished_lost"] for r in rows)
    return {"task": TASK, "config": asdict(cfg), "scenarios": rows, "trials": scenarios, "finished_lost": lost,
            "ok": lost == 0 and all(r["checks_failed"] == 0 for r in rows), "seconds": time.perf_counter() - started,
            "machine": machine()}


def _sources(work: Path) -> dict[str, Path]:
    """The 20-episode store appends and races start from, and its LeRobot export (for ``demo import``)."""
    from demo.interop import export_lerobot  # deferred: av (PyAV) stays out of the collecting children

    store = work / "base.zarr"
    collect_scripted(CollectConfig(task=TASK, episodes=BASE_EPISODES, seed=0), store, workers=0)
    export_lerobot(store, work / "base_lerobot")
    return {"store": store, "lerobot": work / "base_lerobot"}


def _summary(name: str, trials: list[dict[str, Any]]) -> dict[str, Any]:
    """One table row: trials, stores readable (of those that should exist), finished episodes lost, checks."""
    checks = {"overwrite race": "refused_in_one_line", "concurrent create": "losers_one_line"}.get(name)
    failed = sum(1 for t in trials if checks and not t[checks]) + sum(1 for t in trials if t.get("problem"))
    return {
        "scenario": name,
        "trials": len(trials),
        "stores_readable": sum(t["readable"] is True for t in trials),
        "no_store_nothing_finished": sum(t["readable"] is None for t in trials),
        "finished_episodes": sum(t["finished"] for t in trials),
        "finished_lost": sum(t["lost"] for t in trials),
        "checks_failed": failed,
    }
