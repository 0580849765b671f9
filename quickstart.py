"""`demo quickstart`: the whole pipeline on built-in defaults, in a few minutes on 2 CPU cores.

1. collect  scripted ``pick`` demonstrations from a mix of operators (expert, and some poor ones),
2. curate   drop the failed / jerky / idle episodes and trim idle starts,
3. convert  re-express the curated actions as ee7 and measure the round-trip error,
4. train    behaviour cloning (MLP predicting 16-step action chunks, executed with ACT-style temporal
            ensembling) on the curated joint-position demonstrations,
5. eval     roll the policy out on held-out initial states and report success with a 95% interval.

Each stage is the same library call its subcommand makes; the run directory keeps every artefact
(stores, curation report and plot, the trained run, eval JSON) for the other subcommands to open.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
import time
from typing import Any

from demo import algorithms
from demo.collect.scripted import CollectConfig, collect_scripted
from demo.convert.check import round_trip
from demo.convert.convert import ConvertOptions, convert_store
from demo.curate.curate import curate
from demo.errors import DemoError
from demo.progress import Progress
from demo.training.config import TrainConfig


@dataclass
class QuickstartConfig:
    out: str = "quickstart"  # run directory
    task: str = "pick"
    expert_episodes: int = 100
    poor_episodes: int = 20  # mixed in so that curation has something to find
    steps: int | None = None  # BC gradient steps (None: BC's default, demo.training.config.POLICY_DEFAULTS)
    eval_episodes: int = 50
    workers: int = 2
    seed: int = 0


Stage = Callable[[], dict[str, Any]]


def run(config: QuickstartConfig, on_stage: Callable[[str, dict[str, Any], float], None] | None = None,
        overwrite: bool = False, progress: Progress | None = None) -> dict[str, Any]:
    """Run every stage; ``on_stage(name, result, seconds)`` after each, ``progress`` within each
    (the stages' own ticks). Returns all results."""
    from demo.evaluation.evaluate import EvalConfig, evaluate  # deferred: torch stays out of demo --help

    out = Path(config.out)
    if out.exists() and any(out.iterdir()) and not overwrite:
        raise DemoError(out, "already exists (pass --overwrite to replace it, or choose another --out)")
    out.mkdir(parents=True, exist_ok=True)
    demos, curated, ee7, run_dir = out / "demos.zarr", out / "curated.zarr", out / "curated_ee7.zarr", out / "bc"

    def collect() -> dict[str, Any]:
        results = []
        for operator, n in (("expert", config.expert_episodes), ("poor", config.poor_episodes)):
            if n > 0:
                c = CollectConfig(task=config.task, episodes=n, seed=config.seed, operator=operator)
                r = collect_scripted(c, demos, workers=config.workers, append=demos.exists(), overwrite=overwrite,
                                     progress=progress)
                results.append({"operator": operator, "episodes": r.episodes, "success_rate": r.success_rate})
        return {"store": str(demos), "by_operator": results}

    def curate_stage() -> dict[str, Any]:
        result = curate(demos, curated, overwrite=overwrite, progress=progress)
        return {"store": str(curated), "kept": int(result.kept.sum()), "episodes": int(len(result.kept))}

    def convert_stage() -> dict[str, Any]:
        opts = ConvertOptions(to="ee7")
        converted = convert_store(curated, ee7, opts, overwrite=overwrite, progress=progress)
        trip = round_trip(curated, opts)
        return {
            "store": str(ee7),
            "frames": converted.frames,
            "round_trip_max_pos_err_m": trip.max_pos_err_m,
            "round_trip_max_rot_err_rad": trip.max_rot_err_rad,
            "ik_converged_share": trip.ik["converged_share"],
        }

    def train_stage() -> dict[str, Any]:
        tc = TrainConfig(algo="bc", data=str(curated), out=str(run_dir), seed=config.seed, steps=config.steps)
        summary = algorithms.train("bc", tc, overwrite=True, command="demo quickstart", progress=progress)
        return {"run": str(run_dir), "steps": config.steps, **{k: v for k, v in summary.items() if k != "out"}}

    def eval_stage() -> dict[str, Any]:
        ec = EvalConfig(run=str(run_dir), episodes=config.eval_episodes, seed=config.seed, workers=config.workers)
        return evaluate(ec, progress=progress)

    results: dict[str, Any] = {"config": asdict(config)}
    for name, stage in [("collect", collect), ("curate", curate_stage), ("convert", convert_stage),
                        ("train", train_stage), ("eval", eval_stage)]:
        start = time.perf_counter()
        results[name] = stage()
        results[name]["seconds"] = time.perf_counter() - start
        if on_stage:
            on_stage(name, results[name], results[name]["seconds"])
    return results
