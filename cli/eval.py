"""`demo eval`: roll a trained policy out in the simulator and report success with a 95% interval."""

from __future__ import annotations

from pathlib import Path

import typer

from demo.cli.main import app
from demo.cli.output import console, table, write_json


@app.command("eval")
def eval_(
    run: Path = typer.Argument(..., help="Run directory written by demo train."),
    task: str = typer.Option(None, help="Task (default and only allowed: the one the policy was trained on)."),
    blocks: int = typer.Option(None, help="stack: number of cubes (must match training)."),
    robot: Path = typer.Option(None, help="Robot config TOML (default: the trained robot)."),
    episodes: int = typer.Option(100, help="Episodes."),
    seed: int = typer.Option(0, help="Seed of the evaluation episodes (disjoint from collection seeds)."),
    workers: int = typer.Option(1, help="Parallel worker processes (results do not depend on it)."),
    execute: int = typer.Option(None, help="Override: actions executed per chunk query."),
    ensemble: float = typer.Option(None, help="Override: temporal ensembling decay (negative = off)."),
    video: Path = typer.Option(None, help="Write a GIF (or .mp4 where an encoder is installed) of the first episodes."),
    video_episodes: int = typer.Option(4, help="Episodes in the video (tiled)."),
    video_size: int = typer.Option(128, help="Pixels per episode tile."),
    json_out: str = typer.Option(None, "--json", help="Write the result as JSON ('-' for stdout)."),
) -> None:
    """Success rate (95% Wilson interval), mean length and failure breakdown of a trained policy."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    from demo.train.evaluate import EvalConfig, evaluate

    config = EvalConfig(
        run=str(run), task=task, task_options=None if blocks is None else {"blocks": blocks},
        robot=str(robot) if robot else None, episodes=episodes, seed=seed, workers=workers, execute=execute,
        ensemble=ensemble, video=str(video) if video else None, video_episodes=video_episodes, video_size=video_size,
    )
    done = {"n": 0, "ok": 0}
    progress = Progress(
        TextColumn(f"[bold]eval {run.name}[/]"), BarColumn(), MofNCompleteColumn(),
        TextColumn("success {task.fields[success]}"), TimeElapsedColumn(), TimeRemainingColumn(), console=console,
    )
    with progress:
        bar = progress.add_task("episodes", total=episodes, success="-")

        def on_episode(outcome) -> None:
            done["n"] += 1
            done["ok"] += int(outcome.success)
            progress.update(bar, advance=1, success=f"{done['ok']}/{done['n']}")

        result = evaluate(config, on_episode=on_episode)
    lo, hi = result["ci95"]
    failures = ", ".join(f"{k}: {v}" for k, v in sorted(result["failures"].items())) or "none"
    rows = [
        ("run", result["run"]),
        ("task", f"{result['task']} {result['task_options'] or ''}".strip()),
        ("episodes", result["episodes"]),
        ("success", f"{result['successes']}/{result['episodes']} = {result['success_rate']:.1%} (95% CI {lo:.1%}-{hi:.1%})"),
        ("mean length (steps)", f"{result['mean_length']:.1f}"),
        ("failures", failures),
        ("seeds shared with training data", result["seeds_shared_with_training_data"]),
        ("seconds", f"{result['seconds']:.1f}"),
    ]
    if "video" in result:
        rows.append(("video", result["video"]["path"]))
    console.print(table("evaluated", ["", ""], rows))
    write_json(result, json_out)
