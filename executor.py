"""Run jobs on workers and get their results back in job order: what ``--workers`` and
``--executor process|ray`` choose.

Each worker calls ``init(*init_args)`` once (it builds its simulator, policy, ... into module-level
state of the caller's module), then ``run(job)`` per job. Callers give jobs whose result is a pure
function of the job (an episode index or seed, and the fixed ``init_args``), so which worker runs a
job, and how often, changes nothing: results come back in job order and the single writer in this
process commits the same bytes whatever the executor and the number of workers.

- ``process``: ``workers`` processes of this machine, started with ``spawn`` (no inherited
  MuJoCo/GL/torch state; the same behaviour on every OS). Ctrl-C (SIGINT to the process group) and
  SIGTERM interrupt this process: the workers ignore SIGINT and are ended quietly, and what the
  caller committed stays; a worker whose parent was killed outright ends quietly too. A worker that
  dies (killed for memory, say) ends the map with a one-line error naming its job.
- ``ray``: ``workers`` Ray actors (one CPU each) on the Ray cluster at ``address``, else on a local
  one started here with ``workers`` CPUs, reachable from this machine alone (127.0.0.1), and shut
  down afterwards. An actor that dies mid-job (its process killed, its node lost) is replaced and
  the jobs it held are run again, each at most ``retries`` more times; nothing of a job is
  committed before its whole result is back, so a failure never leaves half an episode. Ray is an
  optional dependency (``pip install -e '.[ray]'``), imported only on this path. On a remote
  cluster the workers need ``demo`` installed and the files ``init`` reads (a robot config, a run
  directory) at the same paths.

An exception raised by ``init`` or ``run`` (a :class:`~demo.errors.DemoError`, say) is raised again
in this process as itself; a job that fails that way is never retried.
"""

from __future__ import annotations

import ctypes
import logging
import multiprocessing as mp
import multiprocessing.connection
import os
import signal
import sys
import threading
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass, replace
from typing import Any

from demo import interrupts
from demo.errors import DemoError

KINDS = ("process", "ray")
RAY_INSTALL = "Ray is not installed: pip install -e '.[ray]' (or pip install 'ray>=2.40')"
LOOPBACK = "127.0.0.1"  # where a local Ray started here listens
IN_FLIGHT = 2  # jobs queued per worker or Ray actor: the next one is there when the current one ends
PR_SET_PDEATHSIG = 1  # Linux prctl(2): the signal a process gets when its parent dies
LOOKAHEAD = 32  # at most this many jobs (or 4 per worker) run ahead of the next result to commit


@dataclass(frozen=True)
class ExecutorConfig:
    """Where jobs run. ``workers``: processes (``process``; 0 lets a caller run them itself) or actors
    (``ray``); ``address``: a Ray cluster (None: a local one); ``retries``: re-runs of a job whose Ray
    actor died; ``gpus_per_worker``: GPUs each Ray actor reserves (a fraction shares one)."""

    kind: str = "process"
    workers: int = 1
    address: str | None = None
    retries: int = 2
    gpus_per_worker: float = 0.0

    def check(self) -> None:
        """Refuse a setting that cannot run (Ray missing included), before anything is written."""
        if self.kind not in KINDS:
            raise DemoError("--executor", f"unknown executor {self.kind!r} (choose from {', '.join(KINDS)})")
        if self.address is not None and self.kind != "ray":
            raise DemoError("--address", "names a Ray cluster: use it with --executor ray")
        if self.kind == "ray" and self.workers < 1:
            raise DemoError("--workers", f"--executor ray needs at least 1 worker, got {self.workers}")
        if self.retries < 0:
            raise DemoError("retries", f"must be >= 0, got {self.retries}")
        if self.kind == "ray":
            _import_ray()

    def on_device(self, device: Any) -> "ExecutorConfig":
        """This config for workers whose torch runs on ``device``: Ray actors share the GPUs on CUDA
        (a local Ray gives no GPU to an actor that does not reserve one)."""
        if self.kind == "ray" and str(device).startswith("cuda"):
            return replace(self, gpus_per_worker=1.0 / self.workers)
        return self


def ordered_map(init: Callable[..., None], init_args: Sequence[Any], run: Callable[[Any], Any], jobs: Iterable[Any],
                config: ExecutorConfig, label: Callable[[Any], str] = repr) -> Iterator[list[Any]]:
    """Yield ``run(job)`` for every job, in job order, in lists: each list holds the next result
    (waiting for it) and every result after it already back, so a writer can commit them together.

    ``init``, ``run``, ``init_args``, jobs and results must pickle (module-level functions, plain
    data). ``label(job)`` names a job in the error raised when its Ray worker died too often.
    """
    config.check()
    jobs = list(jobs)
    if not jobs:
        return
    if config.kind == "ray":
        yield from _ray_map(init, init_args, run, jobs, config, label)
    else:
        yield from _process_map(init, init_args, run, jobs, max(1, config.workers), label)


@contextmanager
def session(config: ExecutorConfig) -> Iterator[None]:
    """Keep one Ray connection (and a local Ray) for several :func:`ordered_map` calls, e.g. DAgger's
    rounds; shut down on exit only if it was started here. Does nothing for ``process``."""
    if config.kind != "ray":
        yield
        return
    ray = _import_ray()
    if ray.is_initialized():
        yield
        return
    try:
        local = not config.address
        with _loopback_only() if local else nullcontext():
            ray.init(address=config.address, num_cpus=config.workers if local else None,
                     _node_ip_address=LOOPBACK if local else None, include_dashboard=False, log_to_driver=False,
                     logging_level=logging.ERROR)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        raise DemoError(config.address or "--executor ray", f"cannot start or reach Ray ({_first_line(exc)})") from None
    try:
        yield
    finally:
        ray.shutdown()


@contextmanager
def _loopback_only() -> Iterator[None]:
    """A local Ray started in this block is reachable from this machine alone (its GCS, raylet and
    workers listen on 127.0.0.1), not from the network. On Linux, Ray takes a node's address from its
    default route and its servers then listen on every interface: ``ray.init`` even turns a loopback
    ``_node_ip_address`` into that address, unless it treats the machine as no cluster's (as on
    Windows and macOS, where ``RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER`` is off). That switch is read from
    Ray's constants when the node starts; it is set off for the start only (the node keeps its
    address), so that a later connection to a real cluster is unchanged."""
    try:
        import ray._private.ray_constants as constants  # deferred: optional dependency (ray)
    except ImportError:
        constants = None
    if not hasattr(constants, "ENABLE_RAY_CLUSTER"):  # another Ray: _node_ip_address is all there is
        yield
        return
    previous = constants.ENABLE_RAY_CLUSTER
    constants.ENABLE_RAY_CLUSTER = False
    try:
        yield
    finally:
        constants.ENABLE_RAY_CLUSTER = previous


# ---------------------------------------------------------------------------------- in a worker
_init_error: Exception | None = None  # what this worker's init raised, raised again by each job


def _start(init: Callable[..., None], init_args: Sequence[Any]) -> None:
    """A worker's start: ``init``, keeping its error for the jobs (raised by each, as itself: a Ray
    actor whose constructor raises loses the error's type)."""
    global _init_error
    try:
        init(*init_args)
    except Exception as exc:
        _init_error = exc


def _exit_with_parent() -> None:
    """End this worker, quietly, when its parent is gone (killed outright, it ended no worker):
    sending its next result failed with a BrokenPipeError traceback. On Linux the kernel ends it at
    once (SIGTERM, not handled: no word; it is sent when the parent's thread that started the worker
    ends, and workers are started from the thread that runs the whole map, which outlives them);
    elsewhere, and should that fail, a thread waiting on the parent does, as soon as it runs."""
    parent = mp.parent_process()
    if parent is None:
        return
    if sys.platform.startswith("linux"):
        try:
            ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
        except (OSError, AttributeError):
            pass
    threading.Thread(target=_wait_then_exit, args=(parent,), name="demo-parent-watch", daemon=True).start()


def _wait_then_exit(parent: Any) -> None:
    parent.join()  # returns once the parent process is gone (at once if it already is)
    os._exit(0)


def _worker_main(pipe: Any, init: Callable[..., None], init_args: Sequence[Any], run: Callable[[Any], Any]) -> None:
    """A worker process: ``init``, then ``(i, job)`` from the pipe until ``None`` (or the pipe's end),
    answering each with ``(i, True, result)`` or ``(i, False, exception)``. Ctrl-C reaches the whole
    process group, but only the parent acts on it (it terminates the workers, and SIGTERM ends one
    without a word): a worker interrupted itself printed a traceback."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _exit_with_parent()
    _start(init, init_args)
    while True:
        try:
            message = pipe.recv()
        except (EOFError, OSError):
            return
        if message is None:
            return
        i, job = message
        try:
            answer = (i, True, _call(run, job))
        except Exception as exc:  # noqa: BLE001 - raised again in the parent, as itself
            answer = (i, False, exc)
        try:
            pipe.send(answer)
        except Exception as exc:  # noqa: BLE001 - a result or an exception that does not pickle
            pipe.send((i, False, RuntimeError(f"job {i}: {type(exc).__name__}: {exc}")))


def _call(run: Callable[[Any], Any], job: Any) -> Any:
    if _init_error is not None:
        raise _init_error
    return run(job)


class _RayWorker:
    """The Ray actor: one worker process that runs ``init`` once, then jobs."""

    def __init__(self, spec: tuple[Callable[..., None], Sequence[Any], Callable[[Any], Any]]):
        init, init_args, self._run = spec
        _start(init, init_args)

    def run(self, job: Any) -> Any:
        return _call(self._run, job)


# ---------------------------------------------------------------------------------- process
def _process_map(init: Callable[..., None], init_args: Sequence[Any], run: Callable[[Any], Any], jobs: list[Any],
                 workers: int, label: Callable[[Any], str]) -> Iterator[list[Any]]:
    """Worker processes, each with its own pipe: this process hands each at most :data:`IN_FLIGHT` jobs
    and waits on every pipe and every process at once, so a worker that dies (killed for memory, a
    crash in native code) ends the map with a one-line error naming its job, never a hang.
    (``multiprocessing.Pool`` lost such a worker's job and waited for it forever, and its
    ``terminate`` waits for a lock in the shared task queue that a worker which died holding it
    never releases.)"""
    ctx = mp.get_context("spawn")  # no inherited MuJoCo/GL/torch thread state (nor CUDA)
    procs: list[Any] = []
    pipes: list[Any] = []
    finished = False
    with _terminate_interrupts():
        try:
            # SIGINT ignored while the workers start is inherited through exec (and Python leaves it so):
            # that covers a worker's imports before _worker_main runs. A Ctrl-C in these few
            # milliseconds is lost.
            with _handler(signal.SIGINT, signal.SIG_IGN):
                for _ in range(min(workers, len(jobs))):
                    ours, theirs = ctx.Pipe()
                    proc = ctx.Process(target=_worker_main, args=(theirs, init, tuple(init_args), run), daemon=True,
                                       name="demo-worker")
                    proc.start()
                    theirs.close()  # the worker's end lives in the worker: EOF here once it is gone
                    procs.append(proc)
                    pipes.append(ours)
            held: list[deque[int]] = [deque() for _ in procs]  # per worker: its jobs in flight, oldest first
            done: dict[int, Any] = {}
            submitted = committed = 0
            lookahead = max(LOOKAHEAD, 4 * len(procs))
            while committed < len(jobs):
                while submitted < min(len(jobs), committed + lookahead):
                    slot = min(range(len(procs)), key=lambda s: len(held[s]))
                    if len(held[slot]) >= IN_FLIGHT:
                        break
                    held[slot].append(submitted)
                    pipes[slot].send((submitted, jobs[submitted]))
                    submitted += 1
                for pipe in mp.connection.wait([p for s, p in enumerate(pipes) if held[s]]):
                    slot = pipes.index(pipe)
                    try:
                        i, ok, value = pipe.recv()
                    except (EOFError, OSError):
                        procs[slot].join(timeout=5)
                        raise DemoError(label(jobs[held[slot][0]]),
                                        f"its worker process died ({_exit_reason(procs[slot].exitcode)})") from None
                    if not ok:
                        raise value
                    held[slot].remove(i)
                    done[i] = value
                batch = _next_in_order(done, committed)
                committed += len(batch)
                if batch:
                    yield batch
            finished = True
        finally:
            _stop(procs, pipes, politely=finished)


def _next_in_order(done: dict[int, Any], committed: int) -> list[Any]:
    """The results from job ``committed`` on that are back without a gap, taken out of ``done``."""
    batch = []
    while committed + len(batch) in done:
        batch.append(done.pop(committed + len(batch)))
    return batch


def _stop(procs: list[Any], pipes: list[Any], politely: bool) -> None:
    """End the workers: after the last job, ask them to (each returns normally, running its exit
    handlers); after an error or Ctrl-C, terminate them at once (SIGTERM ends a worker without a word).
    A worker still there 5 s after its SIGTERM is killed, so that ending never hangs."""
    for proc, pipe in zip(procs, pipes):
        if politely:
            try:
                pipe.send(None)
            except OSError:
                pass
        else:
            proc.terminate()
    for proc, pipe in zip(procs, pipes):
        proc.join(timeout=10 if politely else 5)
        if proc.is_alive() and politely:  # asked and still busy: SIGTERM
            proc.terminate()
            proc.join(timeout=5)
        if proc.is_alive():  # not ended by SIGTERM (blocked in native code): SIGKILL
            proc.kill()
            proc.join()
        pipe.close()


def _exit_reason(code: int | None) -> str:
    if code is None:
        return "it closed its pipe"
    if code < 0:
        name = signal.Signals(-code).name if -code in signal.valid_signals() else str(-code)
        return f"killed by {name}" + (": out of memory?" if -code == signal.SIGKILL else "")
    return f"exit code {code}"


@contextmanager
def _handler(signum: int, handler: Any) -> Iterator[None]:
    """``handler`` for ``signum`` while the block runs. Only the main thread may set handlers:
    elsewhere, and where Python does not own the signal (a handler set from C), nothing changes."""
    previous = signal.getsignal(signum)
    if threading.current_thread() is not threading.main_thread() or previous is None:
        yield
        return
    signal.signal(signum, handler)
    try:
        yield
    finally:
        if threading.current_thread() is threading.main_thread():  # a generator may be closed elsewhere
            signal.signal(signum, previous)


@contextmanager
def _terminate_interrupts() -> Iterator[None]:
    """SIGTERM ends this process as Ctrl-C does while worker processes run (unless a handler of its
    own is set): the workers are ended and the caller's committed work kept."""
    if signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL:
        yield
        return
    with _handler(signal.SIGTERM, interrupts.interrupt):
        yield


# ---------------------------------------------------------------------------------- ray
def _import_ray() -> Any:
    try:
        import ray  # deferred: optional dependency (ray)
    except ImportError:
        raise DemoError("--executor ray", RAY_INSTALL) from None
    return ray


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def _ray_map(init: Callable[..., None], init_args: Sequence[Any], run: Callable[[Any], Any], jobs: list[Any],
             config: ExecutorConfig, label: Callable[[Any], str]) -> Iterator[list[Any]]:
    ray = _import_ray()
    from ray.exceptions import NodeDiedError, ObjectLostError, RayActorError, RayTaskError, WorkerCrashedError  # deferred: optional dependency (ray)

    lost = (RayActorError, ObjectLostError, NodeDiedError, WorkerCrashedError)  # the worker, not the job, failed
    with session(config):
        if config.gpus_per_worker:
            have = ray.cluster_resources().get("GPU", 0.0)
            if have < config.gpus_per_worker * config.workers:
                raise DemoError("--device", f"the Ray cluster has {have:g} GPUs; {config.workers} workers on CUDA need "
                                            f"{config.gpus_per_worker * config.workers:g} (or use --device cpu)")
        actor_class = ray.remote(num_cpus=1, num_gpus=config.gpus_per_worker, max_restarts=0)(_RayWorker)
        spec = ray.put((init, tuple(init_args), run))  # stored once, read by every actor (and replacement)
        actors = [actor_class.remote(spec) for _ in range(config.workers)]
        held: list[deque[int]] = [deque() for _ in actors]  # per actor: its jobs in flight, oldest first
        pending: dict[Any, tuple[int, int]] = {}  # object ref -> (job, actor)
        attempts = [0] * len(jobs)
        done: dict[int, Any] = {}
        submitted = committed = 0
        lookahead = max(LOOKAHEAD, 4 * config.workers)

        def submit(slot: int, i: int) -> None:
            pending[actors[slot].run.remote(jobs[i])] = (i, slot)

        def replace_actor(slot: int, exc: BaseException) -> None:
            """The actor died: its oldest job was running (an actor runs its jobs in order); start a new
            actor and give it the same jobs again."""
            for ref in [r for r, (_, s) in pending.items() if s == slot]:
                del pending[ref]
            culprit = held[slot][0]
            attempts[culprit] += 1
            if attempts[culprit] > config.retries:
                raise DemoError(label(jobs[culprit]), f"its Ray worker died {attempts[culprit]} times "
                                                      f"({_first_line(exc)})")
            ray.kill(actors[slot], no_restart=True)
            actors[slot] = actor_class.remote(spec)
            for i in held[slot]:
                submit(slot, i)

        try:
            while committed < len(jobs):
                while submitted < min(len(jobs), committed + lookahead):
                    slot = min(range(len(actors)), key=lambda s: len(held[s]))
                    if len(held[slot]) >= IN_FLIGHT:
                        break
                    held[slot].append(submitted)
                    submit(slot, submitted)
                    submitted += 1
                ray.wait(list(pending), num_returns=1)
                ready, _ = ray.wait(list(pending), num_returns=len(pending), timeout=0)
                died: dict[int, BaseException] = {}
                for ref in ready:
                    i, slot = pending.pop(ref)
                    try:
                        done[i] = ray.get(ref)
                    except RayTaskError as exc:  # run or init raised: the job's own error, as itself
                        cause = exc.cause
                        raise (cause if isinstance(cause, Exception) else exc) from exc
                    except lost as exc:
                        died.setdefault(slot, exc)
                    else:
                        held[slot].remove(i)
                for slot, exc in died.items():
                    replace_actor(slot, exc)
                batch = _next_in_order(done, committed)
                committed += len(batch)
                if batch:
                    yield batch
        finally:
            for actor in actors:
                ray.kill(actor, no_restart=True)
