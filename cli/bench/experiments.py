"""`demo bench compounding|policies|multimodal|crossrobot|peer-gail`: the training experiments behind the
README's results (:mod:`demo.experiments`), each a configuration and a run."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from demo.cli.bench import bench_app
from demo.cli.config_options import config_options, with_options
from demo.cli.options import RUN, json_option
from demo.cli.output import kv_table, report_console, table, write_json
from demo.cli.progress import bars
from demo.cli.train import parse_policy_opts
from demo.errors import DemoError
from demo.experiments.compounding import CompoundingConfig, format_table, run as run_compounding
from demo.experiments.crossrobot import CrossRobotConfig, run as run_crossrobot
from demo.experiments.multimodal import run as run_modes
from demo.experiments.policies import POLICIES, PoliciesConfig, format_rows, run as run_policies
from demo.experiments.suite import SuiteConfig, format_rows as suite_rows, run as run_suite
from demo.progress import Tick

_X = CrossRobotConfig()  # the experiment's defaults live in its config dataclass
_C = CompoundingConfig()


@bench_app.command("crossrobot")
def bench_crossrobot(
    json_out: str = json_option(default="-"),
    out: str = typer.Option(_X.out, help="Working directory (stores and runs, replaced on every run)."),
    robot: list[str] = typer.Option([], "--robot", metavar="TOML", help="The two arms, in order (repeat; 'builtin' is the "
                                                                         "built-in arm); the first also gets a joint-space policy.",
                                    show_default="builtin, robosuite_ur5e.toml"),
    demos: int = typer.Option(_X.demos, help="Demonstrations per arm."),
    episodes: int = typer.Option(_X.episodes, help="Evaluation episodes per policy and arm."),
    seed: int = typer.Option(_X.seed, help="Seed of collection, training and evaluation."),
    steps: int = typer.Option(None, help="BC optimiser steps of every policy.", show_default="demo train's"),
    workers: int = typer.Option(_X.workers, help="Processes for collection and evaluation."),
) -> None:
    """One policy across robots: BC on two arms' ee7 demos vs per-arm and joint-space policies, success on each arm."""
    config = CrossRobotConfig(out=out, robots=tuple(robot) or _X.robots, demos=demos, episodes=episodes, seed=seed,
                              steps=steps, workers=workers)
    with bars() as progress:
        r = run_crossrobot(config, log=lambda text: progress(Tick("bench crossrobot", message=text)))
    rows = [[row["policy"], row["robot"] + ("" if row["trained_on_robot"] else " (new to it)"),
             f"{row['successes']}/{row['episodes']}", f"{row['ci95'][0]:.0%}-{row['ci95'][1]:.0%}",
             ", ".join(f"{k} {v}" for k, v in sorted(row["failures"].items())) or "-"] for row in r["rows"]]
    console = report_console(json_out)
    console.print(table(f"bench crossrobot ({r['config']['task']}, {r['config']['demos']} demos per arm)",
                        ["policy", "evaluated on", "success", "95% CI", "failures"], rows))
    for arm, v in r["union_vs_per_arm"].items():
        console.print(f"{arm}: union {v['union']:.0%} vs per-arm {v['per_arm']:.0%} ({v['points']:+.0f} points)",
                      highlight=False, markup=False)
    same = r["ee7_vs_joint"]
    console.print(f"{same['robot']}, same demos: ee7 {same['ee7']:.0%} vs joint {same['joint']:.0%} (ee7 on the joint "
                  f"policy's observations {same['ee7_on_the_joint_policy_observations']:.0%})", highlight=False, markup=False)
    for name, line in r["refusals"].items():
        console.print(f"{name} refused: {line}", highlight=False, markup=False)
    console.print(f"target ({r['target']}): {'met' if r['meets_target'] else 'NOT met'}", highlight=False, markup=False)
    write_json(r, json_out)


@bench_app.command("policies")
def bench_policies(
    task: str = typer.Option("avoid", help="Task: avoid (bimodal: both sides measured) or pick."),
    json_out: str = json_option(default="-"),
    png: str = typer.Option(None, "--png", help="Where to draw the bars.", show_default="OUT/policies.png"),
    out: str = typer.Option("policies", help="Working directory (store, runs); a rerun continues what is not complete."),
    data: str = typer.Option(None, "--data", metavar="STORE", help="Train every policy on this store (never modified).",
                             show_default="--episodes-demo collected demonstrations"),
    episodes_demo: int = typer.Option(200, "--episodes-demo", help="Demonstrations to collect (without --data)."),
    eval_episodes: int = typer.Option(100, "--eval-episodes", help="demo eval episodes per policy (seeds disjoint from "
                                                                     "the data)."),
    seed: int = typer.Option(0, help="Seed of collection, training and evaluation."),
    policies: str = typer.Option(",".join(POLICIES), help="Policies, comma-separated, in table order."),
    steps: int = typer.Option(None, help="Optimiser steps of every trained policy.",
                              show_default="each one's demo train default"),
    distil_steps: int = typer.Option(None, "--distil-steps", help="Optimiser steps of the one-step student.",
                                     show_default="demo train --distil's"),
    starts: int = typer.Option(20, help="avoid: start states of the both-sides measure."),
    samples: int = typer.Option(3, help="avoid: episodes per start state, each with another sampling seed."),
    latency_seconds: float = typer.Option(5.0, "--latency-seconds", help="Timing budget of the latency column (0 = skip)."),
    workers: int = typer.Option(1, help="Processes for collection and evaluation."),
    threads: int = typer.Option(1, help="Torch threads of each training."),
) -> None:
    """Every policy class on the same data and seeds: success, both sides (avoid), training time, latency; JSON + PNG."""
    config = PoliciesConfig(out=out, task=task, data=data, episodes_demo=episodes_demo, eval_episodes=eval_episodes, seed=seed,
                            policies=tuple(p.strip() for p in policies.split(",") if p.strip()), steps=steps,
                            distil_steps=distil_steps, starts=starts, samples=samples, latency_seconds=latency_seconds,
                            workers=workers, threads=threads, png=png)
    with bars() as progress:
        r = run_policies(config, progress=progress)
    report_console(json_out).print(table(f"bench policies ({task}, seed {seed}) -> {r['png']}",
                                         ["policy", "success", "95% CI", "both sides", "training s (+teacher)", "ms/query"],
                                         format_rows(r)))
    write_json(r, json_out)


@bench_app.command("peer-gail")
def bench_peer_gail(
    data: str = typer.Option(..., "--data", metavar="STORE", help="The demonstrations: a store of --task (never "
                             "modified).", show_default=False),
    json_out: str = json_option(default="-"),
    task: str = typer.Option("reach", help="Task: its Gymnasium env demo/<Task>-v0."),
    demos: int = typer.Option(None, help="Use the first N successful demonstrations.", show_default="all"),
    steps: int = typer.Option(480_000, help="Training environment steps, an upper bound (whole rounds of --envs x "
                                            "--rollout)."),
    seed: int = typer.Option(0, help="Seed of PPO, the discriminator, the training episodes (RL seed stream) and the "
                                     "evaluation episodes (demo eval --seed's)."),
    eval_episodes: int = typer.Option(100, "--eval-episodes", help="Evaluation episodes: demo eval --seed's, disjoint "
                                                                   "from the data."),
    envs: int = typer.Option(8, help="Environments of the vector env (one process, stepped in turn)."),
    rollout: int = typer.Option(2048, help="PPO n_steps: control steps per environment per GAIL round."),
    demo_batch_size: int = typer.Option(1024, "--demo-batch-size", help="Expert (and as many policy) samples per "
                                                                        "discriminator update."),
    threads: int = typer.Option(1, help="Torch threads."),
) -> None:
    """The imitation library's GAIL (stable-baselines3 PPO) on demo/<Task>-v0: success on demo eval's episodes, steps,
    time. Runs where imitation is installed (its own venv: README)."""
    from demo.experiments.peer_gail import PeerGailConfig, run, summary_rows  # deferred: torch stays out of demo --help

    config = PeerGailConfig(data=data, task=task, demos=demos, steps=steps, seed=seed, eval_episodes=eval_episodes,
                            envs=envs, rollout=rollout, demo_batch_size=demo_batch_size, threads=threads)
    with bars() as progress:
        r = run(config, progress=progress)
    report_console(json_out).print(kv_table(f"bench peer-gail ({task}, imitation {r['versions']['imitation']}, "
                                            f"seed {seed})", summary_rows(r)))
    write_json(r, json_out)


@bench_app.command("compounding")
def bench_compounding(
    json_out: str = json_option("the results", default="-"),
    out: Path = typer.Option(Path(_C.out), help="Working directory (stores, runs, PNG); reruns reuse it."),
    task: str = typer.Option(_C.task, help="Task whose horizon --option sets."),
    option: str = typer.Option(_C.option, help="The task option that sets the horizon (stack: repeat, horizon 60 + 100 N K; "
                               "blocks, 60 + 100 N)."),
    values: str = typer.Option(",".join(map(str, _C.values)), help="Values of --option, one horizon each."),
    task_opt: list[str] = typer.Option([f"{k}={v}" for k, v in _C.task_options.items()], "--task-opt", metavar="KEY=VALUE",
                                       help="The task's other options, fixed (repeatable)."),
    methods: str = typer.Option(",".join(_C.methods), help="Methods to compare (hg_dagger always runs: it sets the label budget)."),
    seed: int = typer.Option(_C.seed, help="Seed of collection, training and evaluation."),
    demos: int = typer.Option(_C.demos, help="The DAgger family's initial demonstrations."),
    pool: int = typer.Option(_C.pool, help="Demonstrations collected per value at first (extended for the budgets)."),
    rounds: int = typer.Option(_C.rounds, help="DAgger rounds."),
    episodes_per_round: int = typer.Option(_C.episodes_per_round, help="DAgger rollouts per round."),
    beta: str = typer.Option(_C.beta, help="Plain DAgger's expert-mixing schedule."),
    gate: str = typer.Option(_C.gate, help="HG-DAgger's gate (SafeDAgger's deviation threshold)."),
    steps: int = typer.Option(_C.steps, help="Optimiser steps of BC and of every family member's round 0."),
    round_steps: int = typer.Option(_C.round_steps, help="Optimiser steps per DAgger round."),
    warm_start: bool = typer.Option(_C.warm_start, "--warm-start/--no-warm-start",
                                    help="Each round fine-tunes the previous learner instead of training a new one."),
    max_labels: int = typer.Option(_C.max_labels, help="One expert-label budget for every horizon (HG-DAgger stops there); "
                                   "0: none, HG-DAgger's rounds set each horizon's budget."),
    hidden: str = typer.Option(",".join(map(str, _C.hidden)), help="Hidden widths of every method's MLP."),
    batch_size: int = typer.Option(_C.batch_size, help="Windows per batch of every method."),
    chunk: int = typer.Option(_C.chunk, help="Chunk length of the chunked-BC line (and of the family's learners with --chunked-learners)."),
    chunked_learners: bool = typer.Option(_C.chunked_learners, "--chunked-learners/--single-step-learners",
                                          help="The DAgger family's learners chunked and ensembled like the chunked-BC line."),
    noise: float = typer.Option(_C.noise, help="Fixed-noise DART line: noise on executed joint targets (rad)."),
    val_fraction: float = typer.Option(_C.val_fraction, help="Held-out demonstrations (SafeDAgger's classifier, DART's noise)."),
    candidates: int = typer.Option(_C.candidates, help="AggreVaTe: actions tried per labelled state (1: the expert's alone)."),
    sigma: float = typer.Option(_C.sigma, help="AggreVaTe's exploration noise and perturbation's displacement (rad)."),
    eval_episodes: int = typer.Option(_C.eval_episodes, help="Evaluation episodes per policy."),
    workers: int = typer.Option(_C.workers, help="Processes for collection, rollouts and evaluation."),
) -> None:
    """Compounding errors: success vs horizon for BC, BC + chunking, DART and the DAgger family at equal expert labels."""
    def ints(flag: str, text: str) -> tuple[int, ...]:
        try:
            return tuple(int(x) for x in text.split(","))
        except ValueError:
            raise DemoError(flag, f"{text!r} is not a comma-separated list of integers") from None

    fixed = {k: _number(v) for k, v in parse_policy_opts(task_opt, "--task-opt").items()}
    config = CompoundingConfig(out=str(out), task=task, option=option, values=ints("--values", values), task_options=fixed,
                               methods=tuple(m.strip() for m in methods.split(",") if m.strip()), seed=seed, demos=demos,
                               pool=pool, rounds=rounds, episodes_per_round=episodes_per_round, beta=beta, gate=gate,
                               steps=steps, round_steps=round_steps, warm_start=warm_start, max_labels=max_labels or None,
                               hidden=ints("--hidden", hidden), batch_size=batch_size,
                               chunk=chunk, chunked_learners=chunked_learners, noise=noise, val_fraction=val_fraction,
                               candidates=candidates, sigma=sigma,
                               eval_episodes=eval_episodes,
                               workers=workers)
    config.check()
    with bars() as progress:
        result = run_compounding(config, log=lambda text: progress(Tick("bench compounding", message=text)))
    report_console(json_out).print(format_table(result), highlight=False, markup=False)
    write_json(result, json_out)


def _number(text: str) -> int | float | str:
    """A task option's value as the number it spells, if it does."""
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


@bench_app.command("multimodal")
def bench_multimodal(
    diffusion: str = typer.Option(..., "--diffusion", metavar=RUN, help="Diffusion run directory (trained on avoid)."),
    reference: str = typer.Option(..., "--reference", metavar=RUN, help="Reference run directory, e.g. MSE-BC on the same data."),
    starts: int = typer.Option(20, help="Start states (demo eval's seed stream)."),
    samples: int = typer.Option(3, help="Episodes per start state, each with another policy sampling seed."),
    seed: int = typer.Option(0, help="Evaluation seed (as demo eval --seed)."),
    execute: int = typer.Option(None, help="Actions executed per chunk by the diffusion run.", show_default="the run's own"),
    reference_execute: int = typer.Option(None, help="Actions executed per chunk by the reference run.",
                                          show_default="the run's own"),
    png: str = typer.Option("multimodal.png", "--png", help="Where to draw the end-effector paths."),
    json_out: str = json_option(default="-"),
) -> None:
    """avoid: EE paths of two policies from the same start states, which side they pass, PNG + JSON."""
    r = run_modes(diffusion, reference, starts=starts, samples=samples, seed=seed, png=png, execute=execute,
                  reference_execute=reference_execute)
    rows = []
    for s in (r["figure"], r["reference"]):
        m = s["modes"]
        rows.append((f"{s['algo']} (execute {s['execute']})", f"{s['success_rate']:.1%}", m["left"], m["right"], m["none"],
                     f"{s['starts_with_both_modes']}/{starts}"))
    report_console(json_out).print(table(f"bench multimodal ({starts} starts x {samples} samples) -> {r.get('png')}",
                                         ["policy", "success", "left", "right", "none", "starts with both modes"], rows))
    write_json(r, json_out)


@bench_app.command("suite")
@with_options("tasks", config_options(SuiteConfig))
def bench_suite(
    name: str = typer.Argument(..., metavar="SUITE", help="metaworld-mt10 or metaworld-mt50 (needs metaworld: "
                               "pip install --no-deps metaworld==3.1.1), or aloha (gym-aloha's transfer cube and "
                               "insertion: needs --python, an interpreter with gym-aloha, and gym-aloha's files beside "
                               "demo: pip install --no-deps gym-aloha==0.1.5)."),
    out: str = typer.Option(SuiteConfig.out, "--out", metavar="DIR", help="Stores, runs and per-task results (reused "
                            "when finished with the same configuration)."),
    tasks: str = typer.Option(None, help="Comma-separated subset of the suite's tasks.", show_default="every task"),
    json_out: str = json_option("the results", default="-"),
    **settings: Any,  # one per option field of SuiteConfig (with_options)
) -> None:
    """A public benchmark's tasks, one policy per task, judged in the benchmark's own environments."""
    config = SuiteConfig(suite=name, out=out, tasks=tuple(t.strip() for t in (tasks or "").split(",") if t.strip()),
                         **settings)
    with bars() as progress:
        result = run_suite(config, log=lambda text: progress(Tick(f"bench suite {name}", message=text)))
    report_console(json_out).print(table(f"{name}: success per task",
                                         ("task", "expert", f"{result['algo']} (95% CI)", "published"),
                                         suite_rows(result)))
    write_json(result, json_out)
