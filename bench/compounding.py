"""The compounding-errors experiment: success against horizon for BC, DAgger and BC with chunking.

On ``stack`` with ``blocks`` = N (horizon ``60 + 100 N`` control steps), for each N:

1. collect a pool of scripted demonstrations (``demo collect``'s library, seed ``seed``);
2. **DAgger**: round 0 on the first ``demos`` of them, then ``rounds`` x ``episodes_per_round``
   learner rollouts labelled by the expert (:mod:`demo.train.dagger`). By default HG-DAgger
   (``gate = "deviation:0.05"``): the learner drives, the expert takes over where it strays and only
   those frames become labels. Plain DAgger (``gate = None``) labels every visited state and mixes
   in the expert by ``beta`` (``"linear:4"``: the expert's action is executed with probability 0.75,
   0.5, 0.25 in rounds 1-3, then the learner drives alone). Its expert-label count ``L``
   (demonstration frames + labelled rollout frames) is the budget;
3. **BC**: the same network and optimiser on the first ``k`` pooled demonstrations, ``k`` the
   smallest number whose frames reach ``L`` (equal expert-label budget);
4. **BC + chunking**: the same ``k`` demonstrations, action chunks of ``chunk`` with temporal
   ensembling (ACT);
5. every policy evaluated with :func:`demo.train.evaluate.evaluate` (``demo eval``) on
   ``eval_episodes`` episodes, seeds disjoint from all training data.

Why HG-DAgger, 20 rounds and a 512x512x512 MLP: plain DAgger labels every visited state, so its
budget buys BC many demonstrations and the two end up level (N = 1, 256x256, 6 rounds: BC 81%,
DAgger 83% at 9,733 labels). HG-DAgger spends labels only where the learner needs them; at N = 1 it
reached 58% after 6 rounds with a 256x256 MLP (BC 39% at its 3,318 labels), 89% after 12 rounds
with 512x512x512 (BC 63%), 90% after 20 (BC 62%, 4,032 labels).

Why the mixing schedule of plain DAgger: with ``beta = "indicator"`` (the learner drives from round 1) the early
learners, trained on a few demonstrations, stall in every rollout (a fixed point of the learned
policy above the cube) and each round adds ~100 copies of a stalled state per episode; on
``stack`` N = 1 (30 demonstrations, 4 x 20 rollouts) the learner's own rollouts stayed at 0-5% in
every round. With ``linear:4`` the rollouts move through the whole task while still visiting the
learner's states: 85% of the learner-only rollouts of round 4 succeeded.

Every method executes the gripper as a binary open/closed command (``binary_gripper``): a regressed
0.07 leaves the fingers slightly closed, which the policy then reads as "closing, hold still"
(BC on N = 1 at DAgger's label budget: 30% without it (186 demonstrations), 81% with it (164), 100
episodes each).

Run with ``demo bench compounding``; it writes one JSON
(every number and the exact configuration) and a PNG (success with 95% intervals against horizon).
Each method's run directory is kept under ``out`` for ``demo eval`` and inspection.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from demo.errors import DemoError
from demo.store import EpisodeStore
from demo.train.config import TrainConfig, for_policy


@dataclass
class CompoundingConfig:
    out: str = "compounding"
    task: str = "stack"
    blocks: tuple[int, ...] = (1, 2)
    seed: int = 0
    demos: int = 30  # DAgger's initial demonstrations
    pool: int = 200  # demonstrations collected per N at first (extended when BC's budget needs more)
    rounds: int = 20
    episodes_per_round: int = 20
    beta: str = "linear:4"  # plain DAgger's expert-mixing schedule (see the module docstring)
    gate: str | None = "deviation:0.05"  # HG-DAgger; None = plain DAgger with the beta schedule
    steps: int = 4000  # optimiser steps of BC (and of DAgger's round 0)
    round_steps: int = 4000
    hidden: tuple[int, ...] = (512, 512, 512)
    batch_size: int = 256
    chunk: int = 16  # the chunked BC line
    binary_gripper: bool = True  # every method executes the gripper as open/closed (see demo.train.actor.ExecConfig.binary)
    eval_episodes: int = 100
    workers: int = 1  # collection and evaluation processes
    methods: tuple[str, ...] = ("bc", "dagger", "bc_chunk")
    extra: dict[str, Any] = field(default_factory=dict)


def _train_config(c: CompoundingConfig, data: Path, out: Path, chunk: int = 1) -> TrainConfig:
    """Every method's learner: the same MLP and optimiser; single-step unless ``chunk`` (then ensembled)."""
    return for_policy("bc", data=str(data), out=str(out), seed=c.seed, steps=c.steps, batch_size=c.batch_size,
                      policy={"hidden": c.hidden}, binary_gripper=c.binary_gripper, chunk=chunk, ensemble=chunk > 1)


def _subset(pool: EpisodeStore, path: Path, n: int) -> Path:
    if not path.exists():
        pool.copy_to(path, episodes=np.arange(n), provenance={"op": "subset", "first_episodes": n}).close()
    return path


def _episodes_for_budget(pool: EpisodeStore, labels: int) -> int:
    """The fewest leading pool episodes whose frames reach ``labels``."""
    cumulative = np.cumsum(pool.episode_lengths)
    k = int(np.searchsorted(cumulative, labels) + 1)
    if k > pool.num_episodes:
        raise ValueError(f"the pool of {pool.num_episodes} demos holds {cumulative[-1]} frames < budget {labels}; raise --pool")
    return k


# What a size's cached stores and runs depend on; reruns with other values need another --out.
_CACHE_KEYS = ("task", "seed", "demos", "pool", "rounds", "episodes_per_round", "beta", "gate", "steps", "round_steps",
               "hidden", "batch_size", "chunk", "binary_gripper", "eval_episodes")


def _check_cached_configuration(d: Path, c: CompoundingConfig) -> None:
    """Reuse ``d`` only if it was made with this configuration (written on first use)."""
    from demo.train.checkpoint import read_json, write_json

    path = d / "configuration.json"
    mine = json.loads(json.dumps({k: getattr(c, k) for k in _CACHE_KEYS}))
    if path.exists():
        theirs = read_json(path)
        differ = sorted(k for k in _CACHE_KEYS if theirs.get(k) != mine[k])
        if differ:
            raise DemoError(d, f"holds runs made with other {', '.join(differ)}; choose another --out")
    else:
        write_json(path, mine)


def run(c: CompoundingConfig, log: Callable[[str], None] = print) -> dict[str, Any]:
    # Imported here so that `demo --help`, which shows CompoundingConfig's defaults, stays light.
    from demo.collect.scripted import CollectConfig, collect_scripted
    from demo.train.bc import train
    from demo.train.checkpoint import POLICY_FILE, RUN_FILE, read_json, read_run, write_json
    from demo.train.dagger import DaggerConfig, train_dagger
    from demo.train.evaluate import EvalConfig, evaluate
    from demo.train.plots import plot_success_vs

    out = Path(c.out)
    out.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    started = time.perf_counter()
    for n in c.blocks:
        d = out / f"{c.task}{n}"
        d.mkdir(exist_ok=True)
        _check_cached_configuration(d, c)
        pool_path = d / "pool.zarr"
        if not pool_path.exists():
            log(f"[blocks {n}] collecting {c.pool} demonstrations")
            collect_scripted(CollectConfig(task=c.task, episodes=c.pool, seed=c.seed, task_options={"blocks": n}),
                             pool_path, workers=c.workers if c.workers > 1 else 0)
        pool = EpisodeStore.open(pool_path)
        horizon = int((pool.meta.task or {}).get("horizon", 0))
        entry: dict[str, Any] = {"blocks": n, "horizon": horizon, "expert_success": float(pool.column("success").mean())}

        # ---- DAgger sets the label budget
        dagger_run = d / "dagger"
        if not (dagger_run / RUN_FILE).exists() or "final" not in _metrics(dagger_run):
            log(f"[blocks {n}] DAgger: {c.demos} demos + {c.rounds} x {c.episodes_per_round} rollouts")
            demos = _subset(pool, d / f"demos{c.demos}.zarr", c.demos)
            tc = _train_config(c, demos, dagger_run)
            train_dagger(DaggerConfig(train=tc, rounds=c.rounds, episodes_per_round=c.episodes_per_round,
                                      round_steps=c.round_steps, beta=c.beta, gate=c.gate), overwrite=True)
        budget = int(_metrics(dagger_run)["final"]["expert_labels"])
        while int(pool.episode_lengths.sum()) < budget:
            pool.close()
            more = max(50, c.pool // 2)
            log(f"[blocks {n}] collecting {more} more demonstrations for BC's budget of {budget} labels")
            collect_scripted(CollectConfig(task=c.task, episodes=more, seed=c.seed, task_options={"blocks": n}),
                             pool_path, workers=c.workers if c.workers > 1 else 0, append=True)
            pool = EpisodeStore.open(pool_path)
        k = _episodes_for_budget(pool, budget)
        entry["expert_labels"] = budget
        entry["bc_demos"] = k
        bc_data = _subset(pool, d / f"demos{k}.zarr", k)
        runs = {"dagger": dagger_run}
        if "bc" in c.methods:
            runs["bc"] = d / "bc"
            if not (runs["bc"] / POLICY_FILE).exists():
                log(f"[blocks {n}] BC on {k} demos ({budget} labels)")
                train(_train_config(c, bc_data, runs["bc"]), overwrite=True)
        if "bc_chunk" in c.methods:
            runs["bc_chunk"] = d / f"bc_chunk{c.chunk}"
            if not (runs["bc_chunk"] / POLICY_FILE).exists():
                log(f"[blocks {n}] BC + chunking ({c.chunk}) on {k} demos")
                train(_train_config(c, bc_data, runs["bc_chunk"], chunk=c.chunk), overwrite=True)
        pool.close()
        for method, run_dir in runs.items():
            if method not in c.methods:
                continue
            result_path = run_dir / "eval.json"
            if result_path.exists():
                result = read_json(result_path)
            else:
                log(f"[blocks {n}] evaluating {method} on {c.eval_episodes} episodes")
                result = evaluate(EvalConfig(run=str(run_dir), episodes=c.eval_episodes, seed=c.seed, workers=c.workers))
                result.pop("episodes_detail", None)
                write_json(result_path, result)
            labels = int(read_run(run_dir)["data"]["expert_labels"])
            entry[method] = {k2: result[k2] for k2 in ("success_rate", "ci95", "successes", "episodes", "mean_length", "failures")}
            entry[method]["expert_labels"] = labels
            entry[method]["run"] = str(run_dir)
            log(f"[blocks {n}] {method}: {result['success_rate']:.0%} ({labels} labels)")
        rows.append(entry)
    dagger_name = f"HG-DAgger ({c.gate})" if c.gate else f"DAgger (beta {c.beta})"
    lines = {name: [{"horizon": r["horizon"], "blocks": f"N={r['blocks']}", **r[m]} for r in rows if m in r]
             for m, name in (("bc", "BC"), ("dagger", dagger_name), ("bc_chunk", f"BC + chunking ({c.chunk})"))}
    png = plot_success_vs(lines, out / "compounding.png", title=f"{c.task}: success vs horizon at equal expert labels",
                          annotate="blocks")
    return {
        "experiment": "compounding",
        "config": {**asdict(c), "blocks": list(c.blocks), "hidden": list(c.hidden), "methods": list(c.methods)},
        "rows": rows,
        "png": str(png),
        "seconds": time.perf_counter() - started,
        "target": "DAgger >= 90% where BC is at least 25 points lower",
        "meets_target": any(
            r.get("dagger", {}).get("success_rate", 0) >= 0.9
            and r["dagger"]["success_rate"] - r.get("bc", {}).get("success_rate", 1) >= 0.25
            for r in rows
        ),
    }


def _metrics(run_dir: Path) -> dict[str, Any]:
    from demo.train.checkpoint import METRICS_FILE, read_json

    path = run_dir / METRICS_FILE
    return read_json(path) if path.exists() else {}


def format_table(result: dict[str, Any]) -> str:
    lines = ["blocks  horizon  labels   BC              DAgger          BC+chunk"]
    for r in result["rows"]:
        cells = []
        for m in ("bc", "dagger", "bc_chunk"):
            e = r.get(m)
            cells.append(f"{e['success_rate']:.0%} [{e['ci95'][0]:.0%},{e['ci95'][1]:.0%}]" if e else "-")
        lines.append(f"{r['blocks']:<7} {r['horizon']:<8} {r['expert_labels']:<8} " + "  ".join(f"{c:<15}" for c in cells))
    return "\n".join(lines)

