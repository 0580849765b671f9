"""`demo collect`: record demonstrations into a store."""

from __future__ import annotations

import re
import time
from pathlib import Path

import typer
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from demo.cli.main import app
from demo.cli.output import console, err_console, table, write_json
from demo.errors import DemoError

SOURCES = ("scripted", "kinesthetic", "vr")


def parse_camera(spec: str) -> tuple[str, int, int]:
    """``NAME@WxH`` -> (name, width, height)."""
    match = re.fullmatch(r"([A-Za-z0-9_\-]+)@(\d+)x(\d+)", spec)
    if not match:
        raise DemoError("--camera", f"{spec!r} is not NAME@WIDTHxHEIGHT (e.g. front@128x128)")
    return match.group(1), int(match.group(2)), int(match.group(3))


def task_options(blocks: int | None) -> dict:
    return {} if blocks is None else {"blocks": blocks}


@app.command()
def collect(
    out: Path = typer.Option(..., "--out", "-o", help="Store directory to write (e.g. pick.zarr)."),
    source: str = typer.Option("scripted", help=f"Where demonstrations come from: {', '.join(SOURCES)}."),
    task: str = typer.Option("pick", help="Task: reach, pick, push, avoid, stack."),
    episodes: int = typer.Option(50, help="Number of episodes."),
    seed: int = typer.Option(0, help="Seed of the episodes' initial states (and of all noise)."),
    workers: int = typer.Option(1, help="Simulation processes feeding this (writer) process; 0 = all in this process."),
    noise: float = typer.Option(0.0, help="DART noise: std (rad) added to executed joint targets; labels stay clean."),
    operator: str = typer.Option(
        None, help="scripted: simulated operator profile expert|good|okay|poor (default expert); human sources: a name."
    ),
    input: Path = typer.Option(None, "--input", help="kinesthetic: JOINTS.csv; vr: POSES.jsonl (see README)."),
    calib: Path = typer.Option(None, help="vr: tracker->base calibration JSON (default: align the first pose to the EE)."),
    scale: float = typer.Option(1.0, help="vr: robot motion per hand motion."),
    ik: str = typer.Option("mink", help="vr: IK backend, mink or placo."),
    smoothing: float = typer.Option(2.0, help="vr: jitter filter cutoff in Hz (0 = off)."),
    robot: Path = typer.Option(None, help="Robot config TOML (default: the built-in arm)."),
    blocks: int = typer.Option(None, help="stack: number of cubes to stack."),
    camera: list[str] = typer.Option([], help="Record camera images, NAME@WxH (repeatable)."),
    append: bool = typer.Option(False, help="Append to an existing store of the same task and robot."),
    overwrite: bool = typer.Option(False, help="Replace an existing store at --out."),
    json_out: str = typer.Option(None, "--json", help="Write the run summary as JSON ('-' for stdout)."),
) -> None:
    """Record demonstrations (scripted experts; kinesthetic and VR-style input files)."""
    if source not in SOURCES:
        raise DemoError("--source", f"unknown source {source!r} (choose from {', '.join(SOURCES)})")
    cameras = tuple(parse_camera(c) for c in camera)
    if source != "scripted":
        if input is None:
            raise DemoError("--input", f"--source {source} needs an input file (--input)")
        if workers > 1 or noise > 0:
            raise DemoError("--source", f"{source} replays recorded input: --workers > 1 and --noise do not apply")
    done = {"ok": 0, "n": 0, "frames": 0}
    start = time.perf_counter()
    progress = Progress(
        TextColumn(f"[bold]collect {task}[/]"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("success {task.fields[success]}"),
        TextColumn("{task.fields[fps]} frames/s"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=err_console if json_out == "-" else console,  # stdout carries only the JSON then
        transient=False,
    )
    with progress:
        bar = progress.add_task("episodes", total=episodes if source == "scripted" else None, success="-", fps="-")

        def on_episode(index: int, info: dict, length: int) -> None:
            done["n"] += 1
            done["ok"] += int(info["success"])
            done["frames"] += length
            rate = done["frames"] / max(1e-9, time.perf_counter() - start)
            progress.update(bar, advance=1, success=f"{done['ok']}/{done['n']}", fps=f"{rate:,.0f}")

        robot_config = str(robot) if robot else None
        options = task_options(blocks)
        if source == "scripted":
            from demo.collect.scripted import CollectConfig, collect_scripted

            config = CollectConfig(task=task, episodes=episodes, seed=seed, operator=operator or "expert", noise=noise,
                                   robot=robot_config, task_options=options, cameras=cameras)
            result = collect_scripted(config, out, workers=workers, append=append, overwrite=overwrite,
                                      on_episode=on_episode)
        else:
            human = dict(operator=operator, robot=robot_config, task_options=options, cameras=cameras, append=append,
                         overwrite=overwrite, on_episode=on_episode, on_start=lambda n: progress.update(bar, total=n))
            if source == "vr":
                from demo.collect.vr import collect_vr

                result = collect_vr(task, input, out, seed, calib=calib, scale=scale, ik=ik, smoothing=smoothing, **human)
            else:
                from demo.collect.kinesthetic import collect_kinesthetic

                result = collect_kinesthetic(task, input, out, seed, **human)
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
    if result.modes:
        rows.append(("modes", ", ".join(f"{k}: {v}" for k, v in sorted(result.modes.items()))))
    if json_out != "-":
        console.print(table("collected", ["", ""], rows))
    write_json(summary, json_out)
