"""`demo bench policies`: every policy class trained and evaluated on the same data and seeds.

On one task (``avoid``, bimodal, or ``pick``):

1. **one dataset**: ``data`` (a store, never modified) or ``episodes_demo`` scripted demonstrations
   collected with ``seed`` (``demo collect``; on ``avoid`` in pairs that pass on opposite sides);
2. **each policy** trained on it with ``seed`` and its own defaults (``demo train``'s: the
   configuration measured best for it), timed: MSE-BC (chunked, ensembled), GMM-BC and discrete-BC
   (BC's output heads), ACT, diffusion (DDIM-8) and one-step diffusion, distilled from that
   diffusion run (:mod:`demo.imitation.distill`; its time is the distillation's, its teacher's apart);
3. **success** of each on the same ``eval_episodes`` episodes of ``demo eval --seed seed`` (initial
   states disjoint from the data's), with 95% Wilson intervals;
4. on ``avoid``, **both sides**: from each of the first ``starts`` of those start states, ``samples``
   episodes that differ only in the policy's sampling seed; the share of starts from which the
   policy passes the obstacle on both sides (``demo bench multimodal``'s measure);
5. **latency**: milliseconds per query of each policy at batch 1 on one thread, timed in turn
   (:func:`demo.bench.infer.time_interleaved`, in blocks of calls: each policy's weights warm, as when
   it is deployed alone), and per control step (a query every ``execute`` steps).

Writes one JSON (every number and the configuration) and one PNG (bars with 95% intervals). Each
policy's run directory, evaluation and modes are kept under ``out``; a rerun with the same ``out``
skips what is complete (a run with its final metrics, an evaluation with the same settings), so an
interrupted bench continues where it stopped (a training stopped by Ctrl-C resumes from its checkpoint).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
import json
from pathlib import Path
import time
from typing import Any

import numpy as np

from demo import algorithms
from demo.collect.scripted import CollectConfig, collect_scripted
from demo.errors import DemoError
from demo.experiments import multimodal
from demo.figures import pyplot, save_figure
from demo.jsonio import write_json
from demo.progress import Progress, Tick, or_silent
from demo.store import EpisodeStore
from demo.training.config import TrainConfig, for_policy


@dataclass(frozen=True)
class Entry:
    """A policy class of the table: a registered policy with its options (or a distilled student)."""

    label: str
    algo: str
    options: dict[str, Any] = field(default_factory=dict)
    teacher: str | None = None  # distilled from this entry's run (one-step diffusion)


POLICIES: dict[str, Entry] = {
    "mse-bc": Entry("MSE-BC", "bc"),
    "gmm-bc": Entry("GMM-BC", "bc", {"head": "gmm"}),
    "discrete-bc": Entry("discrete-BC", "bc", {"head": "discrete"}),
    "act": Entry("ACT", "act"),
    "diffusion": Entry("diffusion (DDIM-8)", "diffusion"),
    "one-step": Entry("one-step diffusion", "diffusion", teacher="diffusion"),
}
STAGE = "bench policies"


@dataclass
class PoliciesConfig:
    out: str = "policies"
    task: str = "avoid"
    data: str | None = None  # a store to train on (else episodes_demo collected demonstrations)
    episodes_demo: int = 200
    eval_episodes: int = 100
    seed: int = 0  # collection, training, evaluation
    policies: tuple[str, ...] = tuple(POLICIES)
    steps: int | None = None  # every trained policy's optimiser steps (None: each one's default)
    distil_steps: int | None = None  # the one-step student's (None: demo train --distil's default)
    starts: int = 20  # avoid: start states of the both-sides measure
    samples: int = 3  # episodes per start state, each with another sampling seed
    latency_seconds: float = 5.0  # timing budget of the latency figures (0 = skip)
    workers: int = 1  # collection and evaluation processes
    threads: int = 1  # torch threads of each training
    png: str | None = None  # the figure (None: out/policies.png)

    def check(self) -> None:
        unknown = [p for p in self.policies if p not in POLICIES]
        if unknown or not self.policies:
            raise DemoError("--policies", f"unknown policy {', '.join(unknown) or '(none given)'} (known: {', '.join(POLICIES)})")
        for flag, value in (("--eval-episodes", self.eval_episodes), ("--starts", self.starts), ("--samples", self.samples),
                            ("--episodes-demo", self.episodes_demo)):
            if value < 1:
                raise DemoError(flag, f"must be at least 1, got {value}")
        from demo.policies.policy import policy_config  # deferred: torch stays out of demo --help

        for name in self.policies:  # an unknown policy or option fails before anything runs
            try:
                policy_config(POLICIES[name].algo, POLICIES[name].options)
            except DemoError as exc:
                raise DemoError("--policies", f"{name}: {exc.problem}") from None


def to_train(policies: tuple[str, ...]) -> list[str]:
    """The runs the table needs, teachers before their students (a teacher not in the table included)."""
    order: list[str] = []
    for name in policies:
        teacher = POLICIES[name].teacher
        for n in ([teacher] if teacher else []) + [name]:
            if n not in order:
                order.append(n)
    return order


# ================================================================================== the steps
def dataset(c: PoliciesConfig, out: Path, progress: Progress) -> Path:
    """The store every policy trains on: ``c.data``, or ``c.episodes_demo`` demonstrations collected once."""
    path = Path(c.data) if c.data else out / "data.zarr"
    if not path.exists():
        if c.data:
            raise DemoError(path, "no such store")
        progress(Tick(STAGE, message=f"collecting {c.episodes_demo} {c.task} demonstrations (seed {c.seed})"))
        collect_scripted(CollectConfig(task=c.task, episodes=c.episodes_demo, seed=c.seed), path, workers=c.workers,
                         progress=progress)
    with EpisodeStore.open(path) as store:
        task = (store.meta.task or {}).get("name")
        if task != c.task:
            raise DemoError(path, f"holds task {task!r}, not {c.task!r}")
        if not c.data and store.num_episodes != c.episodes_demo:
            raise DemoError(path, f"holds {store.num_episodes} episodes, not --episodes-demo {c.episodes_demo} "
                                  "(an interrupted collection): delete it or choose another --out")
    return path


def complete(run: Path) -> bool:
    """Whether ``run`` holds a finished training (final metrics and the policy)."""
    from demo.policies.checkpoint import METRICS_FILE, POLICY_FILE  # deferred: torch stays out of demo --help

    try:
        return (run / POLICY_FILE).is_file() and "final" in json.loads((run / METRICS_FILE).read_text())
    except (OSError, ValueError):
        return False


def train(name: str, c: PoliciesConfig, data: Path, runs: Path, progress: Progress) -> dict[str, Any]:
    """Train ``name`` into ``runs/name`` unless complete (an interrupted run, one that saved its train
    state on Ctrl-C, is resumed); its final metrics."""
    from demo.policies.checkpoint import METRICS_FILE, STATE_FILE, read_json  # deferred: torch stays out of demo --help

    entry, run = POLICIES[name], runs / name
    if not complete(run):
        resume = (run / STATE_FILE).is_file()
        progress(Tick(STAGE, message=f"{'resuming' if resume else 'training'} {entry.label}"))
        common = dict(data=str(data), out=str(run), seed=c.seed, threads=c.threads)
        how = dict(progress=progress, resume=resume, overwrite=not resume)
        if entry.teacher:
            from demo.imitation.distill import train as distil  # deferred: torch stays out of demo --help

            distil(TrainConfig(algo=entry.algo, steps=c.distil_steps, **common), runs / entry.teacher, **how)
        else:

            algorithms.train(entry.algo, for_policy(entry.algo, steps=c.steps, policy=dict(entry.options), **common), **how)
    return read_json(run / METRICS_FILE)["final"]


def evaluation(name: str, c: PoliciesConfig, run: Path, progress: Progress) -> dict[str, Any]:
    """Success on ``demo eval``'s episodes and, on avoid, both sides; kept in ``run/bench_policies.json``
    and reused while the settings are the same."""
    from demo.evaluation.evaluate import (  # deferred: torch stays out of demo --help
        EvalConfig,
        evaluate,
        wilson_interval,
    )
    from demo.policies.checkpoint import read_json  # deferred: torch stays out of demo --help

    settings = {"eval_episodes": c.eval_episodes, "seed": c.seed, "starts": c.starts, "samples": c.samples}
    path = run / "bench_policies.json"
    if path.is_file():
        kept = read_json(path)
        if kept.get("settings") == settings:
            return kept
    progress(Tick(STAGE, message=f"evaluating {POLICIES[name].label} on {c.eval_episodes} episodes"))
    result = evaluate(EvalConfig(run=str(run), episodes=c.eval_episodes, seed=c.seed, workers=c.workers), progress)
    success = {k: result[k] for k in ("episodes", "successes", "success_rate", "ci95", "mean_length", "failures", "execution")}
    both = None
    if c.task == "avoid":
        summary = multimodal.summarize(multimodal.rollouts(str(run), c.starts, c.samples, c.seed), c.starts)
        k = summary["starts_with_both_modes"]
        both = {"starts": c.starts, "samples": c.samples, "starts_with_both": k, "share": k / c.starts,
                "ci95": list(wilson_interval(k, c.starts)), "modes": summary["modes"], "rollout_success": summary["success_rate"]}
    kept = {"settings": settings, "success": success, "both_sides": both}
    write_json(path, kept)
    return kept


def latencies(runs: dict[str, Path], seconds: float) -> dict[str, dict[str, float]]:
    """Milliseconds per query (batch 1, one thread) of each run's policy, timed in turn, and per control step."""
    import torch  # deferred: torch stays out of demo --help

    from demo.bench.infer import WARM_BLOCK, time_interleaved  # deferred: torch stays out of demo --help
    from demo.policies.checkpoint import load_bundle  # deferred: torch stays out of demo --help

    class Query:  # each policy on an observation of its own shape (time_interleaved passes one to all)
        def __init__(self, run: Path):
            self.bundle = load_bundle(run)
            spec = self.bundle.policy.spec
            self.obs = torch.zeros(1, spec.n_obs, spec.obs_dim)

        def predict(self, _: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
            return self.bundle.policy.predict(self.obs, generator)

    queries = {name: q for name, q in ((n, Query(r)) for n, r in runs.items()) if not q.bundle.obs_spec.images}
    old = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        timed = time_interleaved(queries, torch.zeros(1), seconds, block=WARM_BLOCK) if queries else {}
    finally:
        torch.set_num_threads(old)
    return {name: {"ms_per_query": t["ms_median"], "ms_per_control_step": t["ms_median"] / queries[name].bundle.execution.execute,
                   "execute": queries[name].bundle.execution.execute} for name, t in timed.items()}


# ================================================================================== the bench
_TRAINING_KEYS = ("task", "data", "episodes_demo", "seed", "steps", "distil_steps", "threads")


def run(c: PoliciesConfig, progress: Progress | None = None) -> dict[str, Any]:
    """Steps 1-5 into ``c.out``; the JSON-able result (``rows``: one per policy in ``c.policies``)."""
    from demo.policies.checkpoint import read_json  # deferred: torch stays out of demo --help

    c.check()
    tell = or_silent(progress)
    out = Path(c.out)
    out.mkdir(parents=True, exist_ok=True)
    training = {k: getattr(c, k) for k in _TRAINING_KEYS}
    training["data"] = str(Path(c.data).resolve()) if c.data else None
    made = out / "training.json"  # what the runs under out were trained with: a rerun must match it
    if made.is_file():
        differ = sorted(k for k, v in read_json(made).items() if training.get(k) != v)
        if differ:
            raise DemoError(out, f"holds runs trained with other {', '.join(differ)}; choose another --out")
    else:
        write_json(made, training)
    started = time.perf_counter()
    data = dataset(c, out, tell)
    runs = out / "runs"
    finals = {name: train(name, c, data, runs, tell) for name in to_train(c.policies)}
    rows = []
    for name in c.policies:
        entry, final = POLICIES[name], finals[name]
        row: dict[str, Any] = {"policy": name, "label": entry.label, "algo": entry.algo, "options": entry.options,
                               "run": str(runs / name), "train_seconds": final["seconds"], "train_steps": final["step"],
                               **evaluation(name, c, runs / name, tell)}
        row.pop("settings")
        if entry.teacher:
            row["teacher"] = entry.teacher
            row["teacher_train_seconds"] = finals[entry.teacher]["seconds"]
        rows.append(row)
    if c.latency_seconds > 0:
        tell(Tick(STAGE, message="timing every policy's queries (batch 1, one thread)"))
        timed = latencies({n: runs / n for n in c.policies}, c.latency_seconds)
        for row in rows:
            if row["policy"] in timed:
                row["latency"] = timed[row["policy"]]
    result = {
        "benchmark": "policies",
        "task": c.task,
        "config": {**asdict(c), "policies": list(c.policies), "data": str(data)},
        "seed_rule": "data: demo collect --seed seed; success: demo eval --seed seed (episode_seed(seed + 10_000_000, i)); "
                     "both sides: the first `starts` of those start states, sample k reseeding the policy with start + 7919 k",
        "rows": rows,
        "seconds": time.perf_counter() - started,
        "note": "training seconds are wall time on this machine, as measured (other jobs may have shared it)",
    }
    result["png"] = str(plot(result, c.png or out / "policies.png"))
    write_json(out / "policies.json", result)
    return result


def plot(result: dict[str, Any], path: str | Path) -> Path:
    """Bars with 95% intervals: success, both sides (avoid), training time and latency per policy."""
    plt = pyplot()
    rows = result["rows"]
    labels = [r["label"] for r in rows]
    # (title, values, 95% intervals, a stacked part)
    panels: list[tuple[str, list[float], list[list[float]] | None, list[float] | None]] = [
        (f"success ({rows[0]['success']['episodes']} episodes)", [r["success"]["success_rate"] for r in rows],
         [r["success"]["ci95"] for r in rows], None)]
    if all(r.get("both_sides") for r in rows):
        b = rows[0]["both_sides"]
        panels.append((f"starts with both sides\n({b['starts']} starts x {b['samples']} samples)",
                       [r["both_sides"]["share"] for r in rows], [r["both_sides"]["ci95"] for r in rows], None))
    panels.append(("training time (s; hatched: the teacher's)", [r["train_seconds"] for r in rows], None,
                   [r.get("teacher_train_seconds", 0.0) for r in rows]))
    if all("latency" in r for r in rows):
        panels.append(("ms per query (batch 1, 1 thread)", [r["latency"]["ms_per_query"] for r in rows], None, None))
    fig, axes = plt.subplots(1, len(panels), figsize=(3.4 * len(panels), 3.8), squeeze=False)
    x = np.arange(len(rows))
    colors = [f"C{i}" for i in range(len(rows))]
    for ax, (title, values, ci, stacked) in zip(axes[0], panels):
        v = np.asarray(values, dtype=float)
        err = None if ci is None else np.clip(np.array([[vi - lo for vi, (lo, _) in zip(v, ci)],
                                                        [hi - vi for vi, (_, hi) in zip(v, ci)]]), 0, None)
        ax.bar(x, v, yerr=err, capsize=3, color=colors)
        if stacked is not None and any(stacked):
            ax.bar(x, stacked, bottom=v, color=colors, alpha=0.35, hatch="//")
        if ci is not None:
            ax.set_ylim(0, 1.05)
        ax.set_title(title, fontsize=9)
        ax.set_xticks(x, labels, rotation=35, ha="right", fontsize=8)
        ax.grid(axis="y", alpha=0.3)
    fig.suptitle(f"{result['task']}: policies on the same data and evaluation seeds (95% Wilson intervals)", fontsize=10)
    fig.tight_layout()
    return save_figure(fig, path)


def format_rows(result: dict[str, Any]) -> list[list[str]]:
    """The table's cells: policy, success, 95% CI, both sides, training time (+ the teacher's), ms per query."""
    cells = []
    for r in result["rows"]:
        s, b, lat = r["success"], r.get("both_sides"), r.get("latency")
        train = f"{r['train_seconds']:,.0f}" + (f" (+{r['teacher_train_seconds']:,.0f})" if r.get("teacher") else "")
        cells.append([r["label"], f"{s['successes']}/{s['episodes']}", f"{s['ci95'][0]:.0%}-{s['ci95'][1]:.0%}",
                      f"{b['starts_with_both']}/{b['starts']}" if b else "-", train,
                      f"{lat['ms_per_query']:.2f}" if lat else "-"])
    return cells
