"""`demo eval RUN`: roll a trained policy out in the simulator and report success with a 95% interval
(``--record STORE``: and keep every rollout as an episode)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import typer

from demo.cli.main import app
from demo.cli.options import (address_option, device_option, env_opt_option, env_option, executor_option, json_option,
                              robot_option, run_argument, target_options, task_opt_option)
from demo.errors import DemoError
from demo.seeds import eval_seeds
from demo.sim.foreign import task_name
from demo.store import EpisodeStore
from demo.store.location import store_path
from demo.cli.output import kv_table, report_console, table, warn, write_json
from demo.cli.progress import bars

if TYPE_CHECKING:
    from demo.evaluation.evaluate import EvalConfig


@app.command("eval")
def eval_(
    run: Path = run_argument(),
    task: str = typer.Option(None, help="Task (only the one the policy was trained on is allowed).",
                             show_default="the trained task"),
    blocks: int = typer.Option(None, help="stack: number of cubes (must match training).", show_default="the trained one"),
    task_opt: list[str] = task_opt_option(),
    env: str = env_option(),
    env_opt: list[str] = env_opt_option(),
    robot: str = robot_option("Robot to evaluate on: the name of one the run was trained on, or a robot config TOML "
                              "(another arm only for an end-effector-space policy, e.g. ee7, through that arm's IK).",
                              "the (first) trained robot"),
    episodes: int = typer.Option(100, help="Episodes (per task of a task set, e.g. a run trained on --env metaworld:MT10)."),
    seed: int = typer.Option(0, help="Seed of the evaluation episodes (disjoint from collection seeds)."),
    workers: int = typer.Option(1, help="Parallel worker processes, or Ray actors (results do not depend on it)."),
    executor: str = executor_option(),
    address: str = address_option(),
    execute: int = typer.Option(None, help="Override: actions executed per chunk query.", show_default="the run's"),
    ensemble: float = typer.Option(None, help="Override: temporal ensembling decay (negative = off).",
                                   show_default="the run's"),
    candidates: int = typer.Option(None, help="Override: chunks a sampling policy draws per query, the one most "
                                   "coherent with the chunk before kept (1 = off).", show_default="the run's"),
    video: Path = typer.Option(None, metavar="FILE", help="Write a GIF (or .mp4 where an encoder is installed) of the first episodes.",
                               show_default="no video"),
    video_episodes: int = typer.Option(4, help="Episodes in the video (tiled)."),
    video_size: int = typer.Option(128, help="Pixels per episode tile."),
    device: str = device_option(),
    instruction: str = typer.Option(None, "--instruction", metavar="TEXT", help="Tell every episode this, in words (a "
                                    "policy trained on instructions; unknown words are read as unknown).",
                                    show_default="each environment's own (a task set: each member's)"),
    record: str = typer.Option(None, "--record", metavar="STORE", help="Append every rollout to this episode store "
                               "(created if absent; same task, robot and observations) as an episode: source policy, "
                               "columns run, success, outcome; curate it and train on its successes.",
                               show_default="nothing stored"),
    shift: list[str] = typer.Option(None, "--shift", metavar="KIND", help="Distribution shift suite (repeatable): "
                                    "lighting, camera, texture, friction, mass, latency, or all; every --level on "
                                    "the same start states, a robustness table.", show_default="no shift"),
    level: str = typer.Option("0..3", "--level", metavar="N|A..B", help="--shift: the level(s), 0 (none) to 3."),
    plot: Path = typer.Option(None, "--plot", metavar="PNG", help="--shift: success against level, one line per "
                              "shift.", show_default="no figure"),
    min_success: float = typer.Option(None, "--min-success", metavar="P", min=0.0, max=1.0,
                                      help="Exit non-zero below this success rate (a fraction), after the results are "
                                           "shown and written.", show_default="none; 0% on a robot the policy was not "
                                           "trained on always fails"),
    json_out: str = json_option("the result"),
) -> None:
    """Success rate (95% Wilson interval), mean length and failure breakdown of a trained policy."""
    from demo.evaluation.evaluate import EvalConfig, evaluate, judge_success  # deferred: torch stays out of demo --help

    if env is not None and (task is not None or blocks is not None):
        raise DemoError("--env", "names the environment to evaluate on: --task and --blocks do not apply")
    if env_opt and env is None:
        raise DemoError("--env-opt", "sets an option of --env")
    options: dict | None = target_options(env, env_opt, task_opt, blocks)
    if env is None and not options:
        options = None  # none given: the trained task's (an environment given without options gets none)
    config = EvalConfig(
        run=str(run), task=task_name(env) if env is not None else task, task_options=options,
        robot=robot or None, episodes=episodes, seed=seed, workers=workers, executor=executor, address=address,
        execute=execute, ensemble=ensemble, candidates=candidates, video=str(video) if video else None, device=device, video_episodes=video_episodes, video_size=video_size,
        record=record, instruction=instruction,
    )
    if shift and min_success is not None:
        raise DemoError("--min-success", "judges one evaluation: --shift evaluates many cells")
    if shift:
        _shift_suite(config, shift, level, plot, json_out)
        return
    if plot is not None:
        raise DemoError("--plot", "draws the --shift suite's figure: give --shift")
    again = _recorded_before(record, run, seed, episodes) if record is not None else 0  # before this run appends
    with bars() as progress:  # the first tick comes after the first episode, i.e. after validation
        result = evaluate(config, progress=progress)
    if again:  # told once the run succeeded: a failed command prints its one error line alone
        warn(f"{record} already held {again} episode(s) of {run} with these seeds (--seed {seed}): they were "
             "recorded again (another --seed gives new episodes)")
    lo, hi = result["ci95"]
    failures = ", ".join(f"{k}: {v}" for k, v in sorted(result["failures"].items())) or "none"
    rows = [
        ("run", result["run"]),
        ("task", f"{result['task']} {result['task_options'] or ''}".strip()),
        ("robot", "the environment's own" if result["robot"] is None else result["robot"] +
         ("" if result["robot_trained_on"] else " (not trained on: " + result["robot_note"] + ")")),
        ("episodes", result["episodes"]),
        ("success", f"{result['successes']}/{result['episodes']} = {result['success_rate']:.1%} (95% CI {lo:.1%}-{hi:.1%})"),
        ("mean length (steps)", f"{result['mean_length']:.1f}"),
        ("failures", failures),
        ("seeds shared with training data", result["seeds_shared_with_training_data"]),
        *([("instruction", result["instruction"] + (f" (unknown words: {', '.join(result['unknown_words'])})"
                                                    if result["unknown_words"] else ""))] if "instruction" in result else []),
        ("seconds", f"{result['seconds']:.1f}"),
    ]
    if "record" in result:
        rows.append(("recorded", f"{result['record']['episodes']} episodes -> {result['record']['store']}"))
    if "video" in result:
        rows.append(("video", result["video"]["path"]))
    report_console(json_out).print(kv_table("evaluated", rows))
    if "per_task" in result:  # a task set (--env metaworld:MT10): every member's own figure
        report_console(json_out).print(table("per task", ("task", "success", "95% CI", "failures"), [
            (name.removeprefix("env:"), f"{r['successes']}/{r['episodes']}", f"{r['ci95'][0]:.0%}-{r['ci95'][1]:.0%}",
             ", ".join(f"{k}: {v}" for k, v in sorted(r["failures"].items())) or "none")
            for name, r in result["per_task"].items()]))
    write_json(result, json_out)
    judge_success(result, min_success)


def _shift_suite(config: "EvalConfig", shifts: list[str], level: str, plot: Path | None, json_out: str) -> None:
    """``--shift``: the robustness table (success per shift and level), its JSON and figure."""
    from demo.evaluation.shifts import evaluate_shifts, parse_levels, parse_shifts, plot_shifts  # deferred: torch

    if config.record is not None or config.video is not None:
        raise DemoError("--shift", "evaluates many cells: --record and --video take one evaluation")
    kinds, levels = parse_shifts(shifts), parse_levels(level)
    with bars() as progress:
        result = evaluate_shifts(config, kinds, levels, progress=progress)
    if plot is not None:
        result["plot"] = str(plot_shifts(result, plot))
    rows = [(kind, *(f"{c['success_rate']:.0%} ({c['ci95'][0]:.0%}-{c['ci95'][1]:.0%})" for c in cells.values()))
            for kind, cells in result["shifts"].items()]
    report_console(json_out).print(table(f"success under shift: {config.run}, {config.episodes} episodes per cell",
                                         ("shift", *(f"level {lv}" for lv in levels)), rows))
    write_json(result, json_out)


def _recorded_before(record: str, run: Path, seed: int, episodes: int) -> int:
    """How many episodes the store at ``record`` holds from ``run`` (its ``run`` column, as evaluation
    writes it) reset to this evaluation's seeds: a rerun appends the same rollouts again. 0 where
    there is no store yet, or none of evaluation's; evaluation then says what is wrong, if anything.
    (Of a task set's seeds, the first ``episodes`` are checked: a rerun repeats those too.)"""
    path = store_path(record)
    if not path.exists():
        return 0
    try:
        with EpisodeStore.open(path) as store:
            runs, seeds = store.column("run"), store.column("seed")
    except DemoError:
        return 0
    ours = set(eval_seeds(seed, episodes))
    return sum(r == str(run) and int(s) in ours for r, s in zip(runs, seeds))
