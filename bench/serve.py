"""`demo bench serve`: the policy server's latency and throughput on CPU, against the policy's own inference.

For each policy (``bc``, ``act`` and ``diffusion`` by default): a run trained for a few steps on a small
``pick`` store collected here (latency does not depend on the weights' values; ``--run`` times trained
runs instead), served by ``demo serve``'s :class:`~demo.deploy.server.PolicyServer` on loopback.

Figure: the round trip one client sees, observation sent to chunk received (msgpack encoding, the
WebSocket both ways, the server's checks, the inference, the answer), as median, p90 and p99 (ms), and
the queries per second it sustains; then the queries per second of ``clients`` clients at once (the
server runs one inference at a time, so this shows what the protocol adds when the server is never
idle). Reference, same run, same process, interleaved with the figure turn by turn: the same actor's
``chunk(frame)`` in-process, the inference alone. ``overhead_ms`` = median round trip - median
inference; ``ratio`` = median inference / median round trip (1.0: the server costs nothing).
"""

from __future__ import annotations

import contextlib
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from websockets.sync.client import connect

from demo.bench.common import interleaved_ms, machine
from demo.deploy.protocol import decode, encode, pack_array
from demo.deploy.server import PolicyServer, ServerConfig
from demo.errors import DemoError
from demo.policies.checkpoint import load_bundle
from demo.progress import Progress, Tick, or_silent

POLICIES = ("bc", "act", "diffusion")
TRAIN_STEPS = 20  # a few steps: a run directory with the policy's default network
BLOCK = 5  # calls per turn, the first of each untimed (demo.bench.common.interleaved_ms)
MIN_ROUNDS = 13  # at least 52 timed calls each


@dataclass
class ServeBenchConfig:
    policies: tuple[str, ...] = POLICIES
    runs: tuple[str, ...] = ()  # trained runs to time instead (their own policies)
    seconds: float = 10.0  # per policy, figure and reference interleaved
    clients: int = 4  # at once, for the throughput under load
    seed: int = 0


def run(config: ServeBenchConfig, progress: Progress | None = None) -> dict[str, Any]:
    """Latency percentiles and throughput of the server per policy, with the in-process inference as reference."""
    if config.clients < 1:
        raise DemoError("--clients", "must be at least 1")
    if config.seconds <= 0:
        raise DemoError("--seconds", "must be positive")
    tell = or_silent(progress)
    with tempfile.TemporaryDirectory(prefix="demo-bench-serve-") as tmp:
        runs = list(config.runs) or _train_runs(Path(tmp), config.policies, config.seed)
        results = []
        for i, path in enumerate(runs):
            results.append(_measure(path, config))
            tell(Tick("bench serve", i + 1, len(runs), {"policy": results[-1]["policy"]}))
    return {"seconds_per_policy": config.seconds, "clients": config.clients, "results": results, "machine": machine()}


def _train_runs(folder: Path, policies: tuple[str, ...], seed: int) -> list[str]:
    """One run per policy, a few training steps each on 6 ``pick`` demonstrations (state observations)."""
    from demo.algorithms import train
    from demo.collect.scripted import CollectConfig, collect_scripted
    from demo.training.config import for_policy

    data = folder / "pick.zarr"
    collect_scripted(CollectConfig(task="pick", episodes=6, seed=seed), data, workers=0)
    runs = []
    for name in policies:
        out = folder / name
        train(name, for_policy(name, data=str(data), out=str(out), steps=TRAIN_STEPS, seed=seed))
        runs.append(str(out))
    return runs


def _frame(bundle: Any, seed: int) -> dict[str, np.ndarray]:
    """The observation a robot of the run's task sends at its first step."""
    from demo.sim import make_env

    trained = bundle.run["task"]
    env = make_env(trained["name"], **dict(trained.get("options") or {}))
    try:
        return env.reset(seed)
    finally:
        env.close()


def _measure(run_path: str, config: ServeBenchConfig) -> dict[str, Any]:
    bundle = load_bundle(run_path)
    frame = _frame(bundle, config.seed)
    message = encode({"type": "obs", "seq": 0, "t_obs": 0.0, "frame": {k: pack_array(np.asarray(v)) for k, v in frame.items()}})
    local = bundle.actor()
    local.reset(config.seed)
    torch.set_num_threads(1)  # as demo serve and demo eval run a policy
    server = PolicyServer(ServerConfig(run_path, port=0)).start()
    try:
        with connect(server.url, max_size=2**26) as ws:
            ws.send(encode({"type": "reset", "seed": config.seed}))
            decode(ws.recv())

            def round_trip() -> None:
                ws.send(message)
                answer = decode(ws.recv())
                if answer["type"] != "chunk":
                    raise DemoError(run_path, f"the server answered {answer}")

            def inference() -> None:
                with torch.inference_mode():
                    local.chunk(frame)

            times = {name: _percentiles(ms) for name, ms in interleaved_ms(
                {"round_trip": round_trip, "inference": inference}, config.seconds, MIN_ROUNDS, BLOCK).items()}
        loaded = _under_load(server.url, message, config.clients, min(config.seconds, 5.0), config.seed)
    finally:
        server.close()
    rt, inf = times["round_trip"], times["inference"]
    return {
        "run": run_path, "policy": bundle.algo, "message_bytes": len(message),
        "round_trip_ms": rt, "inference_ms": inf,
        "queries_per_s": 1000.0 / rt["median"], "queries_per_s_under_load": loaded,
        "overhead_ms": rt["median"] - inf["median"], "ratio": inf["median"] / rt["median"],
    }


def _percentiles(ms: np.ndarray) -> dict[str, float]:
    return {"median": float(np.median(ms)), "p90": float(np.percentile(ms, 90)), "p99": float(np.percentile(ms, 99)),
            "min": float(ms.min()), "calls": int(len(ms))}


def _under_load(url: str, message: bytes, clients: int, seconds: float, seed: int) -> float:
    """Queries per second answered to ``clients`` clients sending back to back for ``seconds``, counted from the
    moment every one of them is connected."""
    counts = [0] * clients
    errors: list[str] = []
    connected = threading.Barrier(clients + 1)
    stop = threading.Event()

    def client(i: int) -> None:
        try:
            with connect(url, max_size=2**26) as ws:
                ws.send(encode({"type": "reset", "seed": seed + i}))
                decode(ws.recv())
                connected.wait()
                while not stop.is_set():
                    ws.send(message)
                    decode(ws.recv())
                    counts[i] += 1
        except Exception as exc:  # noqa: BLE001 - reported after the threads join
            errors.append(str(exc))
            connected.abort()

    threads = [threading.Thread(target=client, args=(i,), daemon=True) for i in range(clients)]
    for t in threads:
        t.start()
    with contextlib.suppress(threading.BrokenBarrierError):  # a client failed: reported below
        connected.wait()
    start = time.perf_counter()
    stop.wait(seconds)
    stop.set()
    for t in threads:
        t.join()
    if errors:
        raise DemoError(url, f"a benchmark client failed: {errors[0]}")
    return sum(counts) / (time.perf_counter() - start)
