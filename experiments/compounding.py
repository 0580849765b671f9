"""The compounding-errors experiment: success against horizon for the DAgger family and BC at equal labels.

A task option sets the horizon (``option``; the task's other options fixed by ``task_options``). The
default is ``stack`` with one block, ``repeat`` = K and ``respawn=1``: K whole pick-and-places, the
cube put back on the table and the pad moved after each (horizon ``60 + 100 K`` control steps;
:mod:`demo.sim.stack`), so the horizon grows while the skill per cycle stays the one where HG-DAgger
already reached 90% (below); ``--option blocks`` gives the N-block stacks (``60 + 100 N``). Every
horizon gets the same expert-label budget ``max_labels`` (below). For each of its ``values``:

1. collect a pool of scripted demonstrations (``demo collect``'s library, seed ``seed``);
2. **HG-DAgger** (``hg_dagger``, ``gate = "deviation:0.03"``): round 0 on the first ``demos`` of them,
   then at most ``rounds`` x ``episodes_per_round`` learner rollouts where the expert takes over when
   the learner strays (:mod:`demo.imitation.dagger`), stopping once ``max_labels`` are spent. Its
   expert-label count ``L`` (demonstration frames + the frames the expert controlled) is every
   method's budget;
3. the rest of the family from the same ``demos`` (:func:`demo.imitation.dagger.make_family`), each
   given about ``L`` labels:

   - ``safedagger``: the same rounds, the expert taking over where a learned classifier predicts the
     learner deviates (:mod:`demo.imitation.safedagger`; its labels are what it asked for);
   - ``aggrevate``: the same rounds, ``states`` cost-to-go labels per rollout chosen so that the
     labels reach ``L`` (:mod:`demo.imitation.aggrevate`; its simulator steps are reported);
   - ``dagger`` (plain, every visited state labelled, mixing by ``beta``), ``dart`` (noise estimated
     from the learner, :mod:`demo.imitation.dart`) and ``perturb`` (expert-labelled perturbed states,
     :mod:`demo.imitation.perturb`): every frame they record is a label, so they get the episodes that
     ``L`` pays for at the expert's mean episode length (at least one), over at most ``rounds`` rounds;

   every member stops rolling out once it has spent ``L`` (``max_labels``: it may pass it by the
   rest of one episode);

4. **BC** on the first ``k`` pooled demonstrations, ``k`` the fewest whose frames reach ``L``;
   **BC + chunking** on the same ``k`` (chunks of ``chunk``, temporal ensembling); **DART with fixed
   noise** (``dart_fixed``): BC on the first demonstrations reaching ``L`` of a pool collected with
   ``noise`` rad on the executed joint targets (``demo collect --noise``);
5. every policy evaluated with :func:`demo.evaluation.evaluate.evaluate` (``demo eval``) on
   ``eval_episodes`` episodes, seeds disjoint from all training data;
6. per method, the growth of failure with horizon fitted (:func:`fit_growth`): success
   ``s(H) = s0 exp(-rate H)`` by maximum likelihood over the binomial counts; ``rate`` is the extra
   failure per control step, ``half_horizon`` the horizon at which success halves.

Measured so far (before this file took the whole family; stack, 30 demos, 20 x 20 rollouts,
512x512x512 MLP, 100 eval episodes): N = 1 (horizon 160, 4,032 labels): HG-DAgger 90%, BC 62%,
BC + chunk 62%; N = 2 (horizon 260, 15,060 labels): 14%, 16%, 5%. Plain DAgger labels every visited
state, so its budget buys BC many demonstrations and the two end level (N = 1, 256x256, 6 rounds:
BC 81%, DAgger 83% at 9,733 labels); HG-DAgger spends labels where the learner strays: 58% after 6
rounds (256x256, BC 39% at its 3,318 labels), 89% after 12 (512x512x512, BC 63%), 90% after 20.
A pilot of ``repeat`` K = 1, 2, 3 at a tiny scale (20 demos, 4 x 10 rounds, 1,500 steps, 256x256, 30
eval episodes): HG-DAgger 27%, 40%, 33%, BC 3%, 10%, 10%, BC + chunk 13%, 0%, 0%: the gap holds and
HG-DAgger does not fall with K (its rollouts hold K cycles' worth of corrections), far from 80% at
that scale. At the earlier settings (30 demos, gate 0.05 rad, no respawn, no warm start, no fixed
budget), K = 4 (horizon 460, expert episodes ~121 steps): HG-DAgger 95% (6,069 labels), BC 70% on the
50 demonstrations those labels buy: DAgger holds, but BC's matched budget grows with K too, so the gap
(25 points) does not widen as the issue asks (BC 40 points lower): K = 1 at the same scale: HG-DAgger
94% (4,192 labels), BC 74% (4,242 labels), a 20-point gap.

With ``respawn=1`` (``--task-opt respawn=1``, :mod:`demo.sim.stack`) the cube goes back on the table
after each stack but the last, so every cycle is a whole pick-and-place (expert episodes 59-174 steps
at K = 1-4). K = 1..4 at those earlier settings: HG-DAgger 94, 86, 92, 83%, BC 74, 67, 70, 67%
(4,192-9,392 labels); with ``demos`` = 10: HG-DAgger 89, 88, 91, 85%, BC 60, 67, 62, 54% (3,387-7,408
labels), the fitted failure growth 0.009 against 0.035 per 100 steps. DAgger holds above 80% at the
longest horizon, BC stays 16-31 points lower and the gap does not grow steadily with K: BC's matched
budget buys more whole demonstrations of the one per-cycle skill as K grows. Hence the fixed budget
below.

**A fixed label budget** (``max_labels``): every horizon gets the same ``L`` expert labels, as in Ross &
Bagnell's comparison (the same data, a longer horizon). BC's budget no longer grows with K (83,
63, 45, 35 demonstrations at K = 1-4: 83-140 pick-and-place cycles) and its per-cycle success ``p``
compounds as ``p^K``, while HG-DAgger spends its ``L`` on the states its own learner reaches.
``warm_start`` (each round fine-tunes the previous learner for ``round_steps``) makes a round about
4x cheaper. Pilots at K = 4 with ``respawn=1``, ``L`` = 6,000, warm start, 1,000 steps per round (BC:
35 demonstrations, 42%, CI 33-52%): HG-DAgger with 10 demos and 10, 5, 20 rollouts per round 77, 66,
79%; with 5 demos 77%; with the gate at 0.1 rad the learner's rollouts stayed at 40-65% after 19
rounds (stopped); with the gate at **0.03 rad, 86%** (CI 78-91%, 5 rounds: the tight gate has the
expert take over early in round 1, 2,162 labels, and every later round spends 350-740). Training
from scratch on HG-DAgger's aggregate instead of the warm-started learner: 26%.

At these defaults (K = 1..4, 100 eval episodes each): HG-DAgger 94, 98, 94, 86% against BC 87, 55, 43, 42%
(4,930-6,011 labels; BC on 83, 63, 45, 35 demonstrations): the gap grows from 7 to 44 points, the
fitted failure growth 0.022 against 0.19 per 100 steps. DART with its estimated noise 85, 80, 84, 84%;
fixed-noise DART 77, 71, 49, 47%; BC + chunking 61, 26, 11, 0%; plain DAgger 29, 10, 32, 23%;
SafeDAgger 70, 36, 40, 73%; AggreVaTe 46, 29, 41, 53% (212,117-915,979 simulator steps); perturbation
1, 1, 3, 4%. Only HG-DAgger and estimated-noise DART stay above 80% at every K. At K = 5 the same
budget gives HG-DAgger 61% and BC 23%: a longer horizon needs more labels to hold 80%.

Why the mixing schedule of plain DAgger (``beta = "linear:4"``): with ``indicator`` (the learner drives
from round 1) the early learners, trained on a few demonstrations, stall in every rollout (a fixed
point of the learned policy above the cube) and each round adds ~100 copies of a stalled state per
episode; on ``stack`` N = 1 the learner's own rollouts stayed at 0-5% in every round. With
``linear:4`` the rollouts move through the whole task while still visiting the learner's states.

Every method executes the gripper as a binary open/closed command (``binary_gripper``): a regressed
0.07 leaves the fingers slightly closed, which the policy then reads as "closing, hold still"
(BC on N = 1 at DAgger's label budget: 30% without it, 81% with it, 100 episodes each).

**Chunked learners** (``chunked_learners``, ``--chunked-learners``): every family member trains BC's chunked
learner (``chunk`` steps, temporally ensembled) instead of the single-step one. At the defaults (K = 1..4):
HG-DAgger 64, 20, 11, 1% against chunked BC 75, 26, 11, 0% and single-step BC 88, 55, 43, 42%: the ensembled
action lags the expert's, the 0.03 rad gate fires at nearly every step and the expert drives almost every
rollout, so the budget buys BC's data again (docs/results.md, "With chunked learners"); with the gate at 0.05 rad
78% and 3% at K = 1 and 4 (chunked BC 74% and 0%): the chunked learner itself fails the long horizon here.

Run with ``demo bench compounding``; it writes one JSON (every number, each method's labels and
seconds, the fits, the exact configuration) and a PNG (success with 95% intervals against horizon).
Each method's run directory is kept under ``out`` for ``demo eval`` and inspection; a rerun reuses
every finished stage.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
import json
import math
from pathlib import Path
import time
from typing import Any, Callable

import numpy as np

from demo import algorithms
from demo.collect.scripted import CollectConfig, collect_scripted
from demo.errors import DemoError
from demo.executor import ExecutorConfig
from demo.imitation.config import DaggerConfig
from demo.jsonio import write_json
from demo.store import EpisodeStore
from demo.training.config import TrainConfig, for_policy
from demo.training.plots import plot_success_vs

METHODS = ("bc", "bc_chunk", "dart_fixed", "dart", "perturb", "dagger", "hg_dagger", "safedagger", "aggrevate")
# The family members (demo.imitation.dagger.make_family) and what they are called in the figure.
FAMILY_OF = {"dart": "dart", "perturb": "perturb", "dagger": "dagger", "hg_dagger": "dagger",
             "safedagger": "safedagger", "aggrevate": "aggrevate"}
ALL_LABELLED = ("dart", "perturb", "dagger")  # every frame they record is a label


@dataclass
class CompoundingConfig:
    out: str = "compounding"
    task: str = "stack"
    option: str = "repeat"  # the task option that sets the horizon
    values: tuple[int, ...] = (1, 2, 3, 4)
    task_options: dict[str, Any] = field(default_factory=lambda: {"blocks": 1, "respawn": 1})  # the task's other options, fixed
    seed: int = 0
    demos: int = 10  # the family's initial demonstrations
    pool: int = 200  # demonstrations collected per value at first (extended when a budget needs more)
    rounds: int = 30  # at most: the label budget usually ends the rounds first
    episodes_per_round: int = 20
    beta: str = "linear:4"  # plain DAgger's expert-mixing schedule (see the module docstring)
    gate: str = "deviation:0.03"  # HG-DAgger's gate; SafeDAgger's deviation threshold (0.05: 79%, 0.1: worse; K = 4)
    steps: int = 4000  # optimiser steps of BC (and of every family member's round 0)
    round_steps: int = 1000
    warm_start: bool = True  # every family member fine-tunes its previous learner each round (demo.imitation.dagger)
    max_labels: int | None = 6000  # a fixed expert-label budget for every horizon (HG-DAgger stops there; None: its rounds set it)
    hidden: tuple[int, ...] = (512, 512, 512)
    batch_size: int = 256
    chunk: int = 16  # the chunked BC line (and every family member's learner with chunked_learners)
    chunked_learners: bool = False  # the family's learners chunked (``chunk``, ensembled) like the chunked BC line
    binary_gripper: bool = True  # every method executes the gripper as open/closed (see demo.policies.actor.ExecConfig.binary)
    noise: float = 0.01  # rad: the fixed-noise DART line's noise (demo collect --noise; on stack 0.02 leaves 3/10 expert episodes successful, 0.05 none)
    val_fraction: float = 0.2  # held-out demonstrations: SafeDAgger's classifier and DART's noise are fitted on them
    candidates: int = 3  # AggreVaTe's actions tried per labelled state
    sigma: float = 0.05  # rad: AggreVaTe's exploration noise and perturb's displacement
    eval_episodes: int = 100
    workers: int = 1  # collection, rollout and evaluation processes
    methods: tuple[str, ...] = METHODS
    extra: dict[str, Any] = field(default_factory=dict)

    def check(self) -> None:
        unknown = sorted(set(self.methods) - set(METHODS))
        if unknown:
            raise DemoError("--methods", f"unknown method(s) {', '.join(unknown)} (choose from {', '.join(METHODS)})")
        if len(self.values) < 1 or any(v < 1 for v in self.values):
            raise DemoError("--values", f"needs positive values of {self.option}, got {list(self.values)}")
        if self.max_labels is not None and self.max_labels < 1:
            raise DemoError("--max-labels", f"must be at least 1, got {self.max_labels}")


def _train_config(c: CompoundingConfig, data: Path, out: Path, chunk: int = 1) -> TrainConfig:
    """Every method's learner: the same MLP and optimiser; single-step unless ``chunk`` (then ensembled)."""
    return for_policy("bc", data=str(data), out=str(out), seed=c.seed, steps=c.steps, batch_size=c.batch_size,
                      policy={"hidden": c.hidden}, binary_gripper=c.binary_gripper, chunk=chunk, ensemble=chunk > 1,
                      val_fraction=c.val_fraction)


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


def fit_growth(points: list[tuple[float, int, int]]) -> dict[str, Any]:
    """Maximum-likelihood fit of ``success(H) = s0 exp(-rate H)`` to ``(horizon, successes, episodes)``
    points (a grid over ``s0`` in (0, 1] and ``rate`` in [0, 0.1] per step, then refined about the
    best): ``rate`` is the failure added per control step, ``half_horizon`` the horizon where
    success halves (``ln 2 / rate``; None for no decay)."""
    h = np.array([p[0] for p in points], float)
    k = np.array([p[1] for p in points], float)
    n = np.array([p[2] for p in points], float)
    if not k.sum():  # never a success: any rate fits; there is nothing to say
        return {"model": "success = s0 * exp(-rate * horizon)", "s0": 0.0, "rate_per_step": None, "half_horizon": None}

    def loglik(s0: np.ndarray, rate: np.ndarray) -> np.ndarray:
        p = np.clip(s0[..., None] * np.exp(-rate[..., None] * h), 1e-9, 1 - 1e-9)
        return (k * np.log(p) + (n - k) * np.log(1 - p)).sum(axis=-1)

    s0_grid, rate_grid = np.linspace(0.005, 1.0, 200), np.r_[0.0, np.geomspace(1e-5, 0.1, 300)]
    for _ in range(3):
        s, r = np.meshgrid(s0_grid, rate_grid, indexing="ij")
        i, j = np.unravel_index(np.argmax(loglik(s, r)), s.shape)
        s0, rate = float(s0_grid[i]), float(rate_grid[j])
        s0_grid = np.linspace(max(1e-3, s0 - 0.02), min(1.0, s0 + 0.02), 81)
        rate_grid = np.linspace(max(0.0, rate * 0.8 - 1e-6), rate * 1.2 + 1e-6, 81)
    return {"model": "success = s0 * exp(-rate * horizon)", "s0": s0, "rate_per_step": rate,
            "half_horizon": math.log(2) / rate if rate > 0 else None}


# What a value's cached stores and runs depend on; reruns with other values need another --out.
_CACHE_KEYS = ("task", "option", "task_options", "seed", "demos", "pool", "rounds", "episodes_per_round", "beta", "gate", "steps",
               "round_steps", "warm_start", "max_labels", "hidden", "batch_size", "chunk", "chunked_learners",
               "binary_gripper", "noise",
               "val_fraction", "candidates", "sigma", "eval_episodes")


# What a directory made before these keys existed ran with.
_BEFORE_THE_KEY_EXISTED = {"warm_start": False, "max_labels": None, "chunked_learners": False}


def _check_cached_configuration(d: Path, c: CompoundingConfig) -> None:
    """Reuse ``d`` only if it was made with this configuration (written on first use)."""
    from demo.policies.checkpoint import read_json  # deferred: torch stays out of demo --help

    path = d / "configuration.json"
    mine = json.loads(json.dumps({k: getattr(c, k) for k in _CACHE_KEYS}))
    if path.exists():
        theirs = {**_BEFORE_THE_KEY_EXISTED, **read_json(path)}
        differ = sorted(k for k in _CACHE_KEYS if theirs.get(k) != mine[k])
        if differ:
            raise DemoError(d, f"holds runs made with other {', '.join(differ)}; choose another --out")
    else:
        write_json(path, mine)


class _Value:
    """One value of the horizon option: its pools, its budget and its runs (cached under ``d``)."""

    def __init__(self, c: CompoundingConfig, value: int, log: Callable[[str], None]):
        self.c, self.value, self.log = c, value, log
        self.d = Path(c.out) / f"{c.task}_{c.option}{value}"
        self.d.mkdir(parents=True, exist_ok=True)
        _check_cached_configuration(self.d, c)
        self.options = {**c.task_options, c.option: value}

    def pool(self, name: str = "pool", noise: float = 0.0, frames: int = 0) -> EpisodeStore:
        """The demonstration pool (``noise``: collected with DART noise), grown until it holds ``frames``."""
        c, path = self.c, self.d / f"{name}.zarr"
        config = CollectConfig(task=c.task, episodes=c.pool, seed=c.seed, noise=noise, task_options=self.options)
        workers = c.workers if c.workers > 1 else 0
        if not path.exists():
            self.log(f"[{c.option} {self.value}] collecting {c.pool} demonstrations{f' (noise {noise})' if noise else ''}")
            collect_scripted(config, path, workers=workers)
        pool = EpisodeStore.open(path)
        while int(pool.episode_lengths.sum()) < frames:
            pool.close()
            config.episodes = max(50, c.pool // 2)
            self.log(f"[{c.option} {self.value}] collecting {config.episodes} more demonstrations for a budget of {frames} labels")
            collect_scripted(config, path, workers=workers, append=True)
            pool = EpisodeStore.open(path)
        return pool

    def family(self, method: str, rounds: int, episodes: int, options: dict[str, str], budget: int | None = None) -> Path:
        """A family member's run from the first ``demos`` demonstrations (kept once finished); it stops
        rolling out once it has spent ``budget`` labels."""
        from demo.policies.checkpoint import RUN_FILE  # deferred: torch stays out of demo --help

        c, run_dir = self.c, self.d / method
        if (run_dir / RUN_FILE).exists() and "final" in _metrics(run_dir):
            return run_dir
        self.log(f"[{c.option} {self.value}] {method}: {c.demos} demos + {rounds} x {episodes} rollouts {options or ''}")
        with self.pool() as pool:
            demos = _subset(pool, self.d / f"demos{c.demos}.zarr", c.demos)
        gated = method in ("hg_dagger", "safedagger")
        chunk = c.chunk if c.chunked_learners else 1
        config = DaggerConfig(train=_train_config(c, demos, run_dir, chunk=chunk), rounds=rounds, episodes_per_round=episodes,
                              round_steps=c.round_steps, warm_start=c.warm_start, beta=c.beta,
                              gate=c.gate if gated else None, max_labels=budget)
        algorithms.train(FAMILY_OF[method], config, options=options, overwrite=True,
                         executor=ExecutorConfig("process", c.workers))
        return run_dir

    def bc(self, method: str, budget: int, noise: float = 0.0, chunk: int = 1) -> tuple[Path, int]:
        """BC (``chunk``: chunked) on the fewest leading demonstrations (``noise``: of the noisy pool) reaching ``budget``."""
        from demo.policies.checkpoint import POLICY_FILE  # deferred: torch stays out of demo --help

        name = "noisy_pool" if noise else "pool"
        with self.pool(name, noise, budget) as pool:
            k = _episodes_for_budget(pool, budget)
            data = _subset(pool, self.d / f"{'noisy_' if noise else ''}demos{k}.zarr", k)
        run_dir = self.d / method
        if not (run_dir / POLICY_FILE).exists():
            self.log(f"[{self.c.option} {self.value}] {method} on {k} demos ({budget} labels)")
            algorithms.train("bc", _train_config(self.c, data, run_dir, chunk=chunk), overwrite=True)
        return run_dir, k


def run(c: CompoundingConfig, log: Callable[[str], None] = print) -> dict[str, Any]:
    from demo.evaluation.evaluate import EvalConfig, evaluate  # deferred: torch stays out of demo --help
    from demo.policies.checkpoint import read_json, read_run  # deferred: torch stays out of demo --help

    c.check()
    out = Path(c.out)
    out.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    started = time.perf_counter()
    for value in c.values:
        v = _Value(c, value, log)
        with v.pool() as pool:
            horizon = int((pool.meta.task or {}).get("horizon", 0))
            mean_length = float(pool.episode_lengths.mean())
            entry: dict[str, Any] = {c.option: value, "value": value, "horizon": horizon,
                                     "expert_success": float(pool.column("success").mean()),
                                     "expert_mean_length": mean_length}

        # ---- HG-DAgger sets the label budget; the family gets about as many labels
        runs = {"hg_dagger": v.family("hg_dagger", c.rounds, c.episodes_per_round, {}, c.max_labels)}
        hg = _metrics(runs["hg_dagger"])
        budget = int(hg["final"]["expert_labels"])
        demo_labels = int(hg["rounds"][0]["labels_total"])
        extra = max(0, budget - demo_labels)
        entry.update(expert_labels=budget, demo_labels=demo_labels)
        episodes = max(1, round(extra / mean_length))  # what `extra` buys a member that labels every frame
        rounds = min(c.rounds, episodes)
        for method in c.methods:
            if method in ALL_LABELLED:
                opts = {"sigma": str(c.sigma)} if method == "perturb" else {}
                runs[method] = v.family(method, rounds, math.ceil(episodes / rounds), opts, budget)
            elif method == "safedagger":
                runs[method] = v.family(method, c.rounds, c.episodes_per_round, {}, budget)
            elif method == "aggrevate":
                states = max(1, round(extra / (c.rounds * c.episodes_per_round)))
                opts = {"states": str(states), "candidates": str(c.candidates), "sigma": str(c.sigma)}
                runs[method] = v.family(method, c.rounds, c.episodes_per_round, opts, budget)
            elif method in ("bc", "bc_chunk"):
                runs[method], entry["bc_demos"] = v.bc(method, budget, chunk=c.chunk if method == "bc_chunk" else 1)
            elif method == "dart_fixed":
                runs[method], entry["dart_fixed_demos"] = v.bc(method, budget, noise=c.noise)
        for method, run_dir in runs.items():
            if method not in c.methods:
                continue
            result_path = run_dir / "eval.json"
            if result_path.exists():
                result = read_json(result_path)
            else:
                log(f"[{c.option} {value}] evaluating {method} on {c.eval_episodes} episodes")
                result = evaluate(EvalConfig(run=str(run_dir), episodes=c.eval_episodes, seed=c.seed, workers=c.workers))
                result.pop("episodes_detail", None)
                write_json(result_path, result)
            record = read_run(run_dir)
            labels = int(record["data"]["expert_labels"])
            e = {k: result[k] for k in ("success_rate", "ci95", "successes", "episodes", "mean_length", "failures")}
            metrics = _metrics(run_dir)
            e.update(expert_labels=labels, run=str(run_dir), train_seconds=(metrics.get("final") or {}).get("seconds"),
                     eval_seconds=result.get("seconds"))
            if "rounds" in metrics:
                e["rounds"] = [_round_summary(r) for r in metrics["rounds"]]
            entry[method] = e
            log(f"[{c.option} {value}] {method}: {result['success_rate']:.0%} ({labels} labels)")
        rows.append(entry)
    lines = {_name(m, c): [{"horizon": r["horizon"], **r[m]} for r in rows if m in r] for m in c.methods}
    png = plot_success_vs(lines, out / "compounding.png", title=f"{c.task}: success vs horizon at equal expert labels",
                          top_ticks={r["horizon"]: f"{c.option}={r['value']}" for r in rows})
    fits = {m: fit_growth([(r["horizon"], r[m]["successes"], r[m]["episodes"]) for r in rows if m in r]) for m in c.methods}
    return {
        "experiment": "compounding",
        "config": {**asdict(c), "values": list(c.values), "hidden": list(c.hidden), "methods": list(c.methods)},
        "rows": rows,
        "fits": fits,
        "png": str(png),
        "seconds": time.perf_counter() - started,
        "target": "at the longest of >= 4 horizons HG-DAgger >= 80% and BC at least 40 points lower, the gap growing",
        "meets_target": meets_target(rows),
    }


def meets_target(rows: list[dict[str, Any]]) -> bool:
    """Issue #19's target on the rows (ordered by horizon)."""
    rows = sorted((r for r in rows if "hg_dagger" in r and "bc" in r), key=lambda r: r["horizon"])
    if len(rows) < 4:
        return False
    gaps = [r["hg_dagger"]["success_rate"] - r["bc"]["success_rate"] for r in rows]
    return rows[-1]["hg_dagger"]["success_rate"] >= 0.8 and gaps[-1] >= 0.4 and gaps[-1] > gaps[0]


def _round_summary(r: dict[str, Any]) -> dict[str, Any]:
    keep = ("round", "labels_round", "labels_total", "rollout_success", "takeovers", "missed_deviations", "sim_steps",
            "noise_std", "classifier_recall")
    return {k: r[k] for k in keep if k in r}


def _name(method: str, c: CompoundingConfig) -> str:
    return {"bc": "BC", "bc_chunk": f"BC + chunking ({c.chunk})", "dart_fixed": f"DART, fixed noise {c.noise} rad",
            "dart": "DART (estimated noise)", "perturb": "state perturbation", "dagger": f"DAgger (beta {c.beta})",
            "hg_dagger": f"HG-DAgger ({c.gate})", "safedagger": "SafeDAgger", "aggrevate": "AggreVaTe"}[method] + (
        f", chunked ({c.chunk})" if c.chunked_learners and method in FAMILY_OF else "")


def _metrics(run_dir: Path) -> dict[str, Any]:
    from demo.policies.checkpoint import METRICS_FILE, read_json  # deferred: torch stays out of demo --help

    path = run_dir / METRICS_FILE
    return read_json(path) if path.exists() else {}


def format_table(result: dict[str, Any]) -> str:
    """One line per method: success (95% interval) at each value of the option, labels, fitted failure growth."""
    option, rows = result["config"]["option"], result["rows"]
    columns = [f"{option}={r['value']} (H {r['horizon']})" for r in rows]
    lines = ["method     " + "".join(f"{c:<22}" for c in columns) + "failure rate / 100 steps"]
    for m in result["config"]["methods"]:
        cells = []
        for r in rows:
            e = r.get(m)
            cells.append(f"{e['success_rate']:.0%} [{e['ci95'][0]:.0%},{e['ci95'][1]:.0%}] {e['expert_labels']}" if e else "-")
        fit = result.get("fits", {}).get(m) or {}
        rate = fit.get("rate_per_step")
        lines.append(f"{m:<11}" + "".join(f"{c:<22}" for c in cells) + ("-" if rate is None else f"{rate * 100:.2f}"))
    return "\n".join(lines)
