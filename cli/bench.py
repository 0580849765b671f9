"""`demo bench <name>`: benchmarks written as JSON, each with its reference measured in the same run.

Each benchmark is a library function in ``demo.bench.<name>`` returning a JSON-able dict; this
module only registers the subcommands. The JSON goes to stdout by default (``--json -``), the
table to stderr; ``--json FILE`` writes the file and prints the table on stdout.
"""

from __future__ import annotations

import typer

from demo.experiments.crossrobot import CrossRobotConfig
from demo.bench.faults import FaultsConfig
from demo.experiments.policies import POLICIES
from demo.cli.main import app
from demo.cli.options import address_option, executor_option, json_option

bench_app = typer.Typer(help="Benchmarks written as JSON (figure and reference from the same run).", no_args_is_help=True)
app.add_typer(bench_app, name="bench")


@bench_app.command("load")
def bench_load(
    json_out: str = json_option(default="-"),
    frames: int = typer.Option(1_000_000, help="Frames in the synthetic store."),
    seconds: float = typer.Option(3.0, help="Timing budget per measurement (s)."),
    seed: int = typer.Option(0, help="Seed of the synthetic store and the sampled windows."),
) -> None:
    """Window-sampling samples/s (batch 256, n_obs 2, H 16) vs a raw memory copy of the same bytes."""
    from demo.bench.load import run
    from demo.cli.output import kv_table, report_console, write_json

    result = run(frames=frames, seconds=seconds, seed=seed)
    report_console(json_out).print(
        kv_table(
            "bench load",
            [
                ("window samples/s", result["samples_per_s"]),
                ("raw copy samples/s (reference)", result["reference_samples_per_s"]),
                ("ratio", result["ratio_to_reference"]),
                ("target", f">= {result['target_samples_per_s']}: {'met' if result['meets_target'] else 'NOT met'}"),
            ],
        )
    )
    write_json(result, json_out)


@bench_app.command("collect")
def bench_collect(
    json_out: str = json_option(default="-"),
    task: str = typer.Option("pick", help="Task: reach, pick, push, avoid, stack."),
    episodes: int = typer.Option(120, help="Episodes per measurement."),
    seconds: float = typer.Option(3.0, help="Timing budget of the raw-physics reference (s)."),
    seed: int = typer.Option(0, help="Seed of the episodes' initial states."),
    rounds: int | None = typer.Option(None, min=1, help="Rounds of reference + 1 worker + 2 workers (--executor ray: "
                                         "2 processes + 2 Ray actors); best of each is reported.",
                                         show_default="6 (--executor ray: 2)"),
    executor: str = executor_option(),
    address: str = address_option(),
) -> None:
    """Scripted collection frames/s (1 and 2 workers) vs bare mj_step of the same scene; --executor ray: 2 Ray
    actors vs 2 worker processes."""
    from demo.bench.collect import run, run_executors
    from demo.cli.output import kv_table, report_console, write_json
    from demo.executor import ExecutorConfig

    ExecutorConfig(executor, 2, address).check()
    if executor == "ray":
        r = run_executors(task=task, episodes=episodes, seed=seed, rounds=rounds or 2, address=address)
        title, rows = f"bench collect --executor ray ({task})", [
            ("collection frames/s, 2 worker processes (reference)", r["process"]["frames_per_s"]),
            ("collection frames/s, 2 Ray actors", r["ray"]["frames_per_s"]),
            (f"ratio (target >= {r['target_ray_to_process']})",
             f"{r['ray_to_process']:.2f}: {'met' if r['meets_target'] else 'NOT met'}"),
            ("same bytes", r["same_bytes"]),
        ]
    else:
        r = run(task=task, episodes=episodes, seconds=seconds, seed=seed, rounds=rounds or 6)
        title, rows = f"bench collect ({task})", [
            ("raw physics control steps/s (reference)", r["reference_physics"]["control_steps_per_s"]),
            ("collection frames/s, 1 worker", r["one_worker"]["frames_per_s"]),
            ("collection frames/s, 2 workers", r["two_workers"]["frames_per_s"]),
            (f"ratio to physics (target >= {r['target_ratio_to_physics']})", r["ratio_to_physics"]),
            (f"2-worker speed-up (target >= {r['target_two_worker_speedup']})", r["two_worker_speedup"]),
        ]
    report_console(json_out).print(kv_table(title, rows))
    write_json(r, json_out)


@bench_app.command("render")
def bench_render(
    json_out: str = json_option(default="-"),
    task: str = typer.Option("pick", help="Task: reach, pick, push, avoid, stack."),
    camera: list[str] = typer.Option([], metavar="NAME@WxH", help="Camera to record (repeatable).",
                                     show_default="front@64x64, wrist@64x64"),
    episodes: int = typer.Option(20, help="Episodes per collection measurement (at least 2)."),
    seconds: float = typer.Option(3.0, help="Timing budget of each bare-render reference (s)."),
    seed: int = typer.Option(0, help="Seed of the episodes' initial states."),
    rounds: int = typer.Option(2, min=1, help="Rounds of reference + collection; best of each is reported."),
    workers: int = typer.Option(1, min=0, help="Simulation processes of the collection (as demo collect); 0 = all in "
                                               "this process."),
) -> None:
    """Collection frames/s with cameras vs bare mujoco.Renderer renders (+ physics) of the same scene."""
    from demo.bench.render import DEFAULT_CAMERAS, run
    from demo.cli.output import kv_table, report_console, write_json

    r = run(task=task, cameras=camera or DEFAULT_CAMERAS, episodes=episodes, seconds=seconds, seed=seed,
            rounds=rounds, workers=workers)
    stored = r["camera_bytes"]["total"]
    report_console(json_out).print(
        kv_table(
            f"bench render ({task}, {' + '.join(r['cameras'])})",
            [
                ("bare render + physics frames/s (reference)", r["reference"]["frames_per_s"]),
                (f"collection frames/s (--workers {r['workers']})", r["figure"]["frames_per_s"]),
                (f"ratio (target >= {r['target_ratio']})", f"{r['ratio']:.2f}: {'met' if r['meets_target'] else 'NOT met'}"),
                *([("ratio in CPU time (this process)", r["cpu_ratio"])] if r["cpu_ratio"] is not None else []),
                ("image bytes per frame, raw / stored", f"{stored['raw_bytes_per_frame']:,} / "
                                                        f"{stored['stored_bytes_per_frame']:,.0f}"),
            ],
        )
    )
    write_json(r, json_out)


_F = FaultsConfig()  # the benchmark's defaults live in its config dataclass


@bench_app.command("faults")
def bench_faults(
    json_out: str = json_option(default="-"),
    episodes: int = typer.Option(_F.episodes, help="Episodes each killed `reach` collection is asked for."),
    kills: int = typer.Option(_F.kills, help="Collections killed (SIGKILL) at a random time."),
    append_kills: int = typer.Option(_F.append_kills, help="`--append` collections killed at a random time."),
    races: int = typer.Option(_F.races, help="`--overwrite` (collect, convert, import in turn) of a store being appended to."),
    creates: int = typer.Option(_F.creates, help="Rounds of 3 processes creating the same new store at once."),
    max_kill_s: float = typer.Option(_F.max_kill_s, help="Kill times are uniform in [0, this] seconds after the start."),
    disk_mib: int = typer.Option(_F.disk_mib, help="Size of the tmpfs filled by the full-disk trial (as root)."),
    workers: int = typer.Option(_F.workers, help="Simulation processes of each killed collection."),
    seed: int = typer.Option(_F.seed, help="Seed of the random kill times."),
) -> None:
    """SIGKILLs, --overwrite races, concurrent creates and a full disk: stores readable, finished episodes lost (must be 0)."""
    from demo.bench.faults import run
    from demo.cli.output import report_console, table, write_json
    from demo.cli.progress import bars

    config = FaultsConfig(episodes=episodes, kills=kills, append_kills=append_kills, races=races, creates=creates,
                          max_kill_s=max_kill_s, disk_mib=disk_mib, workers=workers, seed=seed)
    with bars() as progress:
        r = run(config, progress=progress)
    columns = ["scenario", "trials", "stores readable", "no store, nothing finished", "finished episodes",
               "finished lost", "checks failed"]
    rows = [[s["scenario"], s["trials"], s["stores_readable"], s["no_store_nothing_finished"], s["finished_episodes"],
             s["finished_lost"], s["checks_failed"]] for s in r["scenarios"]]
    report_console(json_out).print(table(f"bench faults ({r['task']}, {r['seconds']:.0f} s)", columns, rows))
    write_json(r, json_out)
    if not r["ok"]:
        raise typer.Exit(1)  # a finished episode was lost, or a refusal was not one clean line


_X = CrossRobotConfig()  # the experiment's defaults live in its config dataclass


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
    from demo.experiments.crossrobot import run
    from demo.cli.output import report_console, table, write_json
    from demo.cli.progress import bars
    from demo.progress import Tick

    config = CrossRobotConfig(out=out, robots=tuple(robot) or _X.robots, demos=demos, episodes=episodes, seed=seed,
                              steps=steps, workers=workers)
    with bars() as progress:
        r = run(config, log=lambda text: progress(Tick("bench crossrobot", message=text)))
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
    from demo.experiments.policies import PoliciesConfig, format_rows, run
    from demo.cli.output import report_console, table, write_json
    from demo.cli.progress import bars

    config = PoliciesConfig(out=out, task=task, data=data, episodes_demo=episodes_demo, eval_episodes=eval_episodes, seed=seed,
                            policies=tuple(p.strip() for p in policies.split(",") if p.strip()), steps=steps,
                            distil_steps=distil_steps, starts=starts, samples=samples, latency_seconds=latency_seconds,
                            workers=workers, threads=threads, png=png)
    with bars() as progress:
        r = run(config, progress=progress)
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
    from demo.experiments.peer_gail import PeerGailConfig, run, summary_rows
    from demo.cli.output import kv_table, report_console, write_json
    from demo.cli.progress import bars

    config = PeerGailConfig(data=data, task=task, demos=demos, steps=steps, seed=seed, eval_episodes=eval_episodes,
                            envs=envs, rollout=rollout, demo_batch_size=demo_batch_size, threads=threads)
    with bars() as progress:
        r = run(config, progress=progress)
    report_console(json_out).print(kv_table(f"bench peer-gail ({task}, imitation {r['versions']['imitation']}, "
                                            f"seed {seed})", summary_rows(r)))
    write_json(r, json_out)
