"""`demo collect`: record demonstrations into a store."""

from __future__ import annotations

import re
import time
from pathlib import Path

import typer
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from demo.cli.main import app
from demo.cli.output import console, table, write_json
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
    operator: str = typer.Option("expert", help="Simulated operator profile: expert, good, okay, poor."),
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
    if source != "scripted":
        raise DemoError("--source", f"{source} collection is not built yet (issue #8)", exit_code=2)
    from demo.collect.scripted import CollectConfig, collect_scripted

    config = CollectConfig(
        task=task,
        episodes=episodes,
        seed=seed,
        operator=operator,
        noise=noise,
        robot=str(robot) if robot else None,
        task_options=task_options(blocks),
        cameras=tuple(parse_camera(c) for c in camera),
    )
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
        console=console,
        transient=False,
    )
    with progress:
        bar = progress.add_task("episodes", total=episodes, success="-", fps="-")

        def on_episode(index: int, info: dict, length: int) -> None:
            done["n"] += 1
            done["ok"] += int(info["success"])
            done["frames"] += length
            rate = done["frames"] / max(1e-9, time.perf_counter() - start)
            progress.update(bar, advance=1, success=f"{done['ok']}/{done['n']}", fps=f"{rate:,.0f}")

        result = collect_scripted(config, out, workers=workers, append=append, overwrite=overwrite, on_episode=on_episode)
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
        ("expert success", f"{result.successes}/{result.episodes} ({result.success_rate:.1%})"),
        ("frames", result.frames),
        ("frames/s", f"{summary['frames_per_s']:,.0f}"),
    ]
    if result.modes:
        rows.append(("modes", ", ".join(f"{k}: {v}" for k, v in sorted(result.modes.items()))))
    console.print(table("collected", ["", ""], rows))
    write_json(summary, json_out)
