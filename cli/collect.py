"""`demo collect`: record demonstrations into a store."""

from __future__ import annotations

from pathlib import Path

import typer

from demo.cli.main import app
from demo.cli.options import (address_option, env_opt_option, env_option, executor_option, json_option, overwrite_option,
                              robot_option, target_options, task_opt_option)
from demo.cli.output import kv_table, report_console, warn, write_json
from demo.cli.progress import bars
from demo.collect.kinesthetic import collect_kinesthetic
from demo.collect.leader_arms import collect_leader_arms
from demo.collect.scripted import CollectConfig, check_success, collect_scripted
from demo.collect.vr import collect_vr
from demo.errors import DemoError
from demo.executor import ExecutorConfig
from demo.sim.foreign import task_name
from demo.sim.randomize import Randomization
from demo.sim.render import parse_camera
from demo.store.instructions import check_instruction

SOURCES = ("scripted", "kinesthetic", "vr", "leader")


@app.command()
def collect(
    out: str = typer.Option(..., "--out", "-o", metavar="STORE", help="Store to write: a directory (e.g. pick.zarr) or a URL "
                                                                       "(s3://bucket/pick.zarr)."),
    source: str = typer.Option("scripted", help=f"Where demonstrations come from: {', '.join(SOURCES)}."),
    task: str = typer.Option("pick", help="Task: reach, pick, push, avoid, stack."),
    env: str = env_option(),
    env_opt: list[str] = env_opt_option(),
    expert: str = typer.Option(None, metavar="module:callable", help="--env: the expert, called as callable(obs, env) "
                               "-> action each step (or callable(env) -> an object with act(obs), per episode); "
                               "demo: the scripted expert of a demo/<Task>-v0 environment.", show_default="none"),
    episodes: int = typer.Option(50, help="Number of episodes (scripted: per task of a task set such as --env "
                                 "metaworld:MT10; human sources record every input episode)."),
    seed: int = typer.Option(0, help="Seed of the episodes' initial states (and of all noise)."),
    workers: int = typer.Option(1, help="Simulation processes (or Ray actors) feeding this (writer) process; 0 = all in "
                                        "this process."),
    executor: str = executor_option(),
    address: str = address_option(),
    noise: float = typer.Option(0.0, help="DART noise: std (rad) added to executed joint targets; labels stay clean."),
    operator: str = typer.Option(
        None, help="scripted: simulated operator profile expert|good|okay|poor; human sources: a name.",
        show_default="expert; human sources: the input's, else human",
    ),
    input: Path = typer.Option(None, "--input", metavar="FILE", help="kinesthetic: JOINTS.csv; vr: POSES.jsonl; leader: LEADER.csv (see README).",
                               show_default="none"),
    calib: Path = typer.Option(None, metavar="JSON", help="vr: tracker->base calibration JSON.",
                               show_default="align the first pose to the EE"),
    scale: float = typer.Option(1.0, help="vr: robot motion per hand motion."),
    ik: str = typer.Option("mink", help="vr: IK backend, mink or placo."),
    smoothing: float = typer.Option(2.0, help="vr: jitter filter cutoff in Hz (0 = off)."),
    robot: Path = robot_option(),
    blocks: int = typer.Option(None, help="stack: number of cubes to stack.", show_default="the task's default"),
    task_opt: list[str] = task_opt_option(),
    camera: list[str] = typer.Option([], metavar="NAME@WxH", help="Record camera images, e.g. front@128x128 (repeatable).",
                                     show_default="none"),
    randomize: str = typer.Option(None, "--randomize", metavar="PRESET|KIND=LEVEL,...|FILE", help="scripted: domain "
                                  "randomisation drawn per episode from its seed: light, medium or heavy (every kind at "
                                  "level 1, 2, 3), levels per kind (friction=2,camera=1), or a TOML of them; kinds: "
                                  "lighting, camera, texture, friction, mass, latency.", show_default="none"),
    instruction: str = typer.Option(None, "--instruction", metavar="TEXT", help="What every episode is told to do, in "
                                    "words (the episode table's instruction column; an instruction-conditioned policy "
                                    "trains on it).", show_default="the environment's own (Meta-World's task as a "
                                    "sentence), else none"),
    every_goal: bool = typer.Option(False, "--every-goal", help="scripted: demonstrate every start state once per goal "
                                    "its words can name (pick --task-opt colours=3: three episodes per scene, one per "
                                    "cube), so that the same images differ only in the instruction."),
    append: bool = typer.Option(False, "--append", help="Append to an existing store of the same task and robot."),
    min_success: float = typer.Option(
        None, "--min-success", metavar="P", min=0.0, max=1.0,
        help="scripted: exit non-zero when the expert's success rate is below P (a fraction); the episodes stay "
             "stored. Below 0.9 a warning is printed either way.", show_default="none",
    ),
    overwrite: bool = overwrite_option("an existing store at --out"),
    json_out: str = json_option("the run summary"),
) -> None:
    """Record demonstrations (scripted experts; kinesthetic, VR-style and leader-arm input files)."""
    if source not in SOURCES:
        raise DemoError("--source", f"unknown source {source!r} (choose from {', '.join(SOURCES)})")
    cameras = tuple(parse_camera(c, "--camera") for c in camera)
    if instruction is not None:
        instruction = check_instruction(instruction)
    if source != "scripted":
        if input is None:
            raise DemoError("--input", f"--source {source} needs an input file (--input)")
        if workers > 1 or noise > 0 or executor != "process" or address or randomize:
            raise DemoError("--source", f"{source} replays recorded input: --workers > 1, --executor, --address, "
                                        "--noise and --randomize do not apply")
        if min_success is not None or every_goal:
            raise DemoError("--min-success" if min_success is not None else "--every-goal",
                            "applies to --source scripted (the scripted experts)")
    if env is not None and source not in ("scripted", "leader"):
        raise DemoError("--env", "collects from an environment's expert (--source scripted) or from the leader arms "
                                 "of a robot of several arms (--source leader --robot ARMS.toml)")
    if (expert is not None or env_opt) and env is None:
        raise DemoError("--expert" if expert is not None else "--env-opt", "applies to a Gymnasium environment (--env)")
    robot_config = str(robot) if robot else None
    options = target_options(env, env_opt, task_opt, blocks)
    task = task_name(env) if env is not None else task
    with bars() as progress:  # the library ticks only once the store is open
        if source == "scripted":
            config = CollectConfig(task=task, episodes=episodes, seed=seed, operator=operator or "expert", noise=noise,
                                   robot=robot_config, task_options=options, cameras=cameras, expert=expert,
                                   randomize=Randomization.parse(randomize).to_json() if randomize else {},
                                   instruction=instruction, every_goal=every_goal)
            result = collect_scripted(config, out, executor=ExecutorConfig(executor, workers, address), append=append,
                                      overwrite=overwrite, progress=progress)
        else:
            human = dict(operator=operator, robot=robot_config, task_options=options, cameras=cameras, append=append,
                         overwrite=overwrite, progress=progress, instruction=instruction or "")
            if source == "vr":
                result = collect_vr(task, input, out, seed, calib=calib, scale=scale, ik=ik, smoothing=smoothing, **human)
            elif env is not None:  # leader arms of a robot of several arms, in the environment
                if cameras:
                    raise DemoError("--camera", "an environment renders its own cameras (--env-opt)")
                del human["cameras"]
                result = collect_leader_arms(task, input, out, seed, **human)
            else:
                result = collect_kinesthetic(task, input, out, seed, leader=source == "leader", **human)
    summary = {
        "out": result.path,
        "task": task,
        "episodes": result.episodes,
        "successes": result.successes,
        "success_rate": result.success_rate,
        "frames": result.frames,
        "seconds": result.seconds,
        "frames_per_s": result.frames / max(1e-9, result.seconds),
        "modes": result.modes,
    }
    rows = [
        ("store", result.path),
        ("episodes", result.episodes),
        ("success", f"{result.successes}/{result.episodes} ({result.success_rate:.1%})"),
        ("frames", result.frames),
        ("frames/s", f"{summary['frames_per_s']:,.0f}"),
    ]
    unreachable = getattr(result, "unreachable_frames", None)
    if unreachable is not None:
        summary["unreachable_frames"] = unreachable
        rows.append(("unreachable frames (flagged)", unreachable))
    tracking = getattr(result, "tracking_error_rad", None)
    if tracking:  # leader-follower: how far the follower lagged its leader, per joint
        summary["tracking_error_rad"] = tracking
        rows.append(("tracking error (rad, mean / max)",
                     ", ".join(f"{joint} {e['mean']:.4f} / {e['max']:.4f}" for joint, e in tracking.items())))
    if result.modes:
        rows.append(("modes", ", ".join(f"{k}: {v}" for k, v in sorted(result.modes.items()))))
    report_console(json_out).print(kv_table("collected", rows))
    write_json(summary, json_out)
    if source == "scripted":
        warning = check_success(result, min_success)  # raises below --min-success
        if warning:
            warn(warning)
